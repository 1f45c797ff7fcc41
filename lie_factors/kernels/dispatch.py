"""Per-group specialization of group-generic kernels: each group compiles only its own cores.

The factors, the batch solver and the public functions need the same cores
(inverse, compose, log, exp, dlog, Ad, ...) for whichever group they work on.
Their kernels are written once, generically, taking a *group tag* ``g`` as
their first argument::

    @kernel
    def between_error(g, Minv, X1, X2, e):
        ...
        _dispatch.inverse(g, X1, X1inv)     # SE(3)'s _inverse when g is SE3
        _dispatch.log(g, E, e)

A group's tag is its :class:`lie_factors.kernels.registry.GroupInfo` (``SE3``
below is ``registry.SE3``): importing this module gives every registered group
a numba type, :class:`GroupType`, distinct per group. Numba specializes a
kernel on its argument types, so ``between_error(SE3, ...)`` and
``between_error(SE2, ...)`` are two compilations, and the functions here are
numba intrinsics that pick the group's core *while typing*: the SE(3)
specialization contains SE(3)'s cores and nothing else (an SE(3) graph compiles
no Sim(2) code). Every specialization is cached on disk by ``cache=True`` like
any other signature (the tag's type pickles by name), and the generic kernels
stay plain top-level functions, so no closure stands in the way of the cache.
A specialization cached before a core was edited is never loaded after: the
cache is keyed by the whole package's sources (:mod:`lie_factors.kernels.cache`).

Writing a new group-generic kernel: make ``g`` its first argument, call the
cores through this module (``_dispatch.exp(g, x, out)``, ``_dispatch.dim(g)``)
and pass ``g`` on to other generic kernels; call it from Python with a tag
(``_dispatch.SE3``, ``registry.group("Pose3")``, ``GroupSpec.group``). Calling a
core that is not listed here: add one line below (``name = _core("_name", doc)``).
An :class:`Op` tag names a core the same way, for kernels generic in the
operation too (:mod:`lie_factors.kernels.public`).

Adding a group is its facts in :mod:`lie_factors.kernels.registry` and a module
``lie_factors.<name>`` with the cores ``_inverse, _compose, _log, _exp, _dlog,
_Ad`` (and ``_hat, _vee, _ad, _dexp`` for the public functions).

A tag costs more than an integer in a call from Python (numba reads its
``_numba_type_`` attribute instead of a fast-path type check); numba-to-numba
calls cost nothing extra, the dispatch having happened at compile time.
"""

from __future__ import annotations

import importlib

from numba.core import types
from numba.core.errors import TypingError
from numba.core.imputils import lower_constant
from numba.core.typing import signature
from numba.extending import NativeValue, intrinsic, models, register_model, typeof_impl, unbox

from . import checks, registry
from .registry import UNIT, GroupInfo


class GroupType(types.Type):
    """Numba type of a group tag; one instance (and so one specialization) per group."""

    def __init__(self, name: str):
        self.group = name
        super().__init__(name=f"Group[{name}]")


class Op:
    """Tag of an operation, for kernels generic in the operation: calls the core ``_<name>``
    of the group (:func:`call`); ``element``: its arguments are group elements (else any
    finite array), what :func:`accepts` checks."""

    __slots__ = ("name", "element", "_numba_type_")

    def __init__(self, name: str, element: bool):
        self.name = name
        self.element = element
        self._numba_type_ = OpType(name, element)

    def __repr__(self) -> str:
        return f"<op {self.name}>"


class OpType(types.Type):
    """Numba type of an :class:`Op` tag."""

    def __init__(self, name: str, element: bool):
        self.op = name
        self.element = element
        super().__init__(name=f"Op[{name}{', element' if element else ''}]")


for _type in (GroupType, OpType):
    # A tag carries no data: everything is in its type.
    register_model(_type)(models.OpaqueModel)
    unbox(_type)(lambda typ, obj, c: NativeValue(c.context.get_dummy_value()))
    lower_constant(_type)(lambda context, builder, ty, pyval: context.get_dummy_value())


@typeof_impl.register(GroupInfo)
@typeof_impl.register(Op)
def _typeof_tag(val, c):
    return val._numba_type_


#: name → GroupInfo, every registered group.
GROUPS: dict[str, GroupInfo] = {}


def register(info: GroupInfo) -> GroupInfo:
    """Give ``info`` its numba type (read by numba's dispatcher in C, so a tag is typed
    without a Python call), making it a tag for group-generic kernels."""
    if info.name in GROUPS:
        raise ValueError(f"group {info.name!r} is already registered")
    object.__setattr__(info, "_numba_type_", GroupType(info.name))
    GROUPS[info.name] = info
    return info


for _info in (*registry.GROUPS.values(), *registry.QUATERNIONS.values()):
    register(_info)

SO3, SE3, SE2, SIM2, SIM3 = registry.SO3, registry.SE3, registry.SE2, registry.SIM2, registry.SIM3


def _group(g) -> GroupInfo:
    """The registered group of numba type ``g`` (raise a typing error for anything else)."""
    if not isinstance(g, GroupType):
        raise TypingError(f"expected a lie_factors.kernels.dispatch group tag, got {g}")
    return GROUPS[g.group]


# The functions below are numba intrinsics: typing one looks up the group's
# core (or constant) and the call compiles to a direct call of that core, as if
# the kernel had named ``se3._inverse`` itself. (An ``overload`` would do the
# same through a small wrapper function compiled once per group and core, each one
# more compilation on a first run.) They are callable from numba only;
# Python code calls ``lie_factors.se3._inverse`` ... directly.


def _calling(typingctx, g, fn, argtys, llargs_of):
    """Signature and codegen of an intrinsic ``f(g, ...)`` that calls the kernel ``fn`` on the
    arguments ``argtys``; ``llargs_of(context, llargs)`` picks (or makes) its LLVM arguments."""
    fnty = typingctx.resolve_value_type(fn)
    fn_sig = fnty.get_call_type(typingctx, argtys, {})

    def codegen(context, builder, sig, llargs):
        return context.get_function(fnty, fn_sig)(builder, llargs_of(context, llargs))

    return fn_sig.return_type, codegen


def _core_of(g, name: str):
    return getattr(importlib.import_module(_group(g).module), name)


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

    def typer(typingctx, g, *args):
        ret, codegen = _calling(typingctx, g, _core_of(g, name), args, lambda ctx, ll: ll[1:])
        return signature(ret, g, *args), codegen

    def two(typingctx, g, x, out):
        return typer(typingctx, g, x, out)

    def three(typingctx, g, x, y, out):
        return typer(typingctx, g, x, y, out)

    f = intrinsic(three if name == "_compose" else two)
    f.__doc__ = doc
    return f


def _op(op) -> OpType:
    if not isinstance(op, OpType):
        raise TypingError(f"expected a lie_factors.kernels.dispatch operation tag, got {op}")
    return op


def _call(typingctx, g, op, *args):
    ret, codegen = _calling(typingctx, g, _core_of(g, "_" + _op(op).op), args, lambda ctx, ll: ll[2:])
    return signature(ret, g, op, *args), codegen


@intrinsic
def call(typingctx, g, op, x, out):
    """call(g, op, x, out): group ``g``'s core ``_<op>(x, out)``."""
    return _call(typingctx, g, op, x, out)


@intrinsic
def call2(typingctx, g, op, x, y, out):
    """call2(g, op, x, y, out): group ``g``'s core ``_<op>(x, y, out)``."""
    return _call(typingctx, g, op, x, y, out)


@intrinsic
def accepts(typingctx, g, op, x):
    """accepts(g, op, x): True when ``x`` (one argument of ``op``, any memory order) is what
    the public functions' fast path takes: finite entries, and, for an operation on group
    elements, an element of ``g`` (:func:`checks.element_ok` or :func:`checks.unit_ok`)."""
    info = _group(g)
    if not _op(op).element:
        ret, codegen = _calling(typingctx, g, checks.finite, (x,), lambda ctx, ll: ll[2:])
    elif info.corner == UNIT:
        ret, codegen = _calling(typingctx, g, checks.unit_ok, (x,), lambda ctx, ll: ll[2:])
    else:
        # Literal d and corner: element_ok is compiled for this group's values, its loops
        # over the rotation block unrolled (as when a kernel writes element_ok(X, 3, ONE)).
        def args(ctx, ll):
            return [ll[2], ctx.get_constant(types.intp, info.rot_dim), ctx.get_constant(types.intp, info.corner)]

        literals = (types.literal(info.rot_dim), types.literal(info.corner))
        ret, codegen = _calling(typingctx, g, checks.element_ok, (x, *literals), args)
    return signature(ret, g, op, x), codegen


dim = _constant("dim", "dim(g): tangent dimension n of group g.")
mat = _constant("mat", "mat(g): matrix size m of group g.")
rot_dim = _constant("rot_dim", "rot_dim(g): size of the rotation block of g's matrices.")
corner = _constant("corner", "corner(g): NO_CORNER, ONE, POSITIVE or UNIT: what makes an element of g valid.")

hat = _core("_hat", "hat(g, x, out): out = hat(x) (m, m).")
vee = _core("_vee", "vee(g, X, out): out = vee(X) (n,).")
ad = _core("_ad", "ad(g, x, out): out = ad_x (n, n).")
dexp = _core("_dexp", "dexp(g, x, out): out = D_exp(x) (n, n), the left Jacobian.")
inverse = _core("_inverse", "inverse(g, X, out): out = X⁻¹ (m, m).")
compose = _core("_compose", "compose(g, X, Y, out): out = X·Y (m, m).")
log = _core("_log", "log(g, X, out): out = Log(X) (n,).")
exp = _core("_exp", "exp(g, x, out): out = Exp(x) (m, m).")
dlog = _core("_dlog", "dlog(g, x, out): out = dlog(x) = D_exp(x)⁻¹ (n, n).")
Ad = _core("_Ad", "Ad(g, X, out): out = Ad(X) (n, n).")
