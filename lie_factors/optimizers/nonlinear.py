"""GTSAM's batch optimizers (Levenberg–Marquardt, Gauss–Newton, Dogleg), driven from Python.

Same constructors, methods and params objects as ``gtsam.LevenbergMarquardtOptimizer``,
``gtsam.GaussNewtonOptimizer`` and ``gtsam.DoglegOptimizer``; the same iterations
(GTSAM's NonlinearOptimizer.cpp, LevenbergMarquardtOptimizer.cpp,
LevenbergMarquardtState.h, DoglegOptimizer.cpp, DoglegOptimizerImpl.h are the
specification).  What differs is who owns the ``Values``: every linearization
point and every trial point is a ``gtsam.Values`` held by the optimizer as a
Python object, so ``CustomFactor`` callbacks receive that object instead of a
fresh copy of the whole ``Values`` each (see :mod:`lie_factors.optimizers`).

GTSAM does all numerical work: ``NonlinearFactorGraph.linearize`` / ``error``,
``Values.retract``, and elimination of ``GaussianFactorGraph``s (multifrontal or
sequential, Cholesky or QR, in the ordering of the params).  Levenberg–Marquardt's
damping is added as GTSAM's ``buildDampedSystem`` adds it: one
``JacobianFactor(key, A, 0, Isotropic(dim, 1/√λ))`` per variable, ``A = I`` or,
with ``diagonalDamping``, ``A = diag(√clamp(diag(JᵀJ), minDiagonal, maxDiagonal))``.

Levenberg–Marquardt's λ schedule, its trial of one λ, ``defaultOptimize`` and
what they print are :mod:`lie_factors.lm`'s, shared with the batch solver; this
module supplies how a step is solved, its linearized cost change computed and a
trial point evaluated.

Parameters the Python wrapper cannot set (``minModelFidelity``, ``minDiagonal``,
``maxDiagonal``) have GTSAM's defaults, as they do in GTSAM's optimizer when
called from Python.

Where this loop cannot run GTSAM's algorithm, the constructor returns GTSAM's own
optimizer instead (:meth:`_NonlinearOptimizer.__new__`): the ``ITERATIVE`` and
``CHOLMOD`` linear solvers, and a custom ordering set with ``params.setOrdering``
(the wrapper cannot read it back) when no ``ordering`` argument is given.
"""

from __future__ import annotations

import math
import sys

import numpy as np
from gtsam import gtsam  # the compiled extension: GTSAM's own classes, whatever is assigned into the package

from .. import dogleg, factors, lm
from ..expressions.plan import KindPlan

__all__ = ["LevenbergMarquardtOptimizer", "GaussNewtonOptimizer", "DoglegOptimizer"]

#: How GTSAM's IndeterminantLinearSystemException reads once pybind11 made it a RuntimeError.
_INDETERMINANT = "Indeterminate linear system"


def _is_indeterminant(exc: BaseException) -> bool:
    return isinstance(exc, RuntimeError) and _INDETERMINANT in str(exc)


class _Plans:
    """The evaluation plans of a graph's factors (our Between/Prior groups, the kinds) as one:
    true when either holds a factor; ``prepared(values)`` prepares both."""

    def __init__(self, *plans):
        self._plans = [p for p in plans if p]

    def __bool__(self) -> bool:
        return bool(self._plans)

    def prepared(self, values):
        import contextlib

        stack = contextlib.ExitStack()
        for plan in self._plans:
            stack.enter_context(plan.prepared(values))
        return stack


class _LinearizedCost:
    """The whitened Jacobian [A b] of one linearization, for GTSAM 4.3's linearized cost change.

    GTSAM 4.3's LM sums each factor's change ``½‖b‖² − ½‖Aδ − b‖²`` (``deltaError``)
    instead of subtracting two totals (which leaves rounding noise of the size of the
    total); here the same change is summed row by row, ``Σ (Aδ)ᵢ (bᵢ − ½(Aδ)ᵢ)``.
    ``diag`` is GTSAM's ``hessianDiagonal`` (column sums of A²).
    """

    def __init__(self, linear: gtsam.GaussianFactorGraph, dims: dict):
        ijs = linear.sparseJacobian_()  # whitened [A b], 1-based, variables in key order, b last
        self.keys = sorted(linear.keys())
        n = sum(dims[key] for key in self.keys)
        rows = ijs[0].astype(np.int64) - 1
        cols = ijs[1].astype(np.int64) - 1
        vals = ijs[2]
        m = int(rows.max()) + 1 if rows.shape[0] else 0
        in_a = cols < n
        self.rows, self.cols, self.vals = rows[in_a], cols[in_a], vals[in_a]
        self.b = np.zeros(m)
        self.b[rows[~in_a]] = vals[~in_a]
        self.m, self.n = m, n
        self.old = 0.5 * float(self.b @ self.b)
        self.dims = dims

    def hessian_diagonal(self) -> np.ndarray:
        return np.bincount(self.cols, weights=self.vals * self.vals, minlength=self.n)

    def change(self, delta: gtsam.VectorValues) -> float:
        """Linearized cost at 0 minus at ``delta``."""
        x = delta.vector(self.keys)
        ax = np.bincount(self.rows, weights=self.vals * x[self.cols], minlength=self.m)
        return float(ax @ (self.b - 0.5 * ax))


#: GTSAM's own optimizer for each params class, which the drop-in runs where its loop cannot.
_GTSAM_OPTIMIZER = {
    gtsam.GaussNewtonParams: gtsam.GaussNewtonOptimizer,
    gtsam.LevenbergMarquardtParams: gtsam.LevenbergMarquardtOptimizer,
    gtsam.DoglegParams: gtsam.DoglegOptimizer,
}

#: The linear solvers this loop runs, and the elimination function each passes to the
#: wrapper (None: its default, EliminatePreferCholesky, which GTSAM's optimizers use).
_ELIMINATION = {
    "MULTIFRONTAL_CHOLESKY": None,
    "SEQUENTIAL_CHOLESKY": None,
    "MULTIFRONTAL_QR": gtsam.EliminateQR,
    "SEQUENTIAL_QR": gtsam.EliminateQR,
}


def runs_in_python(params, ordering=None) -> bool:
    """Whether the drop-in runs its own loop for ``params`` (else GTSAM's own optimizer runs).

    It needs an elimination it can call through the wrapper (``_ELIMINATION``: not
    ``ITERATIVE``, whose PCG/subgraph solvers the wrapper does not expose on a
    linearization, nor ``CHOLMOD``, which GTSAM's optimizer rejects when it solves) and
    an ordering it can read: ``params.setOrdering`` stores one the wrapper cannot
    read back, so a ``CUSTOM`` ordering type needs the ``ordering`` argument.
    """
    return (params.getLinearSolverType() in _ELIMINATION
            and (ordering is not None or params.getOrderingType() != "CUSTOM"))


class _NonlinearOptimizer:
    """GTSAM's ``NonlinearOptimizer``: state (values, error, iterations), ``defaultOptimize``,
    ``solve`` of a linear system with the params' linear solver and ordering."""

    _params_type: type = gtsam.NonlinearOptimizerParams

    def __new__(cls, graph=None, initialValues=None, *args, **kwargs):
        """This class's optimizer, or GTSAM's own where this loop cannot run (:func:`runs_in_python`).

        GTSAM's optimizer (``gtsam.LevenbergMarquardtOptimizer``, ...) is then
        constructed from the same graph, values, params and ordering, and returned
        instead of an instance of this class: GTSAM's results, methods and
        exceptions, at GTSAM's speed. That is slower on graphs of Python factors:
        each ``CustomFactor`` callback receives a copy of the whole ``Values``
        (C++ holds every linearization and trial point), so an iteration costs
        time proportional to the number of factors times the size of the graph.
        """
        ordering, params = cls._parse(args, dict(kwargs))
        if isinstance(params, cls._params_type) and not runs_in_python(params, ordering):
            own = _GTSAM_OPTIMIZER[cls._params_type]
            if ordering is None:
                return own(graph, initialValues, params)
            # LM's wrapper has this overload; GN's and Dogleg's have none, so theirs raises TypeError.
            return own(graph, initialValues, ordering, params)
        return super().__new__(cls)

    @staticmethod
    def _parse(args, kwargs):
        """(ordering, params) of the arguments after (graph, initialValues): ``[params][, ordering]``."""
        names = ("params", "ordering")
        if len(args) > len(names) or set(kwargs) - set(names) or set(names[:len(args)]) & set(kwargs):
            raise TypeError("arguments: (graph, initialValues[, params][, ordering])")
        bound = dict(zip(names, args), **kwargs)
        return bound.get("ordering"), bound.get("params")

    def __init__(self, graph: gtsam.NonlinearFactorGraph, initialValues: gtsam.Values,
                 params=None, ordering: gtsam.Ordering | None = None):
        if not isinstance(graph, gtsam.NonlinearFactorGraph):
            raise TypeError(f"graph must be a gtsam.NonlinearFactorGraph, got {type(graph).__name__}")
        if not isinstance(initialValues, gtsam.Values):
            raise TypeError(f"initialValues must be a gtsam.Values, got {type(initialValues).__name__}")
        if params is None:
            params = self._params_type()
        if not isinstance(params, self._params_type):
            raise TypeError(f"params must be a gtsam.{self._params_type.__name__}, got {type(params).__name__}")
        if ordering is not None and not isinstance(ordering, gtsam.Ordering):
            raise TypeError(f"ordering must be a gtsam.Ordering, got {type(ordering).__name__}")
        # GTSAM's optimizer keeps its own copy of the graph (the same factors): factors
        # the user adds later are not optimized, here either.
        self._graph = gtsam.NonlinearFactorGraph()
        self._graph.push_back(graph)
        graph = self._graph
        self._params = params
        # The optimizer's own copy (GTSAM copies too): the user may change theirs.
        # It is held as a Python object, so callbacks evaluated on it receive it.
        self._values = gtsam.Values(initialValues)
        # lie_factors' factors in the graph answer their callbacks from one kernel call
        # per group for each Values the optimizer hands GTSAM (factors.EvaluationPlan).
        self._plan = _Plans(factors.EvaluationPlan(graph), KindPlan(graph))
        self._error = self._graph_error(self._values)
        self._iterations = 0
        self._ordering = self._ordering_for(graph, params, ordering)
        self._eliminate_fn = self._elimination_function(params)

    # ------------------------------------------------------------ params
    @staticmethod
    def _ordering_for(graph, params, ordering):
        """GTSAM's ``ensureHasOrdering``: the given ordering, else one of the params' type
        (never ``CUSTOM`` here: :meth:`__new__` hands those params to GTSAM's optimizer)."""
        if ordering is not None:
            return ordering
        kind = params.getOrderingType()
        return gtsam.Ordering.CreateNonlinearFactorGraph(getattr(gtsam.Ordering.OrderingType, kind), graph)

    @staticmethod
    def _elimination_function(params):
        """The elimination function of the params' linear solver (one :data:`_ELIMINATION` has)."""
        return _ELIMINATION[params.getLinearSolverType()]

    def _verbosity_level(self) -> int:
        return lm.VERBOSITY.get(self._params.getVerbosity(), 0)

    # ------------------------------------------------------------ state
    def error(self) -> float:
        """The graph's error at the current values."""
        return self._error

    def iterations(self) -> int:
        """Number of iterations (accepted steps) so far."""
        return self._iterations

    def values(self) -> gtsam.Values:
        """The current estimate: a copy, as GTSAM's ``values()`` returns (the optimizer keeps its own)."""
        return gtsam.Values(self._values)

    def graph(self) -> gtsam.NonlinearFactorGraph:
        return self._graph

    def params(self):
        """The params object given to the constructor (or the default one)."""
        return self._params

    # ------------------------------------------------------------ GTSAM's evaluations
    def _linearize(self, values: gtsam.Values) -> gtsam.GaussianFactorGraph:
        """``graph.linearize(values)``; ``values`` is an object this optimizer holds."""
        if not self._plan:
            return self._graph.linearize(values)
        with self._plan.prepared(values):
            return self._graph.linearize(values)

    def _graph_error(self, values: gtsam.Values) -> float:
        """``graph.error(values)``; ``values`` is an object this optimizer holds."""
        if not self._plan:
            return float(self._graph.error(values))
        with self._plan.prepared(values):
            return float(self._graph.error(values))

    # ------------------------------------------------------------ linear algebra
    def _eliminate(self, linear: gtsam.GaussianFactorGraph):
        """Bayes tree (multifrontal) or Bayes net (sequential) of ``linear`` in the params' ordering."""
        if self._params.isSequential():
            if self._eliminate_fn is None:
                return linear.eliminateSequential(self._ordering)
            return linear.eliminateSequential(self._ordering, self._eliminate_fn)
        if self._eliminate_fn is None:
            return linear.eliminateMultifrontal(self._ordering)
        return linear.eliminateMultifrontal(self._ordering, self._eliminate_fn)

    def _solve(self, linear: gtsam.GaussianFactorGraph) -> gtsam.VectorValues:
        """GTSAM's ``NonlinearOptimizer::solve`` (elimination, then back-substitution)."""
        if self._params.isMultifrontal():
            if self._eliminate_fn is None:
                return linear.optimize(self._ordering)
            return linear.optimize(self._ordering, self._eliminate_fn)
        return self._eliminate(linear).optimize()

    # ------------------------------------------------------------ loop
    def iterate(self) -> gtsam.GaussianFactorGraph:  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def optimize(self) -> gtsam.Values:
        """GTSAM's ``defaultOptimize``; returns the final values (a copy)."""
        self._default_optimize()
        return self.values()

    def optimizeSafely(self) -> gtsam.Values:
        """``optimize()``, or an empty ``Values`` if it raised (GTSAM's ``optimizeSafely``)."""
        try:
            self._default_optimize()
        except Exception:
            return gtsam.Values()
        return self.values()

    def _default_optimize(self) -> lm.OptimizeResult:
        """GTSAM's ``defaultOptimize`` (:func:`lie_factors.lm.default_optimize`)."""
        return lm.default_optimize(self, self._params)


class GaussNewtonOptimizer(_NonlinearOptimizer):
    """Drop-in for ``gtsam.GaussNewtonOptimizer(graph, initialValues[, params])``.

    One iteration: linearize at the current values, solve the undamped system
    (an ``IndeterminantLinearSystemException`` propagates, as from GTSAM), retract.
    ``ordering=`` may be given as a keyword (GTSAM's C++ constructor takes one).
    """

    _params_type = gtsam.GaussNewtonParams

    def __init__(self, graph, initialValues, params=None, ordering=None):
        super().__init__(graph, initialValues, params, ordering)

    def iterate(self) -> gtsam.GaussianFactorGraph:
        linear = self._linearize(self._values)
        delta = self._solve(linear)
        if self._verbosity_level() >= lm.VERBOSITY["DELTA"]:
            lm.COUT.sync()
            delta.print("delta")
        values = self._values.retract(delta)
        self._error = self._graph_error(values)
        self._values = values
        self._iterations += 1
        return linear


class LevenbergMarquardtOptimizer(lm.LevenbergMarquardt, _NonlinearOptimizer):
    """Drop-in for ``gtsam.LevenbergMarquardtOptimizer(graph, initialValues[, ordering][, params])``.

    GTSAM's ``iterate``/``tryLambda`` and λ schedule are
    :class:`lie_factors.lm.LevenbergMarquardt`'s; here, for each λ tried, the
    damped system (the linear graph + one damping factor per variable, see the
    module docstring) is solved with GTSAM's elimination, a failed solve
    (indeterminant system) counting as a failed try, and a trial point is a
    ``Values`` this optimizer holds.
    """

    _params_type = gtsam.LevenbergMarquardtParams

    def __init__(self, graph, initialValues, *args, **kwargs):
        ordering, params = self._parse(args, kwargs)
        super().__init__(graph, initialValues, params, ordering)
        self._lm_init(self._params)
        # Vanilla damping: one factor per variable of the values, built once; each
        # λ tried only sets their noise model (JacobianFactor.setModel), and the
        # damped graph shares them (push_back of a graph shares its factors).
        self._dims = self._values.dims()
        self._damping = None
        self._damping_graph = None

    @staticmethod
    def _parse(args, kwargs):
        """(graph, values, params) or (graph, values, ordering, params), as GTSAM's wrapper."""
        ordering = kwargs.pop("ordering", None)
        params = kwargs.pop("params", None)
        if kwargs:
            raise TypeError(f"unexpected keyword arguments: {', '.join(kwargs)}")
        args = list(args)
        if args and isinstance(args[0], gtsam.Ordering):
            if ordering is not None:
                raise TypeError("ordering given twice")
            ordering = args.pop(0)
        if args:
            if params is not None:
                raise TypeError("params given twice")
            params = args.pop(0)
        if args:
            raise TypeError("too many arguments: (graph, initialValues[, ordering][, params])")
        return ordering, params

    def print(self, str: str = "") -> None:  # noqa: A002 - GTSAM's argument name
        sys.stdout.write(f"{str}\n")
        sys.stdout.flush()
        self._params.print("")

    # ------------------------------------------------------------ damping
    def _damping_factors(self, sqrt_diag):
        if sqrt_diag is None:
            if self._damping is None:
                self._damping = [
                    (gtsam.JacobianFactor(key, np.eye(d), np.zeros(d), gtsam.noiseModel.Unit.Create(d)), d)
                    for key, d in self._dims.items()]
                self._damping_graph = gtsam.GaussianFactorGraph()
                for f, _ in self._damping:
                    self._damping_graph.push_back(f)
            return self._damping, self._damping_graph
        damping_factors = [(gtsam.JacobianFactor(key, np.diag(a), np.zeros(a.shape[0]),
                                                 gtsam.noiseModel.Unit.Create(a.shape[0])), a.shape[0])
                           for key, a in sqrt_diag.items()]
        graph = gtsam.GaussianFactorGraph()
        for f, _ in damping_factors:
            graph.push_back(f)
        return damping_factors, graph

    def _damped_system(self, linear, damping) -> gtsam.GaussianFactorGraph:
        """GTSAM's ``buildDampedSystem``: ``linear`` + a prior of σ = 1/√λ on every damped variable."""
        damping_factors, graph = damping
        sigma = 1.0 / math.sqrt(self._lambda)
        sigmas = {}
        for f, d in damping_factors:
            s = sigmas.get(d)
            if s is None:
                s = sigmas[d] = np.full(d, sigma)
            f.setModel(False, s)
        damped = gtsam.GaussianFactorGraph()
        damped.push_back(linear)
        damped.push_back(graph)
        return damped

    # ------------------------------------------------------------ lm.LevenbergMarquardt's hooks
    def _lm_linearize(self) -> gtsam.GaussianFactorGraph:
        # [A b] is read back (for diagonal damping, or for a small linearized change) at most once.
        self._cost = None
        self._old_linear = None
        return self._linearize(self._values)

    def _lm_hessian_diagonal(self, linear) -> np.ndarray:
        self._cost = _LinearizedCost(linear, self._dims)
        return self._cost.hessian_diagonal()

    def _lm_damping(self, linear, diagonal):
        """The damping factors: unit ones, or ``diag(√D)`` per variable of the linear graph."""
        if diagonal is None:
            return self._damping_factors(None)
        sqrt_diag = np.sqrt(diagonal)
        out = {}
        start = 0
        for key in self._cost.keys:
            d = self._dims[key]
            out[key] = sqrt_diag[start:start + d]
            start += d
        return self._damping_factors(out)

    def _lm_solve(self, linear, damping) -> gtsam.VectorValues | None:
        damped = self._damped_system(linear, damping)
        try:
            return self._solve(damped)
        except RuntimeError as exc:
            if not _is_indeterminant(exc):
                raise
            return None

    def _lm_linear_change(self, linear, delta) -> tuple[float, float, float]:
        """(linearized error at 0, at ``delta``, the decrease).

        GTSAM 4.3 sums each factor's decrease; the difference of the two totals that
        ``GaussianFactorGraph.error`` gives carries rounding of the size of the total.
        Where the decrease is ≥ 1e-4 of the total, that rounding is ≤ 1e-11 of it
        (below what any of LM's decisions can see); below, it is summed row by row.
        """
        if self._old_linear is None:
            self._old_linear = float(linear.error(gtsam.VectorValues.Zero(delta)))
        old = self._old_linear
        new = float(linear.error(delta))
        change = old - new
        if abs(change) < 1e-4 * old:
            if self._cost is None:
                self._cost = _LinearizedCost(linear, self._dims)
            change = self._cost.change(delta)
        return old, new, change

    def _lm_evaluate(self, delta) -> tuple[gtsam.Values, float]:
        values = self._values.retract(delta)
        return values, self._graph_error(values)

    def _lm_accept(self, values: gtsam.Values, error: float) -> None:
        self._values = values

    def _lm_size(self) -> int:
        return self._values.size()

    @staticmethod
    def _lm_delta_norm(delta) -> float:
        return delta.norm()

    @staticmethod
    def _lm_print_delta(delta) -> None:
        delta.print("delta")


class DoglegOptimizer(dogleg.Dogleg, _NonlinearOptimizer):
    """Drop-in for ``gtsam.DoglegOptimizer(graph, initialValues[, params])``.

    GTSAM's ``DoglegOptimizerImpl::Iterate`` in ONE_STEP_PER_ITERATION mode, as
    :class:`lie_factors.dogleg.Dogleg` runs it: the linearization eliminated once (a
    Bayes tree, or a Bayes net with a sequential solver), its steepest-descent point
    (``optimizeGradientSearch``) and Gauss–Newton point (``optimize``), the model's error
    the eliminated system's (``error``), the trial points ``Values`` this optimizer holds.
    ``ordering=`` may be given as a keyword (GTSAM's C++ constructor takes one).
    """

    _params_type = gtsam.DoglegParams

    def __init__(self, graph, initialValues, params=None, ordering=None):
        super().__init__(graph, initialValues, params, ordering)
        self._dl_init(self._params)

    # ------------------------------------------------------------ dogleg.Dogleg's hooks
    def _dl_linearize(self):
        linear = self._linearize(self._values)
        return linear, self._eliminate(linear)  # Bayes tree or Bayes net: R and d

    def _dl_points(self, lin):
        rd = lin[1]
        return rd.optimizeGradientSearch(), rd.optimize()

    @staticmethod
    def _dl_dots(dx_u, dx_n):
        return dx_u.squaredNorm(), dx_n.squaredNorm(), dx_u.dot(dx_n)

    @staticmethod
    def _dl_combine(s_u, dx_u, s_n, dx_n):
        if s_n == 0.0:
            return dx_u.scale(s_u)
        if s_u == 0.0 and s_n == 1.0:
            return dx_n
        return dx_u.scale(s_u).add(dx_n.scale(s_n))

    @staticmethod
    def _dl_norm(delta) -> float:
        return delta.norm()

    @staticmethod
    def _dl_model(lin, delta):
        rd = lin[1]
        m_error = rd.error(gtsam.VectorValues.Zero(delta))
        new_m = rd.error(delta)
        return m_error, new_m, m_error - new_m

    def _dl_evaluate(self, delta):
        values = self._values.retract(delta)
        return values, self._graph_error(values)

    def _dl_accept(self, values, error: float) -> None:
        self._values = values

    def _dl_keep(self) -> None:
        # GTSAM retracts a zero step: a new Values equal to the current one.
        self._values = gtsam.Values(self._values)

    @staticmethod
    def _dl_print_delta(delta) -> None:
        lm.COUT.sync()
        delta.print("delta")

    def iterate(self) -> gtsam.GaussianFactorGraph:
        """One dogleg iteration; returns the linearization, as GTSAM's ``iterate``."""
        return super().iterate()[0]
