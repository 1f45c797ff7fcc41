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

Parameters the Python wrapper cannot set (``minModelFidelity``, ``minDiagonal``,
``maxDiagonal``) have GTSAM's defaults, as they do in GTSAM's optimizer when
called from Python.
"""

from __future__ import annotations

import math
import sys
import time

import gtsam
import numpy as np

from .. import factors

__all__ = ["LevenbergMarquardtOptimizer", "GaussNewtonOptimizer", "DoglegOptimizer"]

#: LevenbergMarquardtParams fields without a Python setter (GTSAM's defaults).
MIN_MODEL_FIDELITY = 1e-3
MIN_DIAGONAL = 1e-6
MAX_DIAGONAL = 1e32

#: How GTSAM's IndeterminantLinearSystemException reads once pybind11 made it a RuntimeError.
_INDETERMINANT = "Indeterminate linear system"

_EPS = float(np.finfo(float).eps)

_VERBOSITY = {name: i for i, name in enumerate(("SILENT", "TERMINATION", "ERROR", "VALUES", "DELTA", "LINEAR"))}
_VERBOSITY_LM = {name: i for i, name in enumerate(
    ("SILENT", "SUMMARY", "TERMINATION", "LAMBDA", "TRYLAMBDA", "TRYCONFIG", "DAMPED", "TRYDELTA"))}


def _is_indeterminant(exc: BaseException) -> bool:
    return isinstance(exc, RuntimeError) and _INDETERMINANT in str(exc)


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


class _NonlinearOptimizer:
    """GTSAM's ``NonlinearOptimizer``: state (values, error, iterations), ``defaultOptimize``,
    ``solve`` of a linear system with the params' linear solver and ordering."""

    _params_type: type = gtsam.NonlinearOptimizerParams

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
        self._plan = factors.EvaluationPlan(graph)
        self._error = self._graph_error(self._values)
        self._iterations = 0
        self._ordering = self._ordering_for(graph, params, ordering)
        self._eliminate_fn = self._elimination_function(params)

    # ------------------------------------------------------------ params
    @staticmethod
    def _ordering_for(graph, params, ordering):
        """GTSAM's ``ensureHasOrdering``: the given ordering, else one of the params' type."""
        if ordering is not None:
            return ordering
        kind = params.getOrderingType()
        if kind == "CUSTOM":
            # params.setOrdering() stores the ordering where the Python wrapper cannot read it.
            raise ValueError(
                "params carry a custom ordering (params.setOrdering), which gtsam's Python wrapper "
                "cannot read back; pass it to the optimizer instead: "
                "Optimizer(graph, initialValues, params, ordering=ordering)")
        return gtsam.Ordering.CreateNonlinearFactorGraph(getattr(gtsam.Ordering.OrderingType, kind), graph)

    @staticmethod
    def _elimination_function(params):
        solver = params.getLinearSolverType()
        if solver in ("MULTIFRONTAL_QR", "SEQUENTIAL_QR"):
            return gtsam.EliminateQR
        if solver in ("MULTIFRONTAL_CHOLESKY", "SEQUENTIAL_CHOLESKY"):
            return None  # the wrapper's default, EliminatePreferCholesky (as GTSAM's optimizers)
        if solver == "ITERATIVE":
            raise NotImplementedError(
                "lie_factors.optimizers: the ITERATIVE (PCG/subgraph) linear solver is not supported; "
                "use MULTIFRONTAL_CHOLESKY, MULTIFRONTAL_QR, SEQUENTIAL_CHOLESKY or SEQUENTIAL_QR")
        # CHOLMOD: GTSAM's NonlinearOptimizer::solve rejects it with this runtime_error.
        raise RuntimeError("NonlinearOptimizer::solve: Optimization parameter is invalid")

    def _verbosity(self) -> int:
        return _VERBOSITY.get(self._params.getVerbosity(), 0)

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

    def _default_optimize(self) -> None:
        p = self._params
        verbosity = self._verbosity()
        error_tol = p.getErrorTol()
        current = self._error
        if current <= error_tol:
            if verbosity >= _VERBOSITY["ERROR"]:
                print(f"Exiting, as error = {current} < {error_tol}")
            return
        if verbosity >= _VERBOSITY["VALUES"]:
            self._values.print("Initial values")
        if verbosity >= _VERBOSITY["ERROR"]:
            print(f"Initial error: {current}")
        max_iterations = p.getMaxIterations()
        if self._iterations >= max_iterations:
            if verbosity >= _VERBOSITY["TERMINATION"]:
                print(f"iterations: {self._iterations} >? {max_iterations}")
            return
        rel, abs_, hook = p.getRelativeErrorTol(), p.getAbsoluteErrorTol(), p.iterationHook
        new = current
        while True:
            current = new
            self.iterate()
            new = self._error
            if hook is not None:
                hook(self._iterations, current, new)
            if verbosity >= _VERBOSITY["VALUES"]:
                self._values.print("newValues")
            if verbosity >= _VERBOSITY["ERROR"]:
                print(f"newError: {new}")
            if not (self._iterations < max_iterations
                    and not gtsam.checkConvergence(p, current, new)
                    and math.isfinite(current)):
                break
        if verbosity >= _VERBOSITY["TERMINATION"]:
            print(f"iterations: {self._iterations} >? {max_iterations}")
            if self._iterations >= max_iterations:
                print("Terminating because reached maximum iterations")


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
        if self._verbosity() >= _VERBOSITY["DELTA"]:
            delta.print("delta")
        values = self._values.retract(delta)
        self._error = self._graph_error(values)
        self._values = values
        self._iterations += 1
        return linear


class LevenbergMarquardtOptimizer(_NonlinearOptimizer):
    """Drop-in for ``gtsam.LevenbergMarquardtOptimizer(graph, initialValues[, ordering][, params])``.

    GTSAM's ``iterate``/``tryLambda`` and ``LevenbergMarquardtState``:

    * each iteration linearizes once; for each λ tried, the damped system
      (the linear graph + one damping factor per variable, see the module
      docstring) is solved; a failed solve (indeterminant system) counts as a
      failed try;
    * a step is retracted and evaluated only if the linearized cost decreases;
      it is accepted if ``fidelity = Δcost / Δlinearized > minModelFidelity``
      (when ``Δlinearized > ε·linearized error``);
    * accepted: ``λ ← max(lowerBound, λ·max(1/3, 1 − (2·fidelity − 1)³))`` and
      the factor doubles, or ``λ ← λ/factor`` with ``useFixedLambdaFactor``;
      rejected: ``λ ← λ·factor`` (factor doubles unless fixed); give up once
      ``λ ≥ lambdaUpperBound``, or stop trying when ``|Δcost| < relativeErrorTol·error``.
    """

    _params_type = gtsam.LevenbergMarquardtParams

    def __init__(self, graph, initialValues, *args, **kwargs):
        ordering, params = self._parse(args, kwargs)
        super().__init__(graph, initialValues, params, ordering)
        p = self._params
        self._lambda = float(p.getlambdaInitial())
        self._factor = float(p.getlambdaFactor())
        self._inner = 0
        self._diagonal = bool(p.getDiagonalDamping())
        self._fixed = bool(p.getUseFixedLambdaFactor())
        self._upper = float(p.getlambdaUpperBound())
        self._lower = float(p.getlambdaLowerBound())
        self._verbosity_lm = _VERBOSITY_LM.get(p.getVerbosityLM(), 0)
        self._log_file = p.getLogFile()
        self._start = time.perf_counter()
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

    def lambda_(self) -> float:
        """The current λ."""
        return self._lambda

    def getInnerIterations(self) -> int:
        """Total number of λ tried (GTSAM's ``getInnerIterations``)."""
        return self._inner

    def print(self, str: str = "") -> None:  # noqa: A002 - GTSAM's argument name
        sys.stdout.write(f"{str}\n")
        self._params.print("")

    # ------------------------------------------------------------ damping
    def _sqrt_hessian_diagonal(self, cost: _LinearizedCost) -> dict:
        """key → √clamp(diag(JᵀJ), minDiagonal, maxDiagonal) (GTSAM's clamped ``hessianDiagonal``)."""
        diag = np.sqrt(np.minimum(np.maximum(cost.hessian_diagonal(), MIN_DIAGONAL), MAX_DIAGONAL))
        out = {}
        start = 0
        for key in cost.keys:
            d = self._dims[key]
            out[key] = diag[start:start + d]
            start += d
        return out

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

    # ------------------------------------------------------------ iteration
    def _write_log(self, error: float) -> None:
        if self._log_file:
            with open(self._log_file, "a") as fh:
                fh.write(f"{self._inner},{time.perf_counter() - self._start},{error},"
                         f"{self._lambda},{self._iterations}\n")

    def iterate(self) -> gtsam.GaussianFactorGraph:
        """One iteration: linearize once, then try λ until a step is accepted or LM gives up."""
        linear = self._linearize(self._values)
        if self._inner == 0:
            self._write_log(self._error)
            if self._verbosity_lm == _VERBOSITY_LM["SUMMARY"]:
                print(f"Initial error: {self._error}, values: {self._values.size()}")
        # [A b] read back (for diagonal damping, or for a small linearized change) at most once.
        cost = _LinearizedCost(linear, self._dims) if self._diagonal else None
        self._cost = cost
        self._old_linear = None
        sqrt_diag = self._sqrt_hessian_diagonal(cost) if self._diagonal else None
        damping = self._damping_factors(sqrt_diag)
        while not self._try_lambda(linear, damping):
            self._write_log(self._error)
        return linear

    def _linear_change(self, linear, delta) -> tuple[float, float]:
        """(linearized error at 0, its decrease at ``delta``).

        GTSAM 4.3 sums each factor's decrease; the difference of the two totals that
        ``GaussianFactorGraph.error`` gives carries rounding of the size of the total.
        Where the decrease is ≥ 1e-4 of the total, that rounding is ≤ 1e-11 of it
        (below what any of LM's decisions can see); below, it is summed row by row.
        """
        if self._old_linear is None:
            self._old_linear = float(linear.error(gtsam.VectorValues.Zero(delta)))
        old = self._old_linear
        change = old - float(linear.error(delta))
        if abs(change) < 1e-4 * old:
            if self._cost is None:
                self._cost = _LinearizedCost(linear, self._dims)
            change = self._cost.change(delta)
        return old, change

    def _try_lambda(self, linear, damping) -> bool:
        verbose = self._verbosity_lm >= _VERBOSITY_LM["TRYLAMBDA"]
        if verbose:
            print(f"trying lambda = {self._lambda}")
        t0 = time.perf_counter()
        damped = self._damped_system(linear, damping)
        fidelity = 0.0
        success = stop = False
        new_error = math.inf
        cost_change = 0.0
        new_values = None
        try:
            delta = self._solve(damped)
        except RuntimeError as exc:
            if not _is_indeterminant(exc):
                raise
            delta = None
        if delta is not None:
            old_linear, linear_change = self._linear_change(linear, delta)
            new_linear = old_linear - linear_change
            if verbose:
                print(f"linear delta norm = {delta.norm()}")
                print(f"newlinearizedError = {new_linear}  linearizedCostChange = {linear_change}")
            if linear_change >= 0:
                new_values = self._values.retract(delta)
                new_error = self._graph_error(new_values)
                cost_change = self._error - new_error
                if linear_change > _EPS * old_linear:
                    fidelity = cost_change / linear_change
                    success = fidelity > MIN_MODEL_FIDELITY
                    if verbose:
                        print(f"modelFidelity: {fidelity}")
                if abs(cost_change) < self._params.getRelativeErrorTol() * self._error:
                    stop = True
        if self._verbosity_lm == _VERBOSITY_LM["SUMMARY"]:
            if self._iterations == 0:
                print("iter      cost      cost_change    lambda  success iter_time")
            print(f"{self._iterations:4d} {new_error:12.6g} {cost_change:12.2g} {self._lambda:10.2g} "
                  f"{int(delta is not None):6d} {time.perf_counter() - t0:10.2g}")
        if success:
            if self._fixed:
                self._lambda /= self._factor
            else:
                self._lambda *= max(1.0 / 3.0, 1.0 - (2.0 * fidelity - 1.0) ** 3)
                self._factor *= 2.0
            self._lambda = max(self._lower, self._lambda)
            self._values = new_values
            self._error = new_error
            self._iterations += 1
            self._inner += 1
            return True
        if not stop:
            if verbose:
                print("increasing lambda")
            self._lambda *= self._factor
            self._inner += 1
            if not self._fixed:
                self._factor *= 2.0
            if self._lambda >= self._upper:
                if (self._verbosity() >= _VERBOSITY["TERMINATION"]
                        or self._verbosity_lm == _VERBOSITY_LM["SUMMARY"]):
                    print("Warning:  Levenberg-Marquardt giving up because "
                          "cannot decrease error with maximum lambda")
                return True
            return False
        if verbose:
            print("Levenberg-Marquardt: stopping as relative cost reduction is small")
        return True


class DoglegOptimizer(_NonlinearOptimizer):
    """Drop-in for ``gtsam.DoglegOptimizer(graph, initialValues[, params])``.

    GTSAM's ``DoglegOptimizerImpl::Iterate`` in ONE_STEP_PER_ITERATION mode:
    eliminate the linearization once; steepest-descent point ``dx_u``
    (``optimizeGradientSearch``) and Gauss–Newton point ``dx_n``
    (``optimize``); the dogleg point inside the trust region Δ; gain ratio
    ``ρ = Δf / ΔM`` (0.5 if either change is below 1e-15); ρ ≥ 0.75: Δ ←
    max(Δ, 3‖dx_d‖); 0.25 ≤ ρ < 0.75: Δ kept; 0 ≤ ρ < 0.25: Δ halved (not
    below 1e-5); ρ < 0: Δ halved and the step retried, or, at Δ ≤ 1e-5, no
    step.  ``ordering=`` may be given as a keyword (GTSAM's C++ constructor takes one).
    """

    _params_type = gtsam.DoglegParams

    def __init__(self, graph, initialValues, params=None, ordering=None):
        super().__init__(graph, initialValues, params, ordering)
        if self._params.isIterative():
            raise RuntimeError("Dogleg is not currently compatible with the linear conjugate gradient solver")
        self._delta = float(self._params.getDeltaInitial())
        self._verbose_dl = self._params.getVerbosityDL() != "SILENT"

    def getDelta(self) -> float:
        """The current trust-region radius Δ."""
        return self._delta

    @staticmethod
    def _dogleg_point(delta: float, dx_u: gtsam.VectorValues, dx_n: gtsam.VectorValues,
                      verbose: bool) -> gtsam.VectorValues:
        """The point where the dogleg path dx_u → dx_n leaves the trust region of radius ``delta``."""
        delta_sq = delta * delta
        uu = dx_u.squaredNorm()
        nn = dx_n.squaredNorm()
        if verbose:
            print(f"Steepest descent magnitude {math.sqrt(uu)}, Newton's method magnitude {math.sqrt(nn)}")
        if delta_sq < uu:
            if verbose:
                print(f"In steepest descent region with fraction {math.sqrt(delta_sq / uu)} "
                      "of steepest descent magnitude")
            return dx_u.scale(math.sqrt(delta_sq / uu))
        if delta_sq < nn:
            # τ with ‖(1 − τ) dx_u + τ dx_n‖ = Δ, 0 ≤ τ ≤ 1: a quadratic in τ.
            un = dx_u.dot(dx_n)
            a = uu - 2.0 * un + nn
            b = 2.0 * (un - uu)
            c = uu - delta_sq
            root = math.sqrt(b * b - 4.0 * a * c)
            tau1 = (-b + root) / (2.0 * a)
            tau2 = (-b - root) / (2.0 * a)
            tau = tau1 if -_EPS <= tau1 <= 1.0 + _EPS else tau2
            if verbose:
                print(f"In blend region with fraction {tau} of Newton's method point")
            return dx_u.scale(1.0 - tau).add(dx_n.scale(tau))
        if verbose:
            print("In pure Newton's method region")
        return dx_n

    def iterate(self) -> gtsam.GaussianFactorGraph:
        linear = self._linearize(self._values)
        verbose = self._verbose_dl
        rd = self._eliminate(linear)  # Bayes tree or Bayes net: R and d
        dx_u = rd.optimizeGradientSearch()
        dx_n = rd.optimize()
        m_error = rd.error(gtsam.VectorValues.Zero(dx_u))
        f_error = self._error
        delta = self._delta
        while True:
            dx_d = self._dogleg_point(delta, dx_u, dx_n, verbose)
            if verbose:
                print(f"delta = {delta}, dx_d_norm = {dx_d.norm()}")
            x_d = self._values.retract(dx_d)
            new_f = self._graph_error(x_d)
            new_m = rd.error(dx_d)
            if verbose:
                print(f"f error: {f_error} -> {new_f}")
                print(f"M error: {m_error} -> {new_m}")
            if abs(f_error - new_f) < 1e-15 or abs(m_error - new_m) < 1e-15:
                rho = 0.5
            else:
                rho = (f_error - new_f) / (m_error - new_m)
            if verbose:
                print(f"rho = {rho}")
            if rho >= 0.75:
                delta = max(delta, 3.0 * dx_d.norm())
                break
            if rho >= 0.25:
                break
            if rho >= 0.0:
                if delta > 1e-5:
                    delta *= 0.5
                break
            # f increased (or NaN): shrink the region and retry, down to Δ = 1e-5.
            if delta > 1e-5:
                delta *= 0.5
                continue
            if verbose:
                print("Warning:  Dog leg stopping because cannot decrease error with minimum delta")
            x_d, new_f = self._values, f_error
            dx_d = None
            break
        if dx_d is not None and self._verbosity() >= _VERBOSITY["DELTA"]:
            dx_d.print("delta")
        if dx_d is None:
            # GTSAM retracts a zero step: a new Values equal to the current one.
            x_d = gtsam.Values(self._values)
        self._values = x_d
        self._error = new_f
        self._delta = delta
        self._iterations += 1
        return linear
