"""Expressions: what a residual is written in, recorded as it is written.

A factor's residual function is called once, when its kind is defined, on :class:`Expr`
placeholders of its variables and constants; every operation on them records a :class:`Node`
(its operation, inputs, output type and the line of the user's function that made it) instead
of computing.  The nodes are the expression the kind's kernel is generated from
(:mod:`lie_factors.expressions.codegen`).  An operation outside the vocabulary, or on the wrong
types, raises :class:`~lie_factors.errors.InputError` at once, naming the operation, the types
and the line; so does anything that would decide on a value while the residual is written
(a comparison, ``bool()``, ``abs()``, ``max()``, a numpy function), since the residual is
written once for every value.  Constant numbers and arrays mix with expressions (``v - 1.0``,
``np.ones(3) + v``, ``M @ v``): they become literals of the kernel.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .types import ValueType, matrix, value_type, vector


@dataclass(eq=False)
class Node:
    """One operation of an expression: ``op`` on ``inputs`` (nodes), giving a ``type``; ``attrs``:
    the operation's constant parameters (a variable's index, a scalar, a matrix, indices, a
    literal's value); ``line``: the line of the residual function that wrote it (None if
    unknown)."""

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
        return where(getattr(self.fn, "__qualname__", "the residual"), line)


def where(name: str, line: int | None) -> str:
    """``name, line N``: where a residual function wrote something."""
    return f"{name}, line {line}" if line is not None else name


def _where(line=None) -> str:
    trace = Trace.current
    if trace is None:
        return "an expression"
    return trace.where(trace.line() if line is None else line)


def fail(message: str) -> InputError:
    """The error of an operation being recorded, naming where the residual wrote it."""
    return InputError(f"{_where()}: {message}")


#: numpy's ufuncs that are the vocabulary's arithmetic (``np.ones(3) + v`` is ``v.__radd__``).
_UFUNCS = {"add": "add", "subtract": "sub", "multiply": "mul", "true_divide": "truediv", "divide": "truediv",
           "matmul": "matmul", "negative": "neg", "positive": "pos"}
_COMPARING = ("greater", "greater_equal", "less", "less_equal", "equal", "not_equal", "maximum", "minimum",
              "fmax", "fmin", "absolute", "fabs", "sign", "clip", "amax", "amin", "max", "min", "sort", "where")
_NUMPY_HINTS = {"cross": "write a.cross(b) or ops.cross(a, b)", "dot": "write a.dot(b)", "vdot": "write a.dot(b)",
                "inner": "write a.dot(b)", "norm": "write a.norm()", "concatenate": "write ops.stack(a, b, …)",
                "hstack": "write ops.stack(a, b, …)", "stack": "write ops.stack(a, b, …)",
                "append": "write ops.stack(a, b, …)", "transpose": "write M.T", "ravel": "write M.flatten()",
                "reshape": "write M.flatten(), or index the rows", "sum": "write v.dot(np.ones(n))",
                "square": "write v * v", "power": "write v * v"}


def _numpy_refusal(name: str) -> str:
    short = name.rsplit(".", 1)[-1]
    if short in _COMPARING:
        why = ("it compares values, and a residual cannot compare or branch on them: it is written once, "
               "for every value")
    else:
        why = _NUMPY_HINTS.get(short, "a numpy function does not apply to an expression; write it with the "
                                      "vocabulary's operations (norm, dot, cross, theta, rpy, bearing, …)")
    return f"{name} of an expression is not in the vocabulary: {why}"


def _numpy_name(func) -> str:
    module = getattr(func, "__module__", None) or "numpy"
    parts = module.split(".")
    sub = [p for p in parts[1:] if p in ("linalg", "fft", "random", "ma")]
    return "np." + "".join(f"{p}." for p in sub) + getattr(func, "__name__", "function")


class Expr:
    """A value of a residual being written: a variable, a constant, or an operation on them.

    The operations are GTSAM's names (``compose``, ``inverse``, ``between``,
    ``localCoordinates``, ``logmap``, ``retract``/``expmap``, ``rotation``, ``translation``,
    ``scale``, ``transformFrom``, ``transformTo``, ``transformPoseFrom``, ``transformPoseTo``,
    ``rotate``, ``unrotate``, ``range``, ``bearing``, ``theta``, ``rpy``/``ypr``/``roll``/
    ``pitch``/``yaw``, ``matrix``, ``AdjointMap``), vector arithmetic (``+``, ``-``, ``*`` by a
    number, a scalar expression or elementwise, ``/`` by a number or a scalar expression, ``@``,
    ``dot``, ``cross``, ``norm``, ``[i]``/``[i:j]``/``M[i, j]``, ``M.T``, ``M.flatten()``), with
    constant numbers and arrays on either side, and the functions of
    :mod:`lie_factors.expressions.ops`.
    """

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
        raise fail("a residual cannot branch on a value (an `if`, `and`, `or` or `not` on an expression): it "
                   "is written once, for every value; write it with the vocabulary's operations")

    def __float__(self):
        raise fail(f"a {self.node.type} expression is not a number: math functions and float() do not "
                   "apply; use the vocabulary's operations")

    __int__ = __index__ = __complex__ = __float__

    def __iter__(self):
        raise fail("an expression cannot be unpacked or iterated: index it, e[0], or slice it, e[0:2]")

    def _compare(self, symbol: str):
        raise fail(f"`{symbol}` compares two values (as max(), min() and sorted() do, which call it): a "
                   "residual cannot compare or branch on values, it is written once, for every value; write "
                   "it with the vocabulary's operations")

    def __eq__(self, other):
        self._compare("==")

    def __ne__(self, other):
        self._compare("!=")

    def __lt__(self, other):
        self._compare("<")

    def __le__(self, other):
        self._compare("<=")

    def __gt__(self, other):
        self._compare(">")

    def __ge__(self, other):
        self._compare(">=")

    __hash__ = object.__hash__  # by identity: comparing is refused, holding in a dict or set is not

    def __abs__(self):
        raise fail("abs() is not in the vocabulary: it decides on a value's sign (as max() and min() compare), "
                   "and a residual is written once, for every value; for a magnitude write v.norm()")

    def __pow__(self, other, modulo=None):
        raise fail("`**` is not in the vocabulary: write v * v (the elementwise product), v.dot(v) or v.norm()")

    __rpow__ = __pow__

    def _refused(self, *_):
        raise fail("this operator (//, %, divmod, <<, >>, &, |, ^, ~, round, floor, ceil, trunc) is not in the "
                   "vocabulary")

    __floordiv__ = __rfloordiv__ = __mod__ = __rmod__ = __divmod__ = __rdivmod__ = _refused
    __lshift__ = __rlshift__ = __rshift__ = __rrshift__ = __and__ = __rand__ = _refused
    __or__ = __ror__ = __xor__ = __rxor__ = __invert__ = __round__ = __floor__ = __ceil__ = __trunc__ = _refused

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        """numpy's arithmetic on an expression is the vocabulary's (``np.ones(3) + v``, ``M @ v``,
        ``np.float64(2) * v``); any other ufunc is refused, naming it."""
        op = _UFUNCS.get(ufunc.__name__)
        if op is None or method != "__call__" or kwargs:
            raise fail(_numpy_refusal(f"np.{ufunc.__name__}"))
        if len(inputs) == 1:
            return getattr(inputs[0], f"__{op}__")()
        a, b = inputs
        if isinstance(a, Expr):
            return getattr(a, f"__{op}__")(b)
        return getattr(b, f"__r{op}__")(a)

    def __array_function__(self, func, types, args, kwargs):
        raise fail(_numpy_refusal(_numpy_name(func)))

    # -- group operations
    def compose(self, other):
        return _record("compose", self, other)

    def inverse(self):
        return _record("inverse", self)

    def between(self, other):
        return _record("between", self, other)

    def localCoordinates(self, other):
        """Of two group elements: Log(self⁻¹·other).  Of two Unit3: GTSAM's coordinates of other
        in self's basis (2).  Of two cameras: GTSAM's ``PinholeCamera::localCoordinates``,
        [the poses' Log(P⁻¹·P'), the calibrations' K' − K]."""
        if self.node.type.kind == "camera" and isinstance(other, Expr) and other.node.type.kind == "camera":
            if self.node.type.name != other.node.type.name:
                raise fail(f"localCoordinates of a {self.node.type} and a {other.node.type}: both must be "
                           "of one camera type")
            return _record("stack", self.pose().localCoordinates(other.pose()),
                           other.calibration() - self.calibration())
        return _record("localCoordinates", self, other)

    def logmap(self):
        return _record("logmap", self)

    def retract(self, v):
        return _record("retract", self, v)

    expmap = retract

    def transformPoseFrom(self, other):
        """A pose aTb in this pose's frame, in the world's: this · aTb (GTSAM's
        ``Pose3.transformPoseFrom``, compose)."""
        self._pose3_only("transformPoseFrom")
        return self.compose(other)

    def transformPoseTo(self, other):
        """A pose wTb in this pose's frame: this⁻¹ · wTb (GTSAM's ``Pose3.transformPoseTo``,
        between)."""
        self._pose3_only("transformPoseTo")
        return self.between(other)

    def _pose3_only(self, op: str) -> None:
        if self.node.type.name != "Pose3":
            raise fail(f"{op} of a {self.node.type}: takes a Pose3 (GTSAM's); compose and between are "
                       "every group's")

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
        """The distance from this pose to a point, or to another pose's origin: GTSAM's
        ``Pose2.range`` and ``Pose3.range``, ‖p − t‖ in the world frame, whose Jacobians at
        distance ≤ 1e-10 are GTSAM's (norm's); of a similarity, ‖transformTo(self, p)‖."""
        if isinstance(other, Expr) and other.node.type.is_group:
            other = other.translation()
        if self.node.type.name in ("Pose2", "Pose3"):
            return (other - self.translation()).norm()
        return self.transformTo(other).norm()

    def bearing(self, other=None):
        """Of a Point2: its direction, a Rot2.  Of a pose and a point (or a pose's origin): the
        direction of the point in this pose's frame (GTSAM's ``Pose2.bearing``)."""
        if other is None:
            return _record("bearing", self)
        if isinstance(other, Expr) and other.node.type.is_group:
            other = other.translation()
        return _record("bearing", self.transformTo(other))

    def theta(self):
        """The angle of a Rot2, or of a Pose2's rotation, in (−π, π] (GTSAM's ``theta()``), a
        Vector1."""
        name = self.node.type.name
        if name == "Pose2":
            return self.rotation().logmap()
        if name == "Rot2":
            return self.logmap()
        raise fail(f"theta of a {name}: takes a Rot2 or a Pose2 (GTSAM's)")

    def rpy(self):
        """[roll, pitch, yaw] of a Rot3, R = Rz(yaw)·Ry(pitch)·Rx(roll) (GTSAM's ``Rot3.rpy``,
        its RQ decomposition); its Jacobian is refused within 1e-2 of pitch = π/2, as GTSAM's."""
        return _record("rpy", self)

    def ypr(self):
        """[yaw, pitch, roll] of a Rot3 (GTSAM's ``Rot3.ypr``)."""
        return self.rpy()[::-1]

    def roll(self):
        return self.rpy()[0]

    def pitch(self):
        return self.rpy()[1]

    def yaw(self):
        return self.rpy()[2]

    def pose(self):
        """A camera's pose (camera to world, z forward: GTSAM's ``PinholeCamera::pose()``), a
        Pose3; its Jacobian selects the camera tangent's first six entries."""
        return _record("camera_pose", self)

    def calibration(self):
        """A camera's calibration (GTSAM's ``PinholeCamera::calibration()``); its Jacobian
        selects the camera tangent's entries after the pose's."""
        return _record("camera_calibration", self)

    def project(self, point):
        """The pixel at which a camera sees ``point`` (GTSAM's ``PinholeCamera::project``):
        ``ops.project(camera.pose(), point, camera.calibration())``."""
        return project(self.pose(), point, self.calibration())

    def matrix(self):
        """The element's matrix (GTSAM's ``matrix()``), a matrix expression."""
        return _record("matrix", self)

    def AdjointMap(self):
        """The adjoint Ad(X) (n × n, GTSAM's ``AdjointMap()``: Ad(X)·ξ = Log-coordinates of
        X·Exp(ξ)·X⁻¹), a matrix expression."""
        if self.node.type.name == "Rot2":
            return _literal(np.ones((1, 1)), _line())
        return _record("adjoint_map", self)

    # -- vectors and matrices
    def dot(self, other):
        return _record("dot", self, other)

    def cross(self, other):
        """a × b of two 3-vectors (GTSAM's ``cross``)."""
        return _record("cross", self, other)

    def norm(self):
        return _record("norm", self)

    def __add__(self, other):
        return _offset("add", self, other)

    def __radd__(self, other):
        return _offset("add", other, self)

    def __sub__(self, other):
        return _offset("sub", self, other)

    def __rsub__(self, other):
        return _offset("sub", other, self)

    def __neg__(self):
        return _record("neg", self)

    def __pos__(self):
        return self

    def __mul__(self, other):
        return _product(self, other)

    def __rmul__(self, other):
        return _product(other, self)

    def __truediv__(self, other):
        if isinstance(other, Expr):
            return _record("div", self, other)
        if np.ndim(other) == 0:
            return _record("scale_by", self, divisor=other)
        raise fail("division by an array is not in the vocabulary: divide by a number or a scalar expression")

    def __rtruediv__(self, other):
        return _record("div", other, self)

    def __matmul__(self, other):
        if not isinstance(other, Expr):
            other = _literal(other, _line())
        if not self.node.type.is_matrix and not other.node.type.is_matrix:
            return self.dot(other)
        return _record("mat_mul", self, other)

    def __rmatmul__(self, other):
        if np.ndim(other) == 1:
            return self.dot(other)
        if self.node.type.is_matrix:
            return _record("mat_mul", other, self)
        return _record("matmul", self, matrix=other)

    def __getitem__(self, index):
        return _record("select", self, index=index)

    @property
    def T(self):
        """A matrix's transpose (a vector's is itself, as numpy's)."""
        return self.transpose()

    def transpose(self):
        t = self.node.type
        if not t.is_matrix:
            return self
        from .rules import TRANSPOSE

        return _record("select", self, index=TRANSPOSE)

    def flatten(self):
        """A matrix's entries row by row, a vector (numpy's ``flatten``)."""
        if not self.node.type.is_matrix:
            return self
        return _record("flatten", self)


#: The operations, for the message of an unknown one.
VOCABULARY = ("compose", "inverse", "between", "localCoordinates", "logmap", "retract", "expmap",
              "transformPoseFrom", "transformPoseTo", "rotation", "translation", "scale", "transformFrom",
              "transformTo", "rotate", "unrotate", "range", "bearing", "theta", "rpy", "ypr", "roll", "pitch",
              "yaw", "pose", "calibration", "project", "matrix", "AdjointMap", "dot", "cross", "norm", "+", "-",
              "*", "/", "@", "[]", "T", "flatten", "ops.expmap", "ops.project", "ops.stack", "ops.catch_cheirality")


def _line() -> int | None:
    trace = Trace.current
    return trace.line() if trace is not None else None


def _literal(value, line) -> Expr:
    """A constant number (a Vector1), 1-D array (a vector) or 2-D array (a matrix) written into
    the residual: a literal of the kernel."""
    if isinstance(value, (bool, np.bool_)):
        raise InputError(f"{_where(line)}: a bool is not a value of the vocabulary")
    if _holds_expression(value):
        raise InputError(f"{_where(line)}: a list or array of expressions is not a value: build the vector "
                         "with ops.stack(a, b, …)")
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{_where(line)}: a {type(value).__name__} is not a value of the residual: its inputs "
                         "are the variables, the constants (a measurement, a calibration, another pose: declare "
                         "it, lf.factor(..., name='Pose3'), and pass it at construction), constant numbers and "
                         "arrays, and expressions made from them") from None
    if a.ndim > 2 or a.size == 0:
        raise InputError(f"{_where(line)}: a constant array must be 1-D (a vector) or 2-D (a matrix), got "
                         f"shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{_where(line)}: a constant must be finite, got {a}")
    t = matrix(*a.shape) if a.ndim == 2 else vector(a.size)
    return Expr(Node("literal", t, (), {"value": a.reshape(-1)}, line))


def _holds_expression(value) -> bool:
    if isinstance(value, Expr):
        return True
    if isinstance(value, np.ndarray):
        return value.dtype == object and any(_holds_expression(v) for v in value.ravel())
    return isinstance(value, (list, tuple)) and any(_holds_expression(v) for v in value)


def _is_zero(value) -> bool:
    return not isinstance(value, (bool, np.bool_)) and isinstance(value, (int, float, np.number)) and value == 0


def _offset(op: str, a, b) -> Expr:
    """a + b or a − b, a constant on either side: a number adds to every entry (``v - 1.0``),
    an array entry by entry; adding 0 (``sum()``'s start) is the expression itself."""
    line = _line()
    x = a if isinstance(a, Expr) else b
    other = b if x is a else a
    if not isinstance(other, Expr):
        t = x.node.type
        if _is_zero(other) and not t.is_group:
            return x if (op == "add" or x is a) else -x
        raw, other = other, _literal(other, line)
        if np.ndim(raw) == 0 and not t.is_group:  # a number: to every entry
            full = np.full(t.dim, float(other.node.attrs["value"][0]))
            other = _literal(full.reshape(t.rows, t.cols) if t.is_matrix else full, line)
        a, b = (x, other) if x is a else (other, x)
    return _record(op, a, b)


def _product(a, b) -> Expr:
    """a · b: two group elements compose; a number scales; a scalar (one-entry) expression
    scales a vector or matrix; two vectors (or matrices) of one shape multiply entry by entry."""
    line = _line()
    if not isinstance(a, Expr) and np.ndim(a) == 0:
        return _record("scale_by", b, factor=a)
    if not isinstance(b, Expr) and np.ndim(b) == 0:
        return _record("scale_by", a, factor=b)
    a = a if isinstance(a, Expr) else _literal(a, line)
    b = b if isinstance(b, Expr) else _literal(b, line)
    ta, tb = a.node.type, b.node.type
    if ta.is_group or tb.is_group:
        if ta.is_group and tb.is_group:
            return _record("compose", a, b)
        raise InputError(f"{_where(line)}: {ta} * {tb}: `*` composes two group elements, or multiplies "
                         "vectors: by a number, a scalar expression or entry by entry")
    if ta.dim == 1 and tb.dim != 1:
        return _record("smul", a, b)
    if tb.dim == 1 and ta.dim != 1:
        return _record("smul", b, a)
    return _record("emul", a, b)


def project(pose: Expr, point: Expr, calibration) -> Expr:
    """:func:`lie_factors.expressions.ops.project`: the calibration of the point seen from the
    pose, divided by its depth (GTSAM's PinholeCamera), or GTSAM's StereoCamera's [uL, uR, v]."""
    seen = pose.transformTo(point)
    if isinstance(calibration, Expr) and calibration.type.name == "Cal3_S2Stereo":
        return _record("stereo", calibration, seen)
    return _record("uncalibrate", calibration, _record("pinhole", seen))


def constant_only(node: Node) -> bool:
    """Whether ``node`` depends on none of the factor's variables."""
    stack, seen = [node], set()
    while stack:
        n = stack.pop()
        if n.op == "variable":
            return False
        if id(n) not in seen:
            seen.add(id(n))
            stack.extend(n.inputs)
    return True


def _record(op: str, *inputs, **attrs) -> Expr:
    """Record ``op`` on ``inputs`` (expressions, or constant numbers and arrays, which become
    literals): its output type (:mod:`lie_factors.expressions.rules` checks the types), as a
    new node."""
    from .rules import output_type

    line = _line()
    nodes = [(x if isinstance(x, Expr) else _literal(x, line)).node for x in inputs]
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
