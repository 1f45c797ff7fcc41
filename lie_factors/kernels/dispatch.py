"""Per-group specialization of group-generic kernels: each group compiles only its own cores.

The factors and the batch solver need the same few cores (inverse, compose,
log, exp, dlog, Ad) for whichever group a factor lives on. Their kernels are
written once, generically, taking a *group tag* ``g`` as their first argument::

    @kernel
    def between_error(g, Minv, X1, X2, e):
        ...
        _dispatch.inverse(g, X1, X1inv)     # SE(3)'s _inverse when g is SE3
        _dispatch.log(g, E, e)

Each registered group (:func:`register`) is a :class:`Group` tag whose numba
type, :class:`GroupType`, is distinct per group. Numba specializes a kernel on
its argument types, so ``between_error(SE3, ...)`` and ``between_error(SE2,
...)`` are two compilations, and the functions here are numba intrinsics that
pick the group's core *while typing*: the SE(3)
specialization contains SE(3)'s cores and nothing else (an SE(3) graph compiles
no Sim(2) code). Every specialization is cached on disk by ``cache=True`` like
any other signature (the tag's type pickles by name), and the generic kernels
stay plain top-level functions, so no closure stands in the way of the cache.

Writing a new group-generic kernel: make ``g`` its first argument, call the
cores through this module (``_dispatch.exp(g, x, out)``, ``_dispatch.dim(g)``)
and pass ``g`` on to other generic kernels; call it from Python with a tag
(``_dispatch.SE3``, ``GroupSpec.group``). Calling a core that is not listed
here: add one line below (``name = _core("_name", doc)``).

Adding a group is its facts in :mod:`lie_factors.kernels.registry` and a registration
here, like ``SIM3 = register(sim3)`` below, with a module that has the cores
``_inverse, _compose, _log, _exp, _dlog, _Ad``.

The tag costs ≈1 µs per call from Python over an integer (numba reads its
``_numba_type_`` attribute instead of a fast-path type check); numba-to-numba
calls cost nothing extra, the dispatch having happened at compile time.
"""

from __future__ import annotations

from types import ModuleType

from numba import types
from numba.core.errors import TypingError
from numba.core.imputils import lower_constant
from numba.core.typing import signature
from numba.extending import NativeValue, intrinsic, models, register_model, typeof_impl, unbox

from .. import se2, se3, sim2, sim3, so3
from . import registry


class GroupType(types.Type):
    """Numba type of a :class:`Group` tag; one instance (and so one specialization) per group."""

    def __init__(self, name: str):
        self.group = name
        super().__init__(name=f"Group[{name}]")


register_model(GroupType)(models.OpaqueModel)


@unbox(GroupType)
def _unbox_group(typ, obj, c):
    # The tag carries no data: everything is in its type.
    return NativeValue(c.context.get_dummy_value())


@lower_constant(GroupType)
def _group_constant(context, builder, ty, pyval):
    return context.get_dummy_value()


class Group:
    """Python-side tag of a registered group; pass it as ``g`` to group-generic kernels.

    Attributes: ``name`` (module name, e.g. ``"se3"``), ``module`` (the kernel
    module), ``dim`` (tangent dimension n), ``mat`` (matrix size m),
    ``rot_dim`` (size of the rotation block), ``corner`` (NO_CORNER: the
    element is a bare rotation; ONE: last row [0 … 0 1]; POSITIVE: last row
    [0 … 0 s], s > 0).
    """

    __slots__ = ("name", "module", "dim", "mat", "rot_dim", "corner", "_numba_type_")

    def __init__(self, module: ModuleType):
        self.name = module.__name__.rsplit(".", 1)[-1]
        self.module = module
        info = registry.GROUPS[self.name]
        self.dim = info.dim
        self.mat = info.mat
        self.rot_dim = info.rot_dim
        self.corner = info.corner
        # Read by numba's dispatcher in C, so a tag is typed without a Python call.
        self._numba_type_ = GroupType(self.name)

    def __repr__(self) -> str:
        return f"<group {self.name}>"

    def __reduce__(self):
        return (_by_name, (self.name,))


@typeof_impl.register(Group)
def _typeof_group(val, c):
    return val._numba_type_


#: name → Group, every registered group.
GROUPS: dict[str, Group] = {}


def _by_name(name: str) -> Group:
    return GROUPS[name]


def register(module: ModuleType) -> Group:
    """Make ``module``'s cores reachable from group-generic kernels; returns its tag (its facts
    are :mod:`lie_factors.kernels.registry`'s)."""
    group = Group(module)
    if group.name in GROUPS:
        raise ValueError(f"group {group.name!r} is already registered")
    GROUPS[group.name] = group
    return group


SO3 = register(so3)
SE3 = register(se3)
SE2 = register(se2)
SIM2 = register(sim2)
SIM3 = register(sim3)


def _group(g) -> Group:
    """The registered group of numba type ``g`` (raise a typing error for anything else)."""
    if not isinstance(g, GroupType):
        raise TypingError(f"expected a lie_factors.kernels.dispatch group tag, got {g}")
    return GROUPS[g.group]


# The functions below are numba intrinsics: typing one looks up the group's
# core (or constant) and the call compiles to a direct call of that core, as if
# the kernel had named ``se3._inverse`` itself. (An ``overload`` would do the
# same through a small wrapper function compiled once per group and core, which
# costs ≈0.1 s apiece on a first run.) They are callable from numba only;
# Python code calls ``g.module._inverse`` ... directly.


def _constant(attr: str, doc: str):
    @intrinsic
    def constant(typingctx, g):
        value = getattr(_group(g), attr)

        def codegen(context, builder, sig, args):
            return context.get_constant(types.intp, value)

        return signature(types.intp, g), codegen

    constant.__doc__ = doc
    return constant


def _core(name: str, doc: str):
    """Intrinsic ``f(g, *args)`` calling group ``g``'s core ``name(*args)``."""

    def typer(typingctx, g, args):
        core = getattr(_group(g).module, name)
        fnty = typingctx.resolve_value_type(core)
        core_sig = fnty.get_call_type(typingctx, args, {})

        def codegen(context, builder, sig, llargs):
            return context.get_function(fnty, core_sig)(builder, llargs[1:])

        return signature(core_sig.return_type, g, *args), codegen

    def two(typingctx, g, x, out):
        return typer(typingctx, g, (x, out))

    def three(typingctx, g, x, y, out):
        return typer(typingctx, g, (x, y, out))

    f = intrinsic(three if name == "_compose" else two)
    f.__doc__ = doc
    return f


dim = _constant("dim", "dim(g): tangent dimension n of group g.")
mat = _constant("mat", "mat(g): matrix size m of group g.")
rot_dim = _constant("rot_dim", "rot_dim(g): size of the rotation block of g's matrices.")
corner = _constant("corner", "corner(g): NO_CORNER, ONE or POSITIVE, the bottom-right entry of g's matrices.")

inverse = _core("_inverse", "inverse(g, X, out): out = X⁻¹ (m, m).")
compose = _core("_compose", "compose(g, X, Y, out): out = X·Y (m, m).")
log = _core("_log", "log(g, X, out): out = Log(X) (n,).")
exp = _core("_exp", "exp(g, x, out): out = Exp(x) (m, m).")
dlog = _core("_dlog", "dlog(g, x, out): out = dlog(x) = D_exp(x)⁻¹ (n, n).")
Ad = _core("_Ad", "Ad(g, X, out): out = Ad(X) (n, n).")
