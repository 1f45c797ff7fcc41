"""Levenberg–Marquardt and Gauss–Newton over the batch linear system, with GTSAM's semantics.

GTSAM's ``LevenbergMarquardtOptimizer`` (its λ schedule, ``tryLambda``,
``iterate``, ``defaultOptimize``, ``checkConvergence`` and prints: the one
policy of :mod:`lie_factors.lm`) and ``GaussNewtonOptimizer``; what this module
supplies is how a linear step is computed (:mod:`lie_factors.batch.system`
assembles ``H + damping``, :mod:`lie_factors.batch.solvers` factors it) and how
a trial point is evaluated.  See :class:`BatchLevenbergMarquardt`.

Usage::

    from lie_factors import batch
    result = batch.optimize(graph, initial)                 # LM, GTSAM's default params
    result = batch.optimize(graph, initial, gtsam.GaussNewtonParams())
    result.values, result.iterations, result.errors, result.seconds, result.timings
"""

from __future__ import annotations

import time
from typing import Callable

import gtsam
import numpy as np

from .. import lm
from ..lm import IterationInfo, OptimizeResult
from ..util.timing import Stopwatch
from . import solvers
from .graph import Problem, key_name
from ..errors import IndeterminantLinearSystem, InputError, NotPositiveDefinite
from .system import LinearSystem

#: Keys of ``OptimizeResult.timings`` (seconds, summed over the run).
TIMING_KEYS = ("setup", "linearize", "assemble", "factorize", "solve", "retract", "error", "values", "other")


class BatchLevenbergMarquardt(lm.LevenbergMarquardt):
    """Levenberg–Marquardt (or Gauss–Newton) over ``graph`` from ``initial``, mirroring GTSAM.

    ``params``: ``gtsam.LevenbergMarquardtParams`` (default) or
    ``gtsam.GaussNewtonParams`` (same loop, no damping; a graph that does not
    determine every variable raises :class:`IndeterminantLinearSystem`, decided on
    its structure first (:meth:`Problem.undetermined`), then by the pivot rule of
    :mod:`lie_factors.sparse.pivots`).  ``linear_solver``:
    ``"auto"`` (CHOLMOD if cvxopt is installed, else GTSAM with a warning),
    ``"cholmod"`` or ``"gtsam"``.

    LM is :class:`lie_factors.lm.LevenbergMarquardt` (GTSAM's λ schedule,
    ``diagonalDamping``, model fidelity, prints) and :meth:`optimize` is
    :func:`lie_factors.lm.default_optimize`; the damped system is ``H + λ·I``
    on every variable of the linear system, or ``H + λ·D`` with
    ``diagonalDamping``, factored by the linear solver (a system it cannot
    factor counts as a failed try).

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

    def __init__(self, graph: "gtsam.NonlinearFactorGraph | Problem", initial: gtsam.Values | None,
                 params: gtsam.LevenbergMarquardtParams | gtsam.GaussNewtonParams | None = None,
                 min_model_fidelity: float = lm.MIN_MODEL_FIDELITY, linear_solver: str = "auto",
                 reweight: Callable[[np.ndarray], np.ndarray] | None = None,
                 cost: Callable[[np.ndarray], float] | None = None):
        t0 = time.perf_counter()
        self.reweight, self.cost = reweight, cost
        self.params = params if params is not None else gtsam.LevenbergMarquardtParams()
        if not isinstance(self.params, (gtsam.LevenbergMarquardtParams, gtsam.GaussNewtonParams)):
            raise TypeError("params must be gtsam.LevenbergMarquardtParams or gtsam.GaussNewtonParams, "
                            f"got {type(self.params).__name__}")
        self.gauss_newton = isinstance(self.params, gtsam.GaussNewtonParams)
        self._lm_init(self.params, min_model_fidelity)
        # A Problem (e.g. Problem.from_pose_graph) is used as it is; ``initial`` is then ignored.
        self.problem = (graph if isinstance(graph, Problem)
                        else Problem(graph, initial, group_robust=self.group_robust))
        self.system = LinearSystem(self.problem)
        # Gauss–Newton's system must determine every variable (the pivot rule of
        # lie_factors.sparse.pivots); LM's damped one is GTSAM's: a pivot that is not > 0 raises λ.
        self.solver = solvers.make(linear_solver, self.system,
                                   solvers.PIVOT_TOLERANCE if self.gauss_newton else 0.0)
        self._structure_checked = not self.gauss_newton
        self.timings = dict.fromkeys(TIMING_KEYS, 0.0)
        self._iterations = 0
        self._setup()
        t1 = time.perf_counter()
        self._error = self.objective()
        self.timings["error"] += time.perf_counter() - t1
        self.timings["setup"] += t1 - t0

    # ---------------------------------------------------------------- state
    @property
    def blocks(self):
        return self.problem.blocks

    @property
    def linear_solver(self) -> str:
        return self.solver.name

    @property
    def inner_iterations(self) -> int:
        """λ tried so far (GTSAM's ``getInnerIterations``)."""
        return self._inner

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
        if self.reweight is None and not self.solver.needs_jacobians:
            # H and g straight from batches of factors: the graph's Jacobians are never all held.
            linear_error0, seconds_lin, seconds_asm = self.system.linearize_assemble()
            T["linearize"] += seconds_lin
            T["assemble"] += seconds_asm
            if np.any(self.system.weights != 1.0):
                linear_error0 = 0.5 * float(self.system.weights @ self.problem.linearized_sqnorms())
            return linear_error0
        t = time.perf_counter()
        linear_error0 = self.problem.linearize()
        if self.reweight is not None:
            sq = self.problem.linearized_sqnorms()
            w = np.asarray(self.reweight(sq), dtype=np.float64)
            if w.shape != sq.shape or not np.all(np.isfinite(w)) or np.any(w < 0):
                raise InputError(f"reweight must return {sq.shape[0]} finite non-negative weights")
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
        solving = self.solver.solve_seconds
        try:
            return self.solver.solve(scale)
        finally:
            # "factorize": the numeric factorization (and damping); "solve": the triangular solves
            solve = self.solver.solve_seconds - solving
            self.timings["factorize"] += time.perf_counter() - t - solve
            self.timings["solve"] += solve

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

    # ---------------------------------------------------------------- lm.LevenbergMarquardt's hooks
    def _lm_linearize(self) -> float:
        return self._linearize()

    def _lm_hessian_diagonal(self, linear_error0: float) -> np.ndarray:
        return self.system.hessian_diagonal()

    def _lm_damping(self, linear_error0: float, diagonal: np.ndarray | None) -> np.ndarray | None:
        return diagonal

    def _lm_solve(self, linear_error0: float, diagonal: np.ndarray | None) -> np.ndarray | None:
        scale = np.full(self.system.n, self._lambda) if diagonal is None else self._lambda * diagonal
        try:
            return self._solve(scale)
        except NotPositiveDefinite:  # GTSAM: IndeterminantLinearSystemException, λ goes up
            return None

    def _lm_linear_change(self, linear_error0: float, delta: np.ndarray) -> tuple[float, float, float]:
        t = time.perf_counter()
        change = self.system.linear_change(delta)
        self.timings["error"] += time.perf_counter() - t
        return linear_error0, linear_error0 - change, change

    def _lm_evaluate(self, delta: np.ndarray):
        Xs, other, new_error = self._try_step(delta)
        return (Xs, other), new_error

    def _lm_accept(self, trial, error: float) -> None:
        self.problem.accept(*trial)

    def _lm_size(self) -> int:
        return len(self.problem.managed) + int(self.problem.other.size())

    @staticmethod
    def _lm_delta_norm(delta: np.ndarray) -> float:
        return float(np.linalg.norm(delta))

    def _lm_print_delta(self, delta: np.ndarray) -> None:
        P = self.problem
        vv = gtsam.VectorValues()
        for k, o, d in zip(P.var_keys, P.var_offsets.tolist(), P.var_dims.tolist()):
            vv.insert(k, delta[o:o + d])
        vv.print("delta")

    # ---------------------------------------------------------------- loop
    def iterate(self) -> None:
        """One iteration: linearize and assemble once, then (LM) try λ until a step is accepted
        or LM gives up (:meth:`lie_factors.lm.LevenbergMarquardt.iterate`)."""
        if not self.gauss_newton:
            super().iterate()
            return
        self._require_determined()
        self._linearize()
        try:
            delta = self._solve(None)
        except NotPositiveDefinite as exc:
            P = self.problem
            variable = self.system.variable_at(exc.column)
            where = "" if variable is None else f" near variable {key_name(P.var_keys[variable])}"
            raise IndeterminantLinearSystem(
                f"Gauss-Newton: the linear system is singular{where}: {exc}; the graph does not determine "
                "every variable - add a prior or use Levenberg-Marquardt", variable) from None
        Xs, other, self._error = self._try_step(delta)
        self.problem.accept(Xs, other)
        self._iterations += 1
        self._inner += 1

    def _require_determined(self) -> None:
        """Gauss–Newton: refuse, before the first factorization, a graph whose structure leaves a
        variable undetermined (:meth:`Problem.undetermined`: exact, whatever the rounding)."""
        if self._structure_checked:
            return
        finding = self.problem.undetermined()
        if finding is not None:
            raise finding.error("Gauss-Newton: the linear system is singular",
                                key_name(self.problem.var_keys[finding.variable]))
        self._structure_checked = True

    def optimize(self, progress: Callable[[IterationInfo], None] | None = None,
                 values: bool = True) -> OptimizeResult:
        """GTSAM's ``defaultOptimize`` (:func:`lie_factors.lm.default_optimize`);
        ``progress(IterationInfo)`` after each iteration.

        ``values=False``: ``result.values`` is None (the estimate stays in the
        arrays; :meth:`values` builds the GTSAM Values when asked).  ``seconds``:
        this call's wall time and the set-up's."""
        t0 = time.perf_counter()
        result = lm.default_optimize(self, self.params, progress)
        t1 = time.perf_counter()
        result.values = self.values() if values else None
        self.timings["values"] += time.perf_counter() - t1
        result.seconds = time.perf_counter() - t0 + self.timings["setup"]
        timings = dict(self.timings)
        timings["other"] = result.seconds - sum(v for k, v in timings.items() if k != "other")
        result.timings = timings
        result.linear_solver = self.solver.name
        return result


def optimize(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values,
             params: gtsam.LevenbergMarquardtParams | gtsam.GaussNewtonParams | None = None,
             progress: Callable[[IterationInfo], None] | None = None,
             linear_solver: str = "auto", **hooks) -> OptimizeResult:
    """Batch Levenberg–Marquardt or Gauss–Newton (see :class:`BatchLevenbergMarquardt`;
    ``hooks``: ``reweight``, ``cost``); ``seconds``: the solver's construction and iterations,
    numba compilation excluded (as :func:`lie_factors.optimize`'s)."""
    clock = Stopwatch()
    opt = BatchLevenbergMarquardt(graph, initial, params, linear_solver=linear_solver, **hooks)
    result = opt.optimize(progress)
    result.seconds = clock.seconds()
    return result
