"""GTSAM Between/Prior factors whose Jacobians come from the closed-form dlog.

Drop-in replacements for GTSAM's own factors, same names and arguments::

    from lie_factors.factors import BetweenFactorPose3, PriorFactorPose3
    graph.add(BetweenFactorPose3(1, 2, measured, noise))

Each constructor returns a :class:`gtsam.CustomFactor` subclass, so the factor
works wherever a native one does (NonlinearFactorGraph, LevenbergMarquardt,
GaussNewton, Dogleg, ISAM2, Marginals).

Errors are GTSAM's definitions: ``Log(measured⁻¹ · X1⁻¹ · X2)`` for Between and
``Log(prior⁻¹ · X)`` for Prior. Jacobians are with respect to GTSAM's right
retraction ``X · Exp(δ)``. With ``dlog(x) = D_exp(x)⁻¹`` the inverse *left*
Jacobian (Eade, "Derivative of the Exponential Map", Eq. 40) and ``J_r(x) = D_exp(−x)``:

* ``X2 → X2·Exp(δ)``: ``E → E·Exp(δ)`` so ``e → e + J_r(e)⁻¹ δ``:
  ``H2 = dlog(−e)``.
* ``X1 → X1·Exp(δ)``: ``M⁻¹·Exp(−δ) = Exp(−Ad(M⁻¹) δ)·M⁻¹``, so
  ``E → Exp(−Ad(M⁻¹) δ)·E`` and ``e → e − J_l(e)⁻¹ Ad(M⁻¹) δ``:
  ``H1 = −dlog(e) · Ad(M⁻¹)``, where ``Ad(M⁻¹)`` is constant per factor and
  computed once at construction.
* Prior: ``H = dlog(−e)`` (the X2 case with ``M = prior``, ``X1 = I``).

GTSAM's own ``BetweenFactorSimilarity3`` has H1 = −Ad((X1⁻¹X2)⁻¹), H2 = I (no
Logmap derivative); these are exact.

The numerical work of one evaluation (inverse, compose, log, dlog and the
product with ``Ad(M⁻¹)``) is a single call of :func:`between` / :func:`prior`,
numba kernels over the group modules' cores (the same cores the public
broadcasting functions run); the batch solver loops over the same two kernels.

:class:`EvaluationPlan` evaluates every factor of this module in a graph with
one call of :func:`between_many` (a loop over :func:`between`) per group, for
a ``Values`` object an optimizer holds; the factors' callbacks, handed that
object, return their rows (used by :mod:`lie_factors.optimizers`).

Printing: a factor prints (``print()``, ``str``, ``repr``) what GTSAM's own
factor of the same class, keys, value and noise model prints, by asking that
factor (:meth:`as_gtsam`). A graph is printed by GTSAM's C++ code, which calls
C++'s ``CustomFactor::print`` ("CustomFactor on 0", no value) whatever Python
defines; so importing this module also makes ``gtsam.NonlinearFactorGraph``'s
``print`` and ``repr`` print a graph that holds factors of this module as the
graph with GTSAM's own in their places. A graph without any prints exactly as
before (GTSAM's own methods run on the graph itself).
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from dataclasses import dataclass
from types import ModuleType

import gtsam
import numpy as np
from gtsam import gtsam as _native  # the compiled extension: GTSAM's own classes, whatever is assigned into the package

from .kernels import registry as _registry, validate as _validate
# The codes of check_element (validate.defect words them).
from .kernels.checks import BAD_LAST_ROW, BAD_SCALE, NOT_FINITE, NOT_ORTHONORMAL, OK, REFLECTION  # noqa: F401
from .errors import ArgumentTypeError, InputError, ValuesIncorrectType, ValuesKeyDoesNotExist
from .interop import pose3_from_rows
# The compiled work of every factor here, also run by the batch loops and the smoother.
from .kernels.relative import (between, between_error, between_first_jacobian, between_jacobians,  # noqa: F401
                               between_many, between_relative, between_setup, check_element, prior,
                               prior_error, prior_jacobian, prior_relative)
from .kernels.registry import GroupInfo

__all__ = [
    "BetweenFactorRot3",
    "BetweenFactorPose3",
    "BetweenFactorPose2",
    "BetweenFactorSimilarity2",
    "BetweenFactorSimilarity3",
    "PriorFactorRot3",
    "PriorFactorPose3",
    "PriorFactorPose2",
    "PriorFactorSimilarity2",
    "PriorFactorSimilarity3",
    "GROUPS",
    "warm_up",
    "warm_up_constructed",
]


#: Groups whose factors were constructed in this process (see :func:`warm_up_constructed`).
_constructed: set = set()

#: Identity of each group, Fortran-ordered like the matrices GTSAM hands out (so
#: a Prior factor's call of :func:`between` has the Between factors' signature).
_IDENTITY = {name: np.asfortranarray(np.eye(g.mat)) for name, g in _registry.GROUPS.items()}


def warm_up(group) -> None:
    """Compile (or load from the on-disk cache) what evaluating a factor of ``group`` runs.

    Called before an optimization clock starts, so that reported seconds never
    include compilation. The layouts are those the factors pass: GTSAM hands
    out Fortran-ordered matrices, our own buffers are C-ordered.
    """
    n, m = group.dim, group.mat
    I = _IDENTITY[group.name]
    Minv, Ad = np.eye(m), np.eye(n)
    e, H1, H2 = np.empty(n), np.empty((n, n)), np.empty((n, n))
    between(group, Minv, Ad, I, I, e, H1, H2)


def warm_up_constructed() -> None:
    """:func:`warm_up` every group a factor of this module was constructed on."""
    for group in list(_constructed):
        warm_up(group)


@dataclass(frozen=True)
class GroupSpec:
    """A group of :mod:`lie_factors.kernels.registry` as GTSAM holds it; its facts (``dim``,
    ``mat``, ``rot_dim`` …) are read through from ``group``."""

    name: str  # GTSAM class name, e.g. "Pose3"
    cls: type  # gtsam.Pose3
    group: GroupInfo  # the group's facts and kernel tag, e.g. registry.SE3
    at: str  # Values accessor, e.g. "atPose3"

    def __getattr__(self, fact):
        if fact == "group":  # not set yet (copy, unpickling): no facts to read through
            raise AttributeError(fact)
        return getattr(self.group, fact)

    @property
    def kernels(self) -> ModuleType:
        return importlib.import_module(self.group.module)

    def matrix(self, value) -> np.ndarray:
        return np.asarray(value.matrix(), dtype=np.float64)


#: GTSAM type name → its :class:`GroupSpec`, for every matrix group of the registry.
GROUPS = {info.gtsam: GroupSpec(info.gtsam, getattr(gtsam, info.gtsam), info, f"at{info.gtsam}")
          for info in _registry.GROUPS.values()}


def element_error(spec: GroupSpec, X: np.ndarray, code: int, what: str, factor: str) -> InputError:
    """The error for a failed :func:`check_element` ``code`` of ``what`` (``X``) in ``factor``."""
    return InputError(f"{factor}: {what}: {_validate.defect(code, spec.group, np.asarray(X))}")


def _check_type(spec: GroupSpec, value, what: str, factor: str) -> None:
    if not isinstance(value, spec.cls):
        raise ArgumentTypeError(f"{factor}: {what} must be a gtsam.{spec.name}, got {type(value).__name__}")


#: tangent dimension → the noise model last found to fit it. Graphs typically
#: share one noise model object among many factors; GTSAM noise models are
#: immutable, and holding the object (not its id) makes ``is`` exact.
_noise_checked: dict = {}


def _checked_noise(spec: GroupSpec, noise_model, factor: str):
    if not isinstance(noise_model, gtsam.noiseModel.Base):
        raise ArgumentTypeError(f"{factor}: noise_model must be a gtsam.noiseModel, got {type(noise_model).__name__}")
    if noise_model.dim() != spec.dim:
        raise InputError(
            f"{factor}: noise model has dimension {noise_model.dim()}, "
            f"but {spec.name} has dimension {spec.dim}"
        )
    _noise_checked[spec.dim] = noise_model
    return noise_model


def checked_key(key, factor: str) -> int:
    """``key`` as an int, or an :class:`~lie_factors.errors.ArgumentTypeError` (a ``TypeError``)
    naming ``factor`` for anything but a non-negative integer."""
    if type(key) is int and key >= 0:  # the common case, without the tuple isinstance checks
        return key
    if isinstance(key, (bool, np.bool_)) or not isinstance(key, (int, np.integer)) or key < 0:
        raise ArgumentTypeError(f"{factor}: keys must be non-negative integers, got {key!r}")
    return int(key)


def read_key(values, key: int, accessor: str, type_name: str, factor: str):
    """``values.<accessor>(key)``, GTSAM's object; a key missing from ``values`` raises
    :class:`~lie_factors.errors.ValuesKeyDoesNotExist`, a key holding another type
    :class:`~lie_factors.errors.ValuesIncorrectType` (GTSAM's two cases, each naming the key
    with GTSAM's key formatter and the type ``factor`` reads)."""
    try:
        return getattr(values, accessor)(key)
    except RuntimeError:
        name = gtsam.DefaultKeyFormatter(key)
        if not values.exists(key):
            raise ValuesKeyDoesNotExist(f"{factor}: key {name} is not in the Values (the factor reads a "
                                        f"{type_name} there)") from None
        raise ValuesIncorrectType(f"{factor}: key {name} holds a value of another type than the "
                                  f"{type_name} the factor reads") from None


def _fetch(values, key: int, spec: GroupSpec, factor: str) -> np.ndarray:
    return spec.matrix(read_key(values, key, spec.at, f"gtsam.{spec.name}", factor))


class _Factor(gtsam.CustomFactor):
    """A Between factor, or a Prior factor as the Between factor from the identity
    (``_key1`` None): error Log(M⁻¹·X1⁻¹·X2), Jacobians H1 = −dlog(e)·Ad(M⁻¹), H2 = dlog(−e)."""

    spec: GroupSpec

    def _setup(self, key1, key2, value, what: str, noise_model) -> None:
        # Graphs of 1e5 factors are built in Python loops: the common case (int
        # keys, the exact GTSAM type, a noise model already checked) runs with
        # no helper call; anything else goes through the checking helpers.
        spec = self.spec
        group = spec.group
        if type(value) is not spec.cls:
            _check_type(spec, value, what, type(self).__name__)
        if _noise_checked.get(group.dim) is not noise_model:
            _checked_noise(spec, noise_model, type(self).__name__)
        M = value.matrix()
        Minv = np.empty((group.mat, group.mat))
        AdMinv = np.empty((group.dim, group.dim))
        code = between_setup(group, M, Minv, AdMinv)
        if code != OK:
            raise element_error(spec, M, code, what, type(self).__name__)
        _constructed.add(group)
        gtsam.CustomFactor.__init__(self, noise_model, [key2] if key1 is None else [key1, key2], self._evaluate)
        self._noise = noise_model  # the batch solver reads it without a C++ round trip
        self._key1 = key1
        self._key2 = key2
        self._Minv = Minv
        self._AdMinv = AdMinv

    def as_gtsam(self):
        """GTSAM's own factor of this class (``gtsam.BetweenFactorPose3`` ...): the same keys,
        the measured (or prior) value and the same noise model object, so the same error."""
        if self._key1 is None:
            return getattr(_native, f"PriorFactor{self.spec.name}")(self._key2, self._prior, self._noise)
        return getattr(_native, f"BetweenFactor{self.spec.name}")(self._key1, self._key2, self._measured,
                                                                   self._noise)

    def print(self, s: str = "Factor\n", keyFormatter=_native.DefaultKeyFormatter) -> None:
        """Print as GTSAM's own factor prints (its keys, value and noise model), to standard output."""
        self.as_gtsam().print(s, keyFormatter)

    def __repr__(self, s: str = "Factor\n", keyFormatter=_native.DefaultKeyFormatter) -> str:
        """What :meth:`print` prints (``str`` too), as GTSAM's factors' ``repr`` does."""
        if not hasattr(self, "_measured" if isinstance(self, BetweenFactor) else "_prior"):
            # construction failed or did not run: there is no value to print
            return object.__repr__(self)
        return self.as_gtsam().__repr__(s, keyFormatter)

    def _evaluate(self, this, values, H):
        plan = _prepared
        slot = plan.slots.get(self) if plan is not None and plan.values is values else None
        if slot is not None:  # computed for this very Values: (e, H1, H2), views of this factor's rows
            e, H1, H2 = slot
        else:
            spec = self.spec
            group = spec.group
            key1 = self._key1
            X1 = _IDENTITY[group.name] if key1 is None else _fetch(values, key1, spec, type(self).__name__)
            X2 = _fetch(values, self._key2, spec, type(self).__name__)
            n = group.dim
            e = np.empty(n)
            H1 = np.empty((n, n))
            H2 = np.empty((n, n))
            between(group, self._Minv, self._AdMinv, X1, X2, e, H1, H2)
        if H is not None:
            if self._key1 is None:
                H[0] = H2
            else:
                H[0] = H1
                H[1] = H2
        return e


class BetweenFactor(_Factor):
    """Between factor on ``spec``: error Log(measured⁻¹·X1⁻¹·X2), analytic Jacobians.

    Use the named constructors (``BetweenFactorPose3`` ...). Jacobians: see the
    module docstring (H1 = −dlog(e)·Ad(measured⁻¹), H2 = dlog(−e)).
    """

    def __init__(self, key1, key2, measured, noise_model):
        if type(key1) is not int or type(key2) is not int or key1 < 0 or key2 < 0:
            key1 = checked_key(key1, type(self).__name__)
            key2 = checked_key(key2, type(self).__name__)
        self._setup(key1, key2, measured, "measured", noise_model)
        self._measured = measured

    def measured(self):
        """The measured relative transform, as the GTSAM object given."""
        return self._measured


class PriorFactor(_Factor):
    """Prior factor on ``spec``: error Log(prior⁻¹·X), Jacobian dlog(−e).

    Evaluated as the Between factor from the identity, Log(prior⁻¹·I⁻¹·X) (the
    same numbers: products with I are exact), so a graph of priors and
    between factors compiles one kernel, not two.
    """

    def __init__(self, key, prior, noise_model):
        if type(key) is not int or key < 0:
            key = checked_key(key, type(self).__name__)
        self._setup(None, key, prior, "prior", noise_model)
        self._prior = prior

    def prior(self):
        """The prior value, as the GTSAM object given."""
        return self._prior

    @property
    def _key(self) -> int:
        """The key of the variable (the Between factor's second)."""
        return self._key2


def _named(gtsam_name: str) -> tuple[type, type]:
    """``BetweenFactor<gtsam_name>`` and ``PriorFactor<gtsam_name>``, GTSAM's names and arguments."""
    spec = GROUPS[gtsam_name]
    facts = f"({spec.dim}-dim, tangent {spec.group.tangent})"
    between = type(f"BetweenFactor{gtsam_name}", (BetweenFactor,), {
        "spec": spec, "__module__": __name__,
        "__doc__": f"``BetweenFactor{gtsam_name}(key1, key2, measured: gtsam.{gtsam_name}, noise_model)`` {facts}."})
    prior = type(f"PriorFactor{gtsam_name}", (PriorFactor,), {
        "spec": spec, "__module__": __name__,
        "__doc__": f"``PriorFactor{gtsam_name}(key, prior: gtsam.{gtsam_name}, noise_model)`` {facts}."})
    return between, prior


BetweenFactorRot3, PriorFactorRot3 = _named("Rot3")
BetweenFactorPose3, PriorFactorPose3 = _named("Pose3")
BetweenFactorPose2, PriorFactorPose2 = _named("Pose2")
BetweenFactorSimilarity2, PriorFactorSimilarity2 = _named("Similarity2")
BetweenFactorSimilarity3, PriorFactorSimilarity3 = _named("Similarity3")


# --------------------------------------------------------------------------- #
# Printing a graph that holds factors of this module
# --------------------------------------------------------------------------- #

def as_printed(graph):
    """``graph`` with each factor of this module replaced by GTSAM's own (:meth:`_Factor.as_gtsam`),
    removed (null) slots kept so that the indices are the graph's; ``graph`` itself if it holds none."""
    factors = [graph.at(i) for i in range(graph.size())]
    if not any(isinstance(f, _Factor) for f in factors):
        return graph
    out = _native.NonlinearFactorGraph()
    for f in factors:
        out.add(f.as_gtsam() if isinstance(f, _Factor) else f)
    return out


def _print_graphs_as_gtsam() -> None:
    """Make ``gtsam.NonlinearFactorGraph``'s ``print`` and ``repr`` (so ``str``) print :func:`as_printed`
    graphs. GTSAM's C++ prints a graph's factors through C++'s virtual ``print``, which a Python
    subclass of ``CustomFactor`` cannot override; GTSAM's own methods still do the printing."""
    cls = _native.NonlinearFactorGraph
    if getattr(cls.print, "_gtsam_method", None) is not None:  # this module imported again (reload)
        return
    gtsam_print, gtsam_repr = cls.print, cls.__repr__

    def print(self, s: str = "NonlinearFactorGraph: ", keyFormatter=_native.DefaultKeyFormatter) -> None:
        gtsam_print(as_printed(self), s, keyFormatter)

    def __repr__(self, s: str = "NonlinearFactorGraph: ", keyFormatter=_native.DefaultKeyFormatter) -> str:
        return gtsam_repr(as_printed(self), s, keyFormatter)

    for method, original in ((print, gtsam_print), (__repr__, gtsam_repr)):
        method.__doc__ = (f"GTSAM's ``NonlinearFactorGraph.{method.__name__}`` of the graph with "
                          f"lie_factors' factors as GTSAM's own (:func:`{__name__}.as_printed`).\n\n"
                          + (original.__doc__ or ""))
        setattr(method, "_gtsam_method", original)
        setattr(cls, method.__name__, method)


_print_graphs_as_gtsam()


# --------------------------------------------------------------------------- #
# Evaluating every factor of a graph at once, for one Values object
# --------------------------------------------------------------------------- #

#: The plan whose results the factors' callbacks may return (see :class:`EvaluationPlan`).
_prepared = None


class _GroupEvaluation:
    """The factors of one group in a graph: constants stacked, results of the last evaluation."""

    def __init__(self, spec: GroupSpec, members: list):
        self.spec = spec
        keys = sorted({key for f in members for key in f.keys()})
        index = {key: i for i, key in enumerate(keys)}
        identity = len(keys)  # X[identity] = I: priors are Between factors from the identity
        self.keys = keys
        self.at = getattr(gtsam.Values, spec.at)
        n, m = spec.group.dim, spec.group.mat
        count = len(members)
        self.Minv = np.array([f._Minv for f in members]).reshape(count, m, m)
        self.AdMinv = np.array([f._AdMinv for f in members]).reshape(count, n, n)
        self.i1 = np.array([identity if f._key1 is None else index[f._key1] for f in members], dtype=np.int64)
        self.i2 = np.array([index[f._key2] for f in members], dtype=np.int64)
        self.X = np.empty((len(keys) + 1, m, m))
        self.X[identity] = np.eye(m)
        self.rows: np.ndarray | None = None  # Pose3: rows of extractPose3's output for self.keys
        self.total = 0
        self.e = np.empty((count, n))
        self.H1 = np.empty((count, n, n))
        self.H2 = np.empty((count, n, n))

    def _read_pose3(self, values) -> bool:
        """Fill X from one C++ pass over ``values`` (``utilities.extractPose3``: the rotation
        matrices' and translations' own entries, so X is what ``.matrix()`` gives)."""
        rows = gtsam.utilities.extractPose3(values)  # (every Pose3 in key order, 12)
        if self.rows is None:
            order = {key: j for j, key in enumerate(gtsam.utilities.allPose3s(values).keys())}
            self.rows = np.array([order[key] for key in self.keys], dtype=np.int64)
            self.total = len(order)
        if rows.shape[0] != self.total:
            return False
        pose3_from_rows(rows[self.rows], self.X[:-1])
        return True

    def evaluate(self, values) -> None:
        at, X = self.at, self.X
        if not (self.spec.name == "Pose3" and self._read_pose3(values)):
            for j, key in enumerate(self.keys):
                X[j] = at(values, key).matrix()
        # Written in place: the callbacks hand out views of these rows, which GTSAM
        # copies as it receives them.
        between_many(self.spec.group, self.Minv, self.AdMinv, X, self.i1, self.i2,
                     self.e, self.H1, self.H2)


class PlanBase(ABC):
    """What an evaluation plan shares (:class:`EvaluationPlan`, and the factor kinds'
    :class:`lie_factors.expressions.plan.KindPlan`): ``groups``, each with ``evaluate(values)``;
    ``prepared(values)``, the ``with`` block inside which the callbacks read the results; and
    :meth:`_activate`, which tells the plan's callbacks which plan is prepared (or None)."""

    groups: list

    def __bool__(self) -> bool:
        return bool(self.groups)

    def prepared(self, values):
        return _Prepared(self, values)

    @abstractmethod
    def _activate(self, plan) -> None:
        """Point the callbacks at ``plan`` (None: no plan prepared)."""


class EvaluationPlan(PlanBase):
    """Every factor of this module in ``graph``, evaluated in one kernel call per group.

    For an optimizer that holds its ``Values`` (:mod:`lie_factors.optimizers`)::

        plan = EvaluationPlan(graph)
        with plan.prepared(values):     # reads each variable once, evaluates every factor
            linear = graph.linearize(values)

    Inside the ``with``, each factor's callback, when GTSAM hands it that very
    ``values`` object, returns its row of the results (the same kernel,
    :func:`between`, on the same matrices) instead of fetching its variables
    and calling the kernel itself; for any other object it evaluates as usual.
    The ``values`` must not change inside the ``with`` (GTSAM's calls take it
    as ``const``), nor afterwards while the plan may see it again: results are
    reused when the same object is prepared twice in a row (an optimizer
    linearizes at the trial point it has just evaluated).  If reading the variables fails (a missing key, a wrong
    type), nothing is prepared and the callbacks raise their usual errors.
    """

    def __init__(self, graph: gtsam.NonlinearFactorGraph):
        members: dict = {}
        for i in range(graph.size()):
            f = graph.at(i)
            if isinstance(f, (BetweenFactor, PriorFactor)):
                members.setdefault(f.spec.name, []).append(f)
        self.groups = [_GroupEvaluation(GROUPS[name], fs) for name, fs in members.items()]
        self.slots: dict = {}  # factor → views (e, H1, H2) of its rows
        for res, fs in zip(self.groups, members.values()):
            self.slots.update(zip(fs, zip(res.e, res.H1, res.H2)))
        self.values = None
        self.last = None  # the Values the results were computed for
        for res in self.groups:  # compile (or load) before any clock an optimizer keeps
            warm_up(res.spec.group)
            none = np.empty(0, dtype=np.int64)
            between_many(res.spec.group, res.Minv[:0], res.AdMinv[:0], res.X, none, none,
                         res.e[:0], res.H1[:0], res.H2[:0])

    def _activate(self, plan) -> None:
        global _prepared
        _prepared = plan


class _Prepared:
    def __init__(self, plan: PlanBase, values):
        self.plan, self.values = plan, values

    def __enter__(self):
        plan, values = self.plan, self.values
        if plan.last is not values:
            plan.last = None
            try:
                for group in plan.groups:
                    group.evaluate(values)
            except Exception:  # the callbacks will report it, as without a plan
                return self
            # Held, so that its id cannot be reused by another object while it is `last`.
            plan.last = values
        plan.values = values
        plan._activate(plan)
        return self

    def __exit__(self, *exc):
        self.plan._activate(None)
        self.plan.values = None
        return False
