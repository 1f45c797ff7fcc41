"""Expressions: what a residual is written in, recorded as it is written.

A factor's residual function is called once, when its kind is defined, on :class:`Expr`
placeholders of its variables and constants; every operation on them records a :class:`Node`
(its operation, inputs, output type and the line of the user's function that made it) instead
of computing.  The nodes are the expression the kind's kernel is generated from
(:mod:`lie_factors.expressions.codegen`).  An operation outside the vocabulary, or on the wrong
types, raises :class:`~lie_factors.errors.InputError` at once, naming the operation, the types
and the line.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

from ..errors import InputError
from .types import ValueType, value_type


@dataclass(eq=False)
class Node:
    """One operation of an expression: ``op`` on ``inputs`` (nodes), giving a ``type``; ``attrs``:
    the operation's constant parameters (a variable's index, a scalar, a matrix, a slice);
    ``line``: the line of the residual function that wrote it (None if unknown)."""

    op: str
    type: ValueType
    inputs: tuple = ()
    attrs: dict = field(default_factory=dict)
    line: int | None = None


class Trace:
    """The recording in progress: the residual function being traced (for line numbers)."""

    current: "Trace | None" = None

    def __init__(self, fn):
        self.fn = fn
        self.code = getattr(fn, "__code__", None)

    def line(self) -> int | None:
        frame = sys._getframe(1)
        while frame is not None:
            if frame.f_code is self.code:
                return frame.f_lineno
            frame = frame.f_back
        return None

    def where(self, line: int | None) -> str:
        name = getattr(self.fn, "__qualname__", "the residual")
        return f"{name}, line {line}" if line is not None else name


def _where(line=None) -> str:
    trace = Trace.current
    if trace is None:
        return "an expression"
    return trace.where(trace.line() if line is None else line)


def fail(message: str) -> InputError:
    """The error of an operation being recorded, naming where the residual wrote it."""
    return InputError(f"{_where()}: {message}")


class Expr:
    """A value of a residual being written: a variable, a constant, or an operation on them.

    The operations are GTSAM's names (``compose``, ``inverse``, ``between``,
    ``localCoordinates``, ``logmap``, ``retract``/``expmap``, ``rotation``, ``translation``,
    ``scale``, ``transformFrom``, ``transformTo``, ``rotate``, ``unrotate``, ``range``,
    ``bearing``), vector arithmetic (``+``, ``-``, scalar ``*``, a constant matrix ``@``,
    ``dot``, ``norm``, ``[i]``/``[i:j]``), and the functions of :mod:`lie_factors.expressions.ops`.
    """

    __array_ufunc__ = None  # numpy defers to us: M @ expr is Expr.__rmatmul__, np.sin(expr) an error
    __slots__ = ("node",)

    def __init__(self, node: Node):
        self.node = node

    @property
    def type(self) -> ValueType:
        return self.node.type

    def __repr__(self) -> str:
        return f"<{self.node.type} expression: {self.node.op}>"

    # -- what is not in the vocabulary fails where it is written
    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        raise fail(f"{name} is not an operation of the vocabulary on a {self.node.type} "
                   f"(operations: {', '.join(VOCABULARY)})")

    def __bool__(self):
        raise fail("a residual cannot branch on a value (an `if` or `and` on an expression): write it "
                   "with the vocabulary's operations")

    def __float__(self):
        raise fail(f"a {self.node.type} expression is not a number: math functions and float() do not "
                   "apply; use the vocabulary's operations")

    __int__ = __index__ = __float__

    def __iter__(self):
        raise fail("an expression cannot be unpacked or iterated: index it, e[0], or slice it, e[0:2]")

    # -- group operations
    def compose(self, other):
        return _record("compose", self, other)

    def inverse(self):
        return _record("inverse", self)

    def between(self, other):
        return _record("between", self, other)

    def localCoordinates(self, other):
        return _record("localCoordinates", self, other)

    def logmap(self):
        return _record("logmap", self)

    def retract(self, v):
        return _record("retract", self, v)

    expmap = retract

    def rotation(self):
        return _record("rotation", self)

    def translation(self):
        return _record("translation", self)

    def scale(self):
        return _record("scale", self)

    def transformFrom(self, p):
        return _record("transformFrom", self, p)

    def transformTo(self, p):
        return _record("transformTo", self, p)

    def rotate(self, p):
        return _record("rotate", self, p)

    def unrotate(self, p):
        return _record("unrotate", self, p)

    def range(self, other):
        """The distance from this pose to a point, or to another pose's origin (GTSAM's
        ``Pose3.range``): ‖transformTo(self, p)‖."""
        return self._seen(other).norm()

    def bearing(self, other=None):
        """Of a Point2: its direction, a Rot2.  Of a pose and a point (or a pose's origin): the
        direction of the point in this pose's frame (GTSAM's ``Pose2.bearing``)."""
        if other is None:
            return _record("bearing", self)
        return _record("bearing", self._seen(other))

    def _seen(self, other):
        """``other`` (a point, or a pose's origin) in this pose's frame."""
        if isinstance(other, Expr) and other.node.type.is_group:
            other = other.translation()
        return self.transformTo(other)

    # -- vectors
    def dot(self, other):
        return _record("dot", self, other)

    def norm(self):
        return _record("norm", self)

    def __add__(self, other):
        return _record("add", self, other)

    def __radd__(self, other):
        return _record("add", other, self)

    def __sub__(self, other):
        return _record("sub", self, other)

    def __rsub__(self, other):
        return _record("sub", other, self)

    def __neg__(self):
        return _record("neg", self)

    def __mul__(self, other):
        if isinstance(other, Expr):
            if self.node.type.is_group and other.node.type.is_group:
                return _record("compose", self, other)
            raise fail(f"{self.node.type} * {other.node.type}: `*` composes two group elements or "
                       "scales a vector by a constant number")
        return _record("scale_by", self, factor=other)

    def __rmul__(self, other):
        return _record("scale_by", self, factor=other)

    def __truediv__(self, other):
        if isinstance(other, Expr):
            raise fail("division by an expression is not in the vocabulary")
        return _record("scale_by", self, divisor=other)

    def __matmul__(self, other):
        raise fail("`expr @ M`: write the constant matrix on the left, M @ expr")

    def __rmatmul__(self, other):
        return _record("matmul", self, matrix=other)

    def __getitem__(self, index):
        return _record("select", self, index=index)


#: The operations, for the message of an unknown one.
VOCABULARY = ("compose", "inverse", "between", "localCoordinates", "logmap", "retract", "expmap",
              "rotation", "translation", "scale", "transformFrom", "transformTo", "rotate", "unrotate",
              "range", "bearing", "dot", "norm", "+", "-", "*", "@", "[]", "ops.expmap", "ops.project",
              "ops.stack")


def _record(op: str, *inputs, **attrs) -> Expr:
    """Record ``op`` on ``inputs``: its output type (:mod:`lie_factors.expressions.ops` checks
    the types), as a new node."""
    from .rules import output_type

    trace = Trace.current
    line = trace.line() if trace is not None else None
    nodes = []
    for x in inputs:
        if not isinstance(x, Expr):
            raise InputError(f"{_where(line)}: {op} of a {type(x).__name__}: its inputs must be the "
                             "residual's variables, constants, or expressions made from them (a constant "
                             "number or matrix scales: 2.0 * v, M @ v)")
        nodes.append(x.node)
    try:
        t, attrs = output_type(op, tuple(n.type for n in nodes), attrs)
    except InputError as exc:
        raise InputError(f"{_where(line)}: {exc}") from None
    return Expr(Node(op, t, tuple(nodes), attrs, line))


def variable(index: int, t) -> Expr:
    """The placeholder of the factor's variable ``index`` (its keys' order), of type ``t``."""
    return Expr(Node("variable", value_type(t), (), {"index": index}))


def constant(index: int, name: str, t) -> Expr:
    """The placeholder of the factor's constant ``index`` (the measurement, a calibration)."""
    return Expr(Node("constant", value_type(t), (), {"index": index, "name": name}))
