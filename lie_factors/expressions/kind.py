"""Factor kinds: a residual written once in the vocabulary, a GTSAM factor class made from it.

::

    import lie_factors as lf

    @lf.factor("Pose2", "Point2", measured="Point2")
    def landmark(x, l, z):                 # x: the pose, l: the landmark, z: the measurement
        return x.transformTo(l) - z        # where the pose sees the landmark, less where it was seen

    graph.add(landmark(X(1), L(7), np.array([4.1, 0.5]), noise))

:func:`factor` traces the residual once on placeholders (:mod:`lie_factors.expressions.expr`),
generates the kind's kernel (:mod:`lie_factors.expressions.codegen`) and returns a subclass of
:class:`KindFactor`, a ``gtsam.CustomFactor``: it works in GTSAM's optimizers, ISAM2 and
Marginals, beside GTSAM's own factors, one compiled call per evaluation; and the batch solver
reads every factor of a kind into arrays and evaluates them in one call
(:mod:`lie_factors.batch.graph`).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import cached_property

import gtsam
import numpy as np

from ..errors import ArgumentTypeError, EvaluationError, InputError, ValuesIncorrectType
from ..factors import checked_key, read_key
from . import codegen
from .expr import Expr, Node, Trace, constant, variable, where
from .rules import FAULTS
from .types import CALIBRATIONS, ValueType, as_array, calibration_array, camera_array, value_type

__all__ = ["factor", "KindFactor", "Kind"]


@dataclass
class Kind:
    """A factor kind: its name, variables' and constants' types, residual (an expression
    :class:`Node`, dimension ``dim``) and compiled kernel (``evaluate``, see
    :mod:`lie_factors.expressions.codegen`; ``tags``: the group tags it takes first)."""

    name: str
    variables: list
    constant_names: list
    constants: list
    residual: Node
    source: str
    module: object
    nodes: list  # the kernel's nodes, in its order (a status names one)
    function: str  # the residual function's name, for messages
    #: whether its error is unchanged by one change of frame of all its variables (a Between's):
    #: the batch solver's structural check of the gauge counts such factors as anchoring nothing
    relative: bool = False

    def fault(self, code: int, keys: list, factor: str) -> Exception:
        """The exception of a factor (class ``factor``, its ``keys``) whose evaluation ended with
        the status ``code`` > 0 (:mod:`~lie_factors.expressions.codegen`)."""
        on = f"{factor} on {', '.join(gtsam.DefaultKeyFormatter(k) for k in keys)}"
        if code > len(self.nodes):
            return EvaluationError(f"{on}: {self.function}: the residual is not finite at these values")
        node = self.nodes[code - 1]
        cls, what = FAULTS[node.op]
        return cls(f"{on}: {where(self.function, node.line)}: {what}")

    @property
    def dim(self) -> int:
        return self.residual.type.dim

    # (cached: a callback reads them for every factor it evaluates)
    @cached_property
    def offsets(self) -> list[int]:
        """Each variable's first column in the kernel's Jacobian A (F, dim, Σ d_j)."""
        return [int(x) for x in np.cumsum([0] + [t.dim for t in self.variables])[:-1]]

    @cached_property
    def columns(self) -> int:
        return sum(t.dim for t in self.variables)

    @cached_property
    def blocks(self) -> list[tuple[int, int]]:
        """Each variable's columns (first, end) in A."""
        return [(o, o + t.dim) for o, t in zip(self.offsets, self.variables)]

    @cached_property
    def buffer_name(self) -> str:
        """The name of this kind's one-factor buffers in a thread's storage."""
        return self.name + str(id(self))

    @property
    def tags(self) -> tuple:
        tags = self.__dict__.get("_tags")
        if tags is None:
            from ..kernels import registry

            tags = self.__dict__["_tags"] = tuple(registry.BY_GTSAM[name] for name in self.module.TAGS)
        return tags

    def evaluate(self, *args) -> None:
        """The kernel (module docstring of :mod:`~lie_factors.expressions.codegen`), typed on
        its first call and then called through its compiled entry point."""
        self._entry(*args)

    @property
    def _entry(self):
        entry = self.__dict__.get("_direct")
        if entry is None:
            from ..kernels.jit import direct

            entry = self.__dict__["_direct"] = direct(self.module.evaluate)
        return entry


def _trace(fn, variables: list, names: list, constants: list) -> Node:
    trace = Trace(fn)
    args = [variable(j, t) for j, t in enumerate(variables)]
    args += [constant(c, names[c], t) for c, t in enumerate(constants)]
    previous, Trace.current = Trace.current, trace
    try:
        out = fn(*args)
    finally:
        Trace.current = previous
    if not isinstance(out, Expr):
        raise InputError(f"{trace.where(None)}: the residual must be an expression of the variables "
                         f"(a vector), got {type(out).__name__}")
    if out.node.type.is_group:
        raise InputError(f"{trace.where(out.node.line)}: the residual is a {out.node.type}, a group "
                         "element: return a vector, e.g. measured.localCoordinates(predicted)")
    if out.node.type.is_matrix:
        raise InputError(f"{trace.where(out.node.line)}: the residual is a {out.node.type}: return a vector, "
                         "e.g. the matrix's flatten()")
    if out.node.type.kind == "unit":
        raise InputError(f"{trace.where(out.node.line)}: the residual is a Unit3, a direction: return a "
                         "vector, e.g. measured.localCoordinates(predicted)")
    return out.node


def factor(*variables, measured=None, **constants):
    """Decorator: a factor kind from a residual function (module docstring).

    ``variables``: the types of the factor's variables, in its keys' order (``"Pose3"``,
    ``"Point3"``, ``"Vector4"``, ``"Rot2"``, GTSAM classes…).  ``measured``: the type of its
    measurement, or None for none; ``constants``: more constants by name and type (a calibration:
    ``K="Cal3_S2"``).  The residual function takes the variables, then the measurement, then the
    constants, and returns a vector expression.  Returns the factor class; its constructor is
    ``kind(key_1, …, key_k, measured, noise_model, **constants)``, GTSAM's argument order.
    """
    var_types = [value_type(t) for t in variables]
    names = (["measured"] if measured is not None else []) + list(constants)
    const_types = ([value_type(measured)] if measured is not None else []) + [value_type(t) for t in constants.values()]
    if not var_types:
        raise InputError("a factor needs at least one variable")
    if any(t.kind == "unit" or t.name == "StereoPoint2" for t in var_types):
        raise InputError("a Unit3 or a StereoPoint2 is a measurement, not a variable type of a factor")

    def define(fn):
        residual = _trace(fn, var_types, names, const_types)
        gen = codegen.Generator(fn.__name__, var_types, const_types, residual)
        source = gen.source() + f"\nTAGS = {tuple(gen.tags)!r}\n"
        kind = Kind(fn.__name__, var_types, names, const_types, residual, source,
                    codegen.load(fn.__name__, source), gen.nodes, getattr(fn, "__qualname__", fn.__name__))
        cls = type(fn.__name__, (KindFactor,), {
            "kind": kind, "__module__": getattr(fn, "__module__", __name__), "__qualname__": fn.__qualname__,
            "__doc__": fn.__doc__ or f"The factor kind {fn.__name__}: {', '.join(map(str, var_types))}.",
            "residual_function": staticmethod(fn)})
        return cls

    return define


_buffers = threading.local()

#: The :class:`~lie_factors.expressions.plan.KindPlan` inside whose ``prepared`` block GTSAM is
#: evaluating (its callbacks return the plan's rows for the Values it prepared), or None.
active_plan = None


class KindFactor(gtsam.CustomFactor):
    """A factor of a kind (made by :func:`factor`): ``kind(key_1, …, key_k, measured,
    noise_model, **constants)``.  ``keys()``, ``measured()``, ``constants()`` (name → array),
    ``noiseModel()``; its error is ½‖R·e‖² of the residual e, its Jacobians the chain rule's.
    Where the residual is undefined (a point behind a camera, a division by zero, a key missing
    from the Values), evaluating it raises a :class:`~lie_factors.errors.EvaluationError`."""

    kind: Kind

    def __init__(self, *args, **named):
        kind = self.kind
        name = type(self).__name__
        k = len(kind.variables)
        wanted = k + (1 if kind.constant_names[:1] == ["measured"] else 0) + 1
        extra = [c for c in kind.constant_names if c != "measured"]
        if len(args) != wanted:
            sig = ", ".join([f"key{j + 1}" for j in range(k)]
                            + (["measured"] if "measured" in kind.constant_names else []) + ["noise_model"]
                            + [f"{c}=…" for c in extra])
            raise ArgumentTypeError(f"{name}({sig}): got {len(args)} positional arguments")
        keys = [checked_key(key, name) for key in args[:k]]
        if len(set(keys)) != k:
            raise InputError(f"{name}: a factor's keys must differ, got "
                             f"{', '.join(gtsam.DefaultKeyFormatter(key) for key in keys)}")
        noise = args[-1]
        if not isinstance(noise, gtsam.noiseModel.Base):
            raise ArgumentTypeError(f"{name}: noise_model must be a gtsam.noiseModel, got {type(noise).__name__}")
        if noise.dim() != kind.dim:
            raise InputError(f"{name}: the noise model has dimension {noise.dim()}, the residual {kind.dim}")
        given = dict(zip(["measured"], args[k:-1])) if "measured" in kind.constant_names else {}
        unknown = set(named) - set(extra)
        if unknown:
            raise ArgumentTypeError(f"{name}: unknown constant(s) {sorted(unknown)}; the kind takes {extra or 'none'}")
        missing = [c for c in extra if c not in named]
        if missing:
            raise ArgumentTypeError(f"{name}: the constant(s) {missing} must be given")
        given.update(named)
        self._given = {c: given[c] for c in kind.constant_names}
        self._constants = [as_array(t, given[c], f"{name}: {c}")
                           for c, t in zip(kind.constant_names, kind.constants)]
        gtsam.CustomFactor.__init__(self, noise, keys, self._evaluate)
        self._keys_ = keys
        self._noise = noise

    def measured(self):
        """The measurement, as given (an AttributeError for a kind declared without one)."""
        if "measured" not in self._given:
            raise AttributeError(f"{type(self).__name__} has no measurement; its constants: {list(self._given)}")
        return self._given["measured"]

    def constants(self) -> dict:
        """Every constant (the measurement first), as the kernel holds them: name → array."""
        return dict(zip(self.kind.constant_names, self._constants))

    def evaluated(self, code: int) -> None:
        """What the status ``code`` ≠ 0 of an evaluation of this factor does: raise its
        :meth:`Kind.fault` (> 0), or, for a fault ``ops.catch_cheirality`` caught (< 0), what
        :meth:`on_cheirality` does (nothing here: the residual is the fallback)."""
        if code > 0:
            raise self.kind.fault(code, self._keys_, type(self).__name__)
        self.on_cheirality()

    def on_cheirality(self) -> None:
        """Called when ``ops.catch_cheirality`` gave this factor its fallback (a ready projection
        factor prints or raises here, as GTSAM's ``verboseCheirality``/``throwCheirality``)."""

    def silent_fallback(self) -> bool:
        """Whether :meth:`on_cheirality` does nothing (the fallback residual is all there is to
        it): a solver that never returns to Python mid-solve runs only such factors."""
        return True

    def _evaluate(self, this, values, H):
        plan = active_plan
        if plan is not None and plan.values is values:
            slot = plan.slots.get(self)
            if slot is not None:  # computed for this very Values, with every factor of the kind
                group, k = slot
                e, Hs = group.rows(k)
                if H is not None:
                    for j, block in enumerate(Hs):
                        H[j] = block
                return e
        kind = self.kind
        buf = getattr(_buffers, kind.buffer_name, None)
        if buf is None:
            buf = _Buffers(kind)
            setattr(_buffers, kind.buffer_name, buf)
        for j, (key, t) in enumerate(zip(self._keys_, kind.variables)):
            buf.X[j][0] = fetch(values, key, t, type(self).__name__)
        for c, value in enumerate(self._constants):
            buf.C[c][0] = value
        kind._entry(*buf.args, H is not None)
        code = buf.status[0]
        if code:
            self.evaluated(int(code))
        if H is not None:
            A = buf.A[0]
            for j, (o, end) in enumerate(kind.blocks):
                H[j] = A[:, o:end]
        return buf.e[0]


def check_statuses(factors: list, status: np.ndarray) -> None:
    """Each factor's :meth:`KindFactor.evaluated` for its status in ``status`` (one per factor,
    from one kernel call), in order; nothing when all are 0."""
    if status.any():
        for f in np.flatnonzero(status):
            factors[f].evaluated(int(status[f]))


class _Buffers:
    """One thread's arrays for evaluating one factor of ``kind`` (a callback's)."""

    def __init__(self, kind: Kind):
        m = kind.dim
        self.X = [np.zeros((1,) + t.shape) for t in kind.variables]
        self.C = [np.zeros((1,) + t.shape) for t in kind.constants]
        self.e = np.zeros((1, m))
        self.A = np.zeros((1, m, kind.columns))
        self.status = np.zeros(1, dtype=np.int64)
        index = np.zeros(1, dtype=np.int64)
        args = list(kind.tags)
        for X in self.X:
            args += [X, index]
        args += self.C
        args += [np.eye(m)[None], index, self.e, self.A, np.zeros((1, m)), np.zeros(1), self.status, 0, 1]
        self.args = args


def fetch(values, key: int, t: ValueType, factor: str) -> np.ndarray:
    """The value of a variable of type ``t`` at ``key`` in ``values`` as the kernel holds it;
    a missing key or one of another type raises GTSAM's named error
    (:func:`lie_factors.factors.read_key`)."""
    named = t.is_group or t.name in CALIBRATIONS or t.kind == "camera"
    value = read_key(values, key, t.accessor, f"gtsam.{t}" if named else t.name, factor)
    if t.is_group:
        if t.name == "Rot2":
            c, s = value.c(), value.s()
            return np.array([[c, -s], [s, c]])
        return value.matrix()
    if t.name in CALIBRATIONS:
        return calibration_array(t.name, value)
    if t.kind == "camera":
        return camera_array(t.name, value)
    a = np.asarray(value, dtype=np.float64)
    if a.shape != t.shape:
        raise ValuesIncorrectType(f"{factor}: key {gtsam.DefaultKeyFormatter(key)} holds a vector of shape "
                                  f"{a.shape}, not the {t} the factor reads")
    return a
