"""Levenberg–Marquardt and Gauss–Newton over the batch linear system, with GTSAM's semantics.

The loop of GTSAM's ``LevenbergMarquardtOptimizer`` (``tryLambda`` /
``iterate`` / ``defaultOptimize`` / ``checkConvergence``) and
``GaussNewtonOptimizer``; what differs is only how a linear step is computed
(:mod:`lie_factors.batch.system` assembles ``H + damping``,
:mod:`lie_factors.batch.solvers` factors it).  See
:class:`BatchLevenbergMarquardt`.

Usage::

    from lie_factors import batch
    result = batch.optimize(graph, initial)                 # LM, GTSAM's default params
    result = batch.optimize(graph, initial, gtsam.GaussNewtonParams())
    result.values, result.iterations, result.errors, result.seconds, result.timings
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import gtsam
import numpy as np

from ..errors import PoseGraphError
from ..results import OptimizeResult
from ..timing import IterationLog, Stopwatch
from . import solvers
from .graph import BatchError, Problem, first_line
from .solvers import NotPositiveDefinite
from .system import LinearSystem

#: GTSAM defaults that the Python wrapper does not expose (LevenbergMarquardtParams.h).
MIN_MODEL_FIDELITY = 1e-3
MIN_DIAGONAL = 1e-6
MAX_DIAGONAL = 1e32

#: Keys of ``BatchResult.timings`` (seconds, summed over the run).
TIMING_KEYS = ("setup", "linearize", "assemble", "factorize", "retract", "error", "values", "other")


class IndeterminantLinearSystem(NotPositiveDefinite):
    """Gauss–Newton's undamped system is not positive definite (e.g. no prior fixes the gauge)."""


@dataclass
class BatchResult:
    """What :func:`optimize` returns.

    ``errors[0]`` is the initial error, ``errors[k]`` the error after iteration
    k; ``lambdas[k]`` is λ after iteration k (``lambdas[0]`` the initial λ; 0
    for Gauss–Newton).  ``timings`` splits ``seconds`` into :data:`TIMING_KEYS`:
    ``factorize`` is numeric factorization + solve (the symbolic analysis is
    in ``setup``), ``error`` includes the linearized-cost change.
    """

    values: gtsam.Values
    iterations: int
    errors: list[float]
    lambdas: list[float]
    seconds: float
    converged: bool
    inner_iterations: int = 0
    timings: dict = field(default_factory=dict)
    linear_solver: str = ""

    @property
    def initial_error(self) -> float:
        return self.errors[0]

    @property
    def final_error(self) -> float:
        return self.errors[-1]


class BatchLevenbergMarquardt:
    """Levenberg–Marquardt (or Gauss–Newton) over ``graph`` from ``initial``, mirroring GTSAM.

    ``params``: ``gtsam.LevenbergMarquardtParams`` (default) or
    ``gtsam.GaussNewtonParams`` (same loop, no damping, a non-positive-definite
    system raises :class:`IndeterminantLinearSystem`).  ``linear_solver``:
    ``"auto"`` (CHOLMOD if cvxopt is installed, else GTSAM with a warning),
    ``"cholmod"`` or ``"gtsam"``.

    LM semantics (GTSAM ``LevenbergMarquardtOptimizer``/``LevenbergMarquardtState``):

    * damping ``λ·I`` on every variable of the linear system, or with
      ``diagonalDamping`` ``λ·clamp(diag(JᵀJ), 1e-6, 1e32)``, for each λ tried;
    * a step is tried only if the linearized cost decreases; it is accepted if
      ``fidelity = Δcost / Δlinearized > minModelFidelity (1e-3)``, provided
      ``Δlinearized > ε·linearized error``; a system that cannot be factored
      counts as a failed try;
    * accepted: ``λ ← max(lowerBound, λ·max(1/3, 1 − (2·fidelity − 1)³))``,
      factor ← 2·factor (or ``λ ← λ/factor`` with ``useFixedLambdaFactor``);
      rejected: ``λ ← λ·factor``, factor ← 2·factor (unless fixed); give up
      once ``λ ≥ lambdaUpperBound``, or stop trying when
      ``|Δcost| < relativeErrorTol·error``;
    * :meth:`optimize`: nothing if error ≤ errorTol or iterations ≥
      maxIterations, else iterate while iterations < maxIterations, not
      ``gtsam.checkConvergence`` and the error is finite.

    Hooks for robust cost functions / GNC (arrays indexed by position in the
    graph): ``reweight(sq) -> w`` is called after every linearization with the
    squared whitened residual norms there (``Problem.linearized_sqnorms``);
    ``w`` multiplies each factor's whitened AᵀA and Aᵀb (√w on its rows), and
    the linearized error at δ = 0 becomes ½·Σ w·sq.  ``cost(sq) -> float``
    replaces the error ½·Σ sq wherever the nonlinear error is evaluated (e.g.
    Σ ρ(√sq) for an M-estimator).  Without ``reweight``, ``self.system.weights``
    can be set directly (GNC: fixed weights per outer step).  Subclasses
    change the cost by overriding :meth:`objective` (evaluated once for the
    initial error and once per tried step) and prepare what it needs in
    :meth:`_setup`, which runs before that first evaluation.
    """

    #: Group lie_factors factors with robust noise (only subclasses that apply the loss do).
    group_robust = False

    def __init__(self, graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values,
                 params: gtsam.LevenbergMarquardtParams | gtsam.GaussNewtonParams | None = None,
                 min_model_fidelity: float = MIN_MODEL_FIDELITY, linear_solver: str = "auto",
                 reweight: Callable[[np.ndarray], np.ndarray] | None = None,
                 cost: Callable[[np.ndarray], float] | None = None):
        t0 = time.perf_counter()
        self.reweight, self.cost = reweight, cost
        self.params = params if params is not None else gtsam.LevenbergMarquardtParams()
        if not isinstance(self.params, (gtsam.LevenbergMarquardtParams, gtsam.GaussNewtonParams)):
            raise TypeError("params must be gtsam.LevenbergMarquardtParams or gtsam.GaussNewtonParams, "
                            f"got {type(self.params).__name__}")
        self.gauss_newton = isinstance(self.params, gtsam.GaussNewtonParams)
        self.min_model_fidelity = float(min_model_fidelity)
        self._read_params()
        # A Problem (e.g. Problem.from_pose_graph) is used as it is; ``initial`` is then ignored.
        self.problem = (graph if isinstance(graph, Problem)
                        else Problem(graph, initial, group_robust=self.group_robust))
        self.system = LinearSystem(self.problem)
        self.solver = solvers.make(linear_solver, self.system)
        self.timings = dict.fromkeys(TIMING_KEYS, 0.0)
        self.lambda_ = 0.0 if self.gauss_newton else self.lambda_initial
        self.current_factor = self.lambda_factor
        self._iterations = 0
        self.inner_iterations = 0
        self._setup()
        t1 = time.perf_counter()
        self._error = self.objective()
        self.timings["error"] += time.perf_counter() - t1
        self.errors = [self._error]
        self.lambdas = [self.lambda_]
        self.timings["setup"] += t1 - t0

    # ---------------------------------------------------------------- params
    def _read_params(self):
        p = self.params
        self.max_iterations = int(p.getMaxIterations())
        self.relative_tol = float(p.getRelativeErrorTol())
        self.absolute_tol = float(p.getAbsoluteErrorTol())
        self.error_tol = float(p.getErrorTol())
        self.verbosity = str(p.getVerbosity())
        self._verbose_error = self.verbosity in ("ERROR", "VALUES", "DELTA", "LINEAR")
        self._verbose_termination = self.verbosity not in ("SILENT",)
        if self.gauss_newton:
            self.lambda_initial = self.lambda_factor = 0.0
            self._summary = self._trylambda = False
            return
        self.lambda_initial = float(p.getlambdaInitial())
        self.lambda_factor = float(p.getlambdaFactor())
        self.lambda_upper = float(p.getlambdaUpperBound())
        self.lambda_lower = float(p.getlambdaLowerBound())
        self.diagonal_damping = bool(p.getDiagonalDamping())
        self.fixed_factor = bool(p.getUseFixedLambdaFactor())
        verbosity_lm = str(p.getVerbosityLM())
        self._summary = verbosity_lm == "SUMMARY"
        self._trylambda = verbosity_lm in ("TRYLAMBDA", "TRYCONFIG", "DAMPED", "TRYDELTA")

    # ---------------------------------------------------------------- state
    @property
    def blocks(self):
        return self.problem.blocks

    @property
    def linear_solver(self) -> str:
        return self.solver.name

    def error(self) -> float:
        return self._error

    def iterations(self) -> int:
        return self._iterations

    def lambda_value(self) -> float:
        return self.lambda_

    def values(self) -> gtsam.Values:
        return self.problem.values()

    # ---------------------------------------------------------------- cost hook
    def _setup(self) -> None:
        """Called once by ``__init__`` after the problem, system and solver exist and before
        the initial :meth:`objective` is evaluated: subclasses prepare what their objective needs."""

    def objective(self, Xs=None, other=None) -> float:
        """The nonlinear error LM minimizes at (Xs, other) (default: the current estimate).

        The one cost hook: ``__init__`` evaluates it once for the initial
        error, every tried step once.  Here GTSAM's ½·Σ‖R e‖², or ``cost(sq)``
        if that hook was given; subclasses override it (robust Σ s·ρ).
        """
        if self.cost is None:
            return self.problem.error(Xs, other)
        sq = np.zeros(self.problem.graph_size)
        self.problem.error(Xs, other, sq_out=sq)
        return float(self.cost(sq))

    # ---------------------------------------------------------------- steps
    def _linearize(self) -> float:
        T = self.timings
        t = time.perf_counter()
        linear_error0 = self.problem.linearize()
        if self.reweight is not None:
            sq = self.problem.linearized_sqnorms()
            w = np.asarray(self.reweight(sq), dtype=np.float64)
            if w.shape != sq.shape or not np.all(np.isfinite(w)) or np.any(w < 0):
                raise BatchError(f"reweight must return {sq.shape[0]} finite non-negative weights")
            self.system.weights[:] = w
        if self.reweight is not None or np.any(self.system.weights != 1.0):
            linear_error0 = 0.5 * float(self.system.weights @ self.problem.linearized_sqnorms())
        t1 = time.perf_counter()
        self.system.assemble()
        T["linearize"] += t1 - t
        T["assemble"] += time.perf_counter() - t1
        return linear_error0

    def _solve(self, scale):
        t = time.perf_counter()
        try:
            return self.solver.solve(scale)
        finally:
            self.timings["factorize"] += time.perf_counter() - t

    def _try_step(self, delta):
        """(elements, other, new error) at the retracted ``delta``."""
        T = self.timings
        t = time.perf_counter()
        Xs, other = self.problem.retract(delta)
        t1 = time.perf_counter()
        new_error = self.objective(Xs, other)
        T["retract"] += t1 - t
        T["error"] += time.perf_counter() - t1
        return Xs, other, new_error

    def _try_lambda(self, linear_error0: float, hdiag) -> bool:
        scale = (np.full(self.system.n, self.lambda_) if hdiag is None
                 else self.lambda_ * hdiag)
        model_fidelity = 0.0
        success = False
        stop = False
        new_error = math.inf
        cost_change = 0.0
        try:
            delta = self._solve(scale)
        except NotPositiveDefinite:  # GTSAM: IndeterminantLinearSystemException, λ goes up
            delta = None
        if delta is not None:
            t = time.perf_counter()
            linear_change = self.system.linear_change(delta)
            self.timings["error"] += time.perf_counter() - t
            if self._trylambda:
                print(f"linear delta norm = {np.linalg.norm(delta)}")
                print(f"newlinearizedError = {linear_error0 - linear_change:.15g}  "
                      f"linearizedCostChange = {linear_change:.15g}")
            if linear_change >= 0:
                Xs, other, new_error = self._try_step(delta)
                cost_change = self._error - new_error
                if linear_change > np.finfo(float).eps * linear_error0:
                    model_fidelity = cost_change / linear_change
                    success = model_fidelity > self.min_model_fidelity
                    if self._trylambda:
                        print(f"modelFidelity: {model_fidelity}")
                if abs(cost_change) < self.relative_tol * self._error:
                    stop = True
        if self._summary:
            print(f"{self._iterations:4d} {new_error:12.6e} {cost_change:12.4e} "
                  f"{self.lambda_:10.2e} {int(success):4d}")
        if success:
            self.problem.accept(Xs, other)
            self._error = new_error
            if self.fixed_factor:
                self.lambda_ /= self.current_factor
            else:
                self.lambda_ *= max(1.0 / 3.0, 1.0 - (2.0 * model_fidelity - 1.0) ** 3)
                self.current_factor *= 2.0
            self.lambda_ = max(self.lambda_lower, self.lambda_)
            self._iterations += 1
            self.inner_iterations += 1
            return True
        if not stop:
            self.lambda_ *= self.current_factor
            self.inner_iterations += 1
            if not self.fixed_factor:
                self.current_factor *= 2.0
            if self.lambda_ >= self.lambda_upper:
                if self._verbose_termination or self._summary:
                    print("Warning:  Levenberg-Marquardt giving up because "
                          "cannot decrease error with maximum lambda")
                return True
            return False
        if self._trylambda:
            print("Levenberg-Marquardt: stopping as relative cost reduction is small")
        return True

    def iterate(self) -> None:
        """One iteration: linearize and assemble once, then (LM) try λ until a step is accepted or LM gives up."""
        linear_error0 = self._linearize()
        if self.gauss_newton:
            try:
                delta = self._solve(None)
            except NotPositiveDefinite as exc:
                raise IndeterminantLinearSystem(
                    f"Gauss-Newton: {exc}; the graph does not determine every variable "
                    "(e.g. no prior fixes the gauge) - add a prior or use Levenberg-Marquardt") from None
            Xs, other, self._error = self._try_step(delta)
            self.problem.accept(Xs, other)
            self._iterations += 1
            self.inner_iterations += 1
            return
        if self._summary and self.inner_iterations == 0:
            print(f"Initial error: {self._error}, values: {len(self.problem.var_keys)}")
        hdiag = None
        if self.diagonal_damping:
            hdiag = np.clip(self.system.hessian_diagonal(), MIN_DIAGONAL, MAX_DIAGONAL)
        while not self._try_lambda(linear_error0, hdiag):
            pass

    def optimize(self, progress: Callable[[int, float, float], None] | None = None,
                 values: bool = True) -> BatchResult:
        """GTSAM's ``defaultOptimize``; ``progress(iteration, error, lambda)`` after each iterate.

        ``values=False``: ``result.values`` is None (the estimate stays in the
        arrays; :meth:`values` builds the GTSAM Values when asked)."""
        t0 = time.perf_counter()
        new_error = self._error
        converged = False
        if new_error <= self.error_tol:
            if self._verbose_error:
                print(f"Exiting, as error = {new_error} < {self.error_tol}")
            converged = True
        elif self._iterations < self.max_iterations:
            while True:
                current_error = new_error
                self.iterate()
                new_error = self._error
                self.errors.append(new_error)
                self.lambdas.append(self.lambda_)
                if self._verbose_error:
                    print(f"newError: {new_error}")
                if progress is not None:
                    progress(self._iterations, new_error, self.lambda_)
                converged = bool(gtsam.checkConvergence(
                    self.relative_tol, self.absolute_tol, self.error_tol, current_error, new_error))
                if (self._iterations >= self.max_iterations or converged
                        or not math.isfinite(current_error)):
                    break
        t1 = time.perf_counter()
        values = self.values() if values else None
        self.timings["values"] += time.perf_counter() - t1
        seconds = time.perf_counter() - t0 + self.timings["setup"]
        timings = dict(self.timings)
        timings["other"] = seconds - sum(v for k, v in timings.items() if k != "other")
        return BatchResult(values, self._iterations, list(self.errors), list(self.lambdas), seconds,
                           converged, self.inner_iterations, timings, self.solver.name)


def optimize(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values,
             params: gtsam.LevenbergMarquardtParams | gtsam.GaussNewtonParams | None = None,
             progress: Callable[[int, float, float], None] | None = None,
             linear_solver: str = "auto", **hooks) -> BatchResult:
    """Batch Levenberg–Marquardt or Gauss–Newton (see :class:`BatchLevenbergMarquardt`;
    ``hooks``: ``reweight``, ``cost``)."""
    t0 = time.perf_counter()
    opt = BatchLevenbergMarquardt(graph, initial, params, linear_solver=linear_solver, **hooks)
    result = opt.optimize(progress)
    result.seconds = time.perf_counter() - t0
    return result


def run_batch(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, max_iterations: int = 100,
              progress: Callable | None = None,
              params: gtsam.LevenbergMarquardtParams | gtsam.GaussNewtonParams | None = None,
              linear_solver: str = "auto", optimizer_class=None) -> OptimizeResult:
    """``posegraph.optimize``-compatible entry point for ``--backend batch``.

    ``progress`` receives a :class:`lie_factors.results.IterationInfo` after
    each iteration; returns a :class:`lie_factors.results.OptimizeResult`.
    ``max_iterations=0`` runs none; ``optimizer_class``: a subclass of
    :class:`BatchLevenbergMarquardt` (e.g. ``batch.robust.WeightedLevenbergMarquardt``).  Bad input and unsolvable systems raise
    :class:`lie_factors.errors.PoseGraphError`.
    """
    if params is None:
        params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    # Compilation of the loops (first run on a machine) is not optimization time.
    clock = Stopwatch()
    log = IterationLog(progress)
    try:
        cls = BatchLevenbergMarquardt if optimizer_class is None else optimizer_class
        opt = cls(graph, initial, params, linear_solver=linear_solver)
        log.restart()
        res = opt.optimize(log)
    except BatchError as exc:
        raise PoseGraphError(f"batch backend: {exc}") from None
    except RuntimeError as exc:
        raise PoseGraphError(f"optimization failed: {first_line(exc)}") from None
    return OptimizeResult(res.values, res.iterations, res.initial_error, res.final_error,
                          clock.seconds(), res.converged, log.history)
