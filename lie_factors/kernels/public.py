"""The public functions of every group, written once: validation, broadcasting, the single-element fast path.

Each group module defines its cores (``_exp(x, out)`` ...) and then, in one line,
the functions users call::

    hat, vee, exp, log, ad, Ad, dexp, dlog, compose, inverse = _public.functions(_info, globals())

:func:`functions` builds one function per operation of :data:`OPERATIONS` (the
unit quaternions have exp, log, compose and inverse only) around the module's
core of that name, with the group's facts from
:mod:`lie_factors.kernels.registry`. Every argument is one of three kinds, each
with one rule (:mod:`lie_factors.kernels.validate`) and the same messages for
every group:

* a tangent vector x (..., n): finite entries;
* a Lie-algebra matrix X (..., m, m), the argument of ``vee``: finite entries;
* a group element X (..., m, m), or q (..., 4) / (..., 8) for unit (dual)
  quaternions: :func:`elements`. Every function taking elements checks every one
  of them, ``compose`` both of its arguments.

A function first tries its *single-element fast path*: an ndarray of exactly
one argument's shape and dtype float64 (any memory order; GTSAM's ``.matrix()``
is Fortran-ordered) is checked and computed in ONE numba call, the entry point
(:func:`lie_factors.kernels.jit.entry_point`) of :func:`one` or :func:`one_pair`
specialized for the group and the operation. That kernel returns False when the
input must take the general path, whose checks (:mod:`lie_factors.kernels.validate`,
:func:`elements`) raise the :class:`~lie_factors.errors.InputError` (a ``ValueError``)
naming the problem (the fast path's checks, :mod:`lie_factors.kernels.checks`, are
the same tests, never accepting what they reject). Batches, lists, other dtypes and refused inputs take the general path:
validation, then :func:`many` over the flattened batch. Both paths run the same
cores, so a single element gives the batch path's result bit for bit.
``np.ascontiguousarray`` copies the input (at most 16 numbers) so that
the cores only ever see, and are only compiled for, C-ordered arrays.
Arguments are positional only (``se3.log(X)``, ``quaternion.compose(p, q)``).

:func:`one`, :func:`one_pair`, :func:`many` and :func:`many_pairs` are generic in
the group and the operation (their tags, :mod:`lie_factors.kernels.dispatch`), so
each (group, operation) is one specialization, cached on disk like any kernel
(and compiled afresh when a core changes: the group tag's type says which sources
it was compiled from).
"""

from __future__ import annotations

import functools
import inspect
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from . import checks as _check, dispatch as _dispatch, jit as _jit, validate as _validate
from .jit import kernel
from .registry import UNIT, GroupInfo

#: Kinds of argument and result: shapes (..., n), (..., m, m), (...,) + the element's, (..., n, n).
TANGENT, ALGEBRA, ELEMENT, JACOBIAN = "tangent", "algebra", "element", "jacobian"


@dataclass(frozen=True)
class Operation:
    """A public function of every group: its name (and its core's, ``_<name>``), the kinds
    of its arguments and result, what it computes, and its numba tag."""

    name: str
    args: tuple
    result: str
    doc: str

    @functools.cached_property
    def tag(self) -> _dispatch.Op:
        return _dispatch.Op(self.name, self.args[0] == ELEMENT)


OPERATIONS = (
    Operation("hat", (TANGENT,), ALGEBRA, "the Lie-algebra matrix of the tangent vector {0} (GTSAM's ``Hat``)."),
    Operation("vee", (ALGEBRA,), TANGENT,
              "the tangent vector of the Lie-algebra matrix {0}, the inverse of ``hat`` (GTSAM's ``Vee``); "
              "reads the entries ``hat`` writes."),
    Operation("exp", (TANGENT,), ELEMENT, "Exp({0}), the group element of the tangent vector {0} (GTSAM's ``Expmap``)."),
    Operation("log", (ELEMENT,), TANGENT,
              "Log({0}), the principal logarithm: Exp(Log({0})) = {0} with rotation angle ≤ π (GTSAM's ``Logmap``)."),
    Operation("ad", (TANGENT,), JACOBIAN, "ad_{0}, the matrix of y ↦ vee([hat {0}, hat y]) (GTSAM's ``adjointMap``)."),
    Operation("Ad", (ELEMENT,), JACOBIAN, "Ad({0}), the matrix of y ↦ vee({0}·hat(y)·{0}⁻¹) (GTSAM's ``AdjointMap``)."),
    Operation("dexp", (TANGENT,), JACOBIAN,
              "the left Jacobian D_exp({0}) = Σ ad^i/(i+1)! (Eade, \"Derivative of the Exponential Map\", Eq. 35): "
              "exp({0} + ε) ≈ exp(dexp({0})·ε)·exp({0}). GTSAM's ``ExpmapDerivative({0})`` is the right Jacobian, "
              "dexp(−{0})."),
    Operation("dlog", (TANGENT,), JACOBIAN,
              "D_exp({0})⁻¹, the inverse of ``dexp`` (GTSAM's ``LogmapDerivative({0})`` is dlog(−{0}))."),
    Operation("compose", (ELEMENT, ELEMENT), ELEMENT,
              "{0}·{1}, the group product; batch axes broadcast (GTSAM's ``compose``)."),
    Operation("inverse", (ELEMENT,), ELEMENT, "{0}⁻¹, the group inverse (GTSAM's ``inverse``)."),
)

#: What the unit (dual) quaternions have.
QUATERNION_OPERATIONS = ("exp", "log", "compose", "inverse")


@kernel
def one(g, op, x, out):
    """``op`` of group ``g`` on one argument ``x`` (any memory order) into ``out``.

    Returns False, ``out`` untouched, when ``x`` is refused (see the module docstring)."""
    x = np.ascontiguousarray(x)
    if not _dispatch.accepts(g, op, x):
        return False
    _dispatch.call(g, op, x, out)
    return True


@kernel
def one_pair(g, op, x, y, out):
    """:func:`one` for an operation of two arguments."""
    x = np.ascontiguousarray(x)
    y = np.ascontiguousarray(y)
    if not (_dispatch.accepts(g, op, x) and _dispatch.accepts(g, op, y)):
        return False
    _dispatch.call2(g, op, x, y, out)
    return True


@kernel
def many(g, op, x, out):
    """``op`` of group ``g`` on every element of the batch ``x`` (N, ...) into ``out`` (N, ...),
    both C-ordered, ``x`` already validated: the general path's loop."""
    for i in range(x.shape[0]):
        _dispatch.call(g, op, x[i], out[i])


@kernel
def many_pairs(g, op, x, y, out):
    """:func:`many` for an operation of two arguments."""
    for i in range(x.shape[0]):
        _dispatch.call2(g, op, x[i], y[i], out[i])


def apply(g, op, x: np.ndarray, ndim: int, out_shape: tuple) -> np.ndarray:
    """``op`` of group ``g`` on every element of ``x``, broadcasting leading axes.

    ``x`` has shape ``batch + shape`` (``ndim`` trailing axes); the result has shape
    ``batch + out_shape``. ``x`` must already be a validated float64 array. The loop
    (:func:`many`) is cached on disk for each group and operation, like the cores.
    """
    batch = x.shape[: x.ndim - ndim]
    flat = np.ascontiguousarray(x.reshape((-1,) + x.shape[x.ndim - ndim:]))
    out = np.empty((flat.shape[0],) + out_shape)
    if flat.shape[0]:
        many(g, op, flat, out)
    return out.reshape(batch + out_shape)


def apply2(g, op, x: np.ndarray, y: np.ndarray, ndim: int, out_shape: tuple) -> np.ndarray:
    """Two-argument version of :func:`apply`; the batch shapes of ``x`` and ``y`` broadcast."""
    batch = np.broadcast_shapes(x.shape[: x.ndim - ndim], y.shape[: y.ndim - ndim])
    fx, fy = (np.ascontiguousarray(np.broadcast_to(a, batch + a.shape[a.ndim - ndim:]).reshape(
        (-1,) + a.shape[a.ndim - ndim:])) for a in (x, y))
    out = np.empty((fx.shape[0],) + out_shape)
    if fx.shape[0]:
        many_pairs(g, op, fx, fy, out)
    return out.reshape(batch + out_shape)


_ND, _F64, _empty = np.ndarray, np.dtype(np.float64), np.empty


def shape(kind: str, info: GroupInfo) -> tuple:
    """The shape of one argument or result of ``kind`` for the group ``info``."""
    if kind == TANGENT:
        return (info.dim,)
    if kind == JACOBIAN:
        return (info.dim, info.dim)
    if kind == ALGEBRA:
        return (info.mat, info.mat)
    return info.element


def _names(op: Operation, info: GroupInfo) -> tuple:
    if op.args[0] == TANGENT:
        return ("x",)
    if op.args[0] == ELEMENT and info.corner == UNIT:
        return ("p", "q") if len(op.args) == 2 else ("q",)
    return ("X", "Y")[: len(op.args)]


def elements(X, info: GroupInfo, name: str = "X") -> np.ndarray:
    """The general path's check of group elements: ``X`` as float64 elements of ``info`` (shape
    ``(...,) + info.element``), or :class:`~lie_factors.errors.InputError` naming the first
    defect, in the order of :func:`lie_factors.kernels.checks.element_code`, that some element has."""
    if info.corner == UNIT:
        return _validate.unit(X, info, name)
    arr = _validate.square(X, info.mat, name)
    flat = np.ascontiguousarray(arr.reshape((-1, info.mat, info.mat)))
    code = _check.worst_code(flat, info.rot_dim, info.corner) if flat.shape[0] else _check.OK
    if code != _check.OK:
        raise InputError(f"{name}: {_validate.defect(code, info, arr)}")
    return arr


def _validator(kind: str, info: GroupInfo):
    """The general path's check of one argument: ``check(a, name)`` → float64 array or InputError."""
    if kind == TANGENT:
        return functools.partial(_validate.tangent, n=info.dim)
    if kind == ALGEBRA:
        return functools.partial(_validate.square, m=info.mat)
    return functools.partial(elements, info=info)


def _fast(info: GroupInfo, op: Operation):
    """The fast path's call ``fast(g, tag, *arrays, out) → bool`` for ``op`` of ``info``: the entry
    point of :func:`one` or :func:`one_pair`, compiled or loaded from the on-disk cache now."""
    ndim = len(shape(op.args[0], info))
    argtypes = (info._numba_type_, op.tag._numba_type_) + (_jit.ANY[ndim],) * len(op.args)
    argtypes += (_jit.C[len(shape(op.result, info))],)
    return _jit.entry_point(one if len(op.args) == 1 else one_pair, argtypes)


def _doc(op: Operation, info: GroupInfo, names: tuple) -> str:
    def text(kind):
        return "(..., " + ", ".join(map(str, shape(kind, info))) + ")"

    kind = op.args[0]
    if kind == ELEMENT:
        raises = f"every {' and every '.join(names)} is {_validate.rule(info)}"
    else:
        raises = f"{names[0]} has shape {text(kind)} and finite entries"
    return (f"{op.name}({', '.join(names)}): {' × '.join(text(k) for k in op.args)} → {text(op.result)}, "
            f"{op.doc.format(*names)}\n\nRaises InputError (a ValueError) unless {raises}. "
            f"The closed form and its sources: :mod:`{info.module}`.")


def _function(info: GroupInfo, op: Operation):
    """The public function ``op`` of group ``info``: the fast path, else the general one.

    Its arguments are positional (``__signature__`` names them as the docstring does)."""
    names = _names(op, info)
    arg_shape = shape(op.args[0], info)
    G, OP, ARG, OUT, NDIM = info, op.tag, arg_shape, shape(op.result, info), len(arg_shape)
    check = _validator(op.args[0], info)

    def compile_then_call(*args):  # the fast path's call, compiled (or loaded) on first use
        nonlocal fast
        fast = _fast(info, op)
        return fast(*args)

    fast = compile_then_call
    if len(op.args) == 1:
        def function(a, /):
            if type(a) is _ND and a.shape == ARG and a.dtype is _F64:
                out = _empty(OUT)
                if fast(G, OP, a, out):
                    return out
            return apply(G, OP, check(a, name=names[0]), NDIM, OUT)
    else:
        def function(a, b, /):
            if (type(a) is _ND and type(b) is _ND and a.shape == ARG and b.shape == ARG
                    and a.dtype is _F64 and b.dtype is _F64):
                out = _empty(OUT)
                if fast(G, OP, a, b, out):
                    return out
            return apply2(G, OP, check(a, name=names[0]), check(b, name=names[1]), NDIM, OUT)

    function.__name__ = function.__qualname__ = op.name
    function.__module__ = info.module
    function.__doc__ = _doc(op, info, names)
    function.__signature__ = inspect.Signature(  # type: ignore[attr-defined]
        [inspect.Parameter(n, inspect.Parameter.POSITIONAL_ONLY) for n in names])
    return function


def functions(info: GroupInfo, namespace: dict) -> tuple:
    """The public functions of group ``info`` on the cores ``namespace["_<name>"]``, in the
    order of :data:`OPERATIONS` (for the unit quaternions: exp, log, compose, inverse)."""
    ops = [op for op in OPERATIONS if info.corner != UNIT or op.name in QUATERNION_OPERATIONS]
    missing = [op.name for op in ops if f"_{op.name}" not in namespace]
    if missing:
        raise AttributeError(f"{info.module} has no core _{', _'.join(missing)}")
    return tuple(_function(info, op) for op in ops)
