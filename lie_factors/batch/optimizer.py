"""Levenberg–Marquardt, Gauss–Newton and Powell's dogleg over the batch linear system, with GTSAM's semantics.

GTSAM's ``LevenbergMarquardtOptimizer`` (its λ schedule, ``tryLambda``,
``iterate``, ``defaultOptimize``, ``checkConvergence`` and prints: the one
policy of :mod:`lie_factors.lm`), ``GaussNewtonOptimizer`` and ``DoglegOptimizer``
(the one policy of :mod:`lie_factors.dogleg`); what this module supplies is how a
linear step is computed (:mod:`lie_factors.batch.system` assembles ``H + damping``,
:mod:`lie_factors.batch.solvers` factors it) and how a trial point is evaluated.
See :class:`BatchLevenbergMarquardt`.

Usage::

    from lie_factors import batch
    result = batch.optimize(graph, initial)                 # LM, GTSAM's default params
    result = batch.optimize(graph, initial, gtsam.GaussNewtonParams())
    result = batch.optimize(graph, initial, gtsam.DoglegParams())
    result.values, result.iterations, result.errors, result.seconds, result.timings
"""

from __future__ import annotations

import math
import time
from typing import Callable

import gtsam
import numpy as np

from .. import dogleg, lm
from ..lm import IterationInfo, OptimizeResult
from ..util.timing import Stopwatch
from . import small, solvers
from .graph import Problem, key_name
from ..errors import IndeterminantLinearSystem, InputError, NotPositiveDefinite
from .system import LinearSystem

#: Keys of ``OptimizeResult.timings`` (seconds, summed over the run).
TIMING_KEYS = ("setup", "linearize", "assemble", "factorize", "solve", "retract", "error", "values", "other")
#: The params whose algorithm the batch solver runs.
PARAMS = (gtsam.LevenbergMarquardtParams, gtsam.GaussNewtonParams, gtsam.DoglegParams)


class BatchLevenbergMarquardt(lm.LevenbergMarquardt, dogleg.Dogleg):
    """Levenberg–Marquardt (or Gauss–Newton, or dogleg) over ``graph`` from ``initial``, mirroring GTSAM.

    ``params``: ``gtsam.LevenbergMarquardtParams`` (default),
    ``gtsam.GaussNewtonParams`` (same loop, no damping; a graph that does not
    determine every variable raises :class:`IndeterminantLinearSystem`, decided on
    its structure first (:meth:`Problem.undetermined`), then by the pivot rule of
    :mod:`lie_factors.sparse.pivots`) or ``gtsam.DoglegParams`` (:mod:`lie_factors.dogleg`:
    its Gauss–Newton point refuses such a graph as Gauss–Newton does; its steepest-descent
    point is (gᵀg / gᵀHg)·g, the pinned variables' entries of g 0).  ``linear_solver``:
    ``"auto"`` (CHOLMOD if cvxopt is installed, else GTSAM with a warning),
    ``"cholmod"`` or ``"gtsam"``.  An error at the start that is not a finite number, or
    after a Gauss–Newton step, raises :class:`InputError` naming the factor.

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
    #: Whether the small path (:mod:`lie_factors.batch.small`) computes this class's objective: a
    #: subclass that changes :meth:`objective` says so, and gives its losses by :meth:`_small_losses`.
    small_path = True

    def __init__(self, graph: "gtsam.NonlinearFactorGraph | Problem", initial: gtsam.Values | None,
                 params: gtsam.LevenbergMarquardtParams | gtsam.GaussNewtonParams | None = None,
                 min_model_fidelity: float = lm.MIN_MODEL_FIDELITY, linear_solver: str = "auto",
                 reweight: Callable[[np.ndarray], np.ndarray] | None = None,
                 cost: Callable[[np.ndarray], float] | None = None):
        t0 = time.perf_counter()
        self.reweight, self.cost = reweight, cost
        self.params = params if params is not None else gtsam.LevenbergMarquardtParams()
        if not isinstance(self.params, PARAMS):
            raise TypeError("params must be gtsam.LevenbergMarquardtParams, gtsam.GaussNewtonParams or "
                            f"gtsam.DoglegParams, got {type(self.params).__name__}")
        self.gauss_newton = isinstance(self.params, gtsam.GaussNewtonParams)
        self.dogleg = isinstance(self.params, gtsam.DoglegParams)
        self._lm_init(self.params, min_model_fidelity)
        if self.dogleg:
            self._dl_init(self.params)
        # A Problem (e.g. Problem.from_pose_graph) is used as it is; ``initial`` is then ignored.
        self.problem = (graph if isinstance(graph, Problem)
                        else Problem(graph, initial, group_robust=self.group_robust))
        if self.dogleg and self.problem.constrained and linear_solver not in ("gtsam", "auto"):
            # GTSAM's dogleg takes both points from its elimination, whose QR imposes the constraints
            i = self.problem.native[next(iter(self.problem.constrained))][0]
            raise InputError(f"linear_solver={linear_solver!r}: dogleg on a graph with a hard constraint "
                             f"(factor {i}) takes its points from GTSAM's elimination: use "
                             "linear_solver='gtsam' (or 'auto')")
        self._linear_solver = linear_solver
        self._system = self._solver = None
        undamped = self.gauss_newton or self.dogleg
        self._structure_checked = not undamped
        self.timings = dict.fromkeys(TIMING_KEYS, 0.0)
        self._iterations = 0
        # The whole solve in one compiled call where the problem allows it (lie_factors.batch.small);
        # the linear system and its solver are then never built.
        self.small_refusal = "linear_solver=" + repr(linear_solver) if linear_solver != "auto" else small.refusal(
            self.problem, self.params, reweight is not None or cost is not None or not self.small_path,
            type(self)._small_losses is not BatchLevenbergMarquardt._small_losses)
        self._small = small.SmallSolve(self.problem, self.params) if self.small_refusal is None else None
        if self._small is None:
            self._linear()
        self._setup()
        t1 = time.perf_counter()
        self._error = self.objective()
        if not math.isfinite(self._error):
            raise self.problem.nonfinite("at the initial values")
        self.timings["error"] += time.perf_counter() - t1
        self.timings["setup"] += t1 - t0

    def _linear(self) -> None:
        """The linear system and its solver (built once, where the small path does not run)."""
        if self._system is not None:
            return
        linear_solver = self._linear_solver
        if self.dogleg and self.problem.constrained:
            linear_solver = "gtsam"
        self._system = LinearSystem(self.problem)
        # Gauss–Newton's (and dogleg's) undamped system must determine every variable (the pivot
        # rule of lie_factors.sparse.pivots); LM's damped one is GTSAM's: a pivot that is not > 0 raises λ.
        undamped = self.gauss_newton or self.dogleg
        self._solver = solvers.make(linear_solver, self._system, solvers.PIVOT_TOLERANCE if undamped else 0.0)

    # ---------------------------------------------------------------- state
    @property
    def system(self) -> LinearSystem:
        """The normal equations (:mod:`lie_factors.batch.system`), built on first use."""
        self._linear()
        return self._system

    @property
    def solver(self):
        """The linear solver (:mod:`lie_factors.batch.solvers`), built on first use."""
        self._linear()
        return self._solver

    @property
    def blocks(self):
        return self.problem.blocks

    @property
    def linear_solver(self) -> str:
        """The linear solver's name: ``"small"`` where the whole solve is one compiled call."""
        return "small" if self._small is not None else self.solver.name

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

    # ---------------------------------------------------------------- dogleg.Dogleg's hooks
    def _dl_linearize(self) -> float:
        return self._linearize()

    def _dl_points(self, linear_error0: float) -> tuple[np.ndarray, np.ndarray]:
        """(δ_u, δ_n): the steepest-descent point (gᵀg / gᵀHg)·g and the Gauss–Newton point H⁻¹g
        (with GTSAM's elimination as the linear solver: its Bayes tree's, as GTSAM's dogleg)."""
        points = getattr(self.solver, "dogleg_points", None)
        if points is not None:
            try:
                dx_u, dx_n, self._tree = points()
            except NotPositiveDefinite as exc:
                raise self._singular(exc) from None
            return dx_u, dx_n
        self._tree = None
        dx_n = self._gauss_newton_step()
        g = self.system.free(self.system.rhs)
        with np.errstate(divide="ignore", invalid="ignore"):  # g = 0: 0/0, NaN, as in GTSAM's C++
            step = np.float64(g @ g) / np.float64(self.system.curvature(g))
        return step * g, dx_n

    @staticmethod
    def _dl_dots(dx_u: np.ndarray, dx_n: np.ndarray) -> tuple[float, float, float]:
        return float(dx_u @ dx_u), float(dx_n @ dx_n), float(dx_u @ dx_n)

    @staticmethod
    def _dl_combine(s_u: float, dx_u: np.ndarray, s_n: float, dx_n: np.ndarray) -> np.ndarray:
        if s_n == 0.0:
            return s_u * dx_u
        if s_u == 0.0 and s_n == 1.0:
            return dx_n
        return s_u * dx_u + s_n * dx_n

    _dl_norm = _lm_delta_norm

    def _dl_model(self, linear_error0: float, delta: np.ndarray) -> tuple[float, float, float]:
        if self._tree is not None:
            m_error = self.solver.model_error(self._tree, np.zeros_like(delta))
            new_m = self.solver.model_error(self._tree, delta)
            return m_error, new_m, m_error - new_m
        return self._lm_linear_change(linear_error0, delta)

    def _dl_evaluate(self, delta: np.ndarray):
        return self._lm_evaluate(delta)

    def _dl_accept(self, trial, error: float) -> None:
        self.problem.accept(*trial)

    def _dl_keep(self) -> None:
        """No step: the estimate stays."""

    def _dl_print_delta(self, delta: np.ndarray) -> None:
        lm.COUT.sync()
        self._lm_print_delta(delta)

    # ---------------------------------------------------------------- loop
    @property
    def _method(self) -> str:
        return "Dogleg" if self.dogleg else "Gauss-Newton" if self.gauss_newton else "Levenberg-Marquardt"

    def iterate(self) -> None:
        """One iteration: linearize and assemble once, then (LM) try λ until a step is accepted
        or LM gives up (:meth:`lie_factors.lm.LevenbergMarquardt.iterate`), or (dogleg) try
        dogleg points until one is taken or Δ is at its minimum (:meth:`lie_factors.dogleg.Dogleg.iterate`)."""
        if self.dogleg:
            self._require_determined()
            dogleg.Dogleg.iterate(self)
            return
        if not self.gauss_newton:
            lm.LevenbergMarquardt.iterate(self)
            return
        self._require_determined()
        self._linearize()
        delta = self._gauss_newton_step()
        Xs, other, error = self._try_step(delta)
        if not math.isfinite(error):
            raise self.problem.nonfinite(f"after Gauss-Newton step {self._iterations + 1}", Xs, other)
        self._error = error
        self.problem.accept(Xs, other)
        self._iterations += 1
        self._inner += 1

    def _gauss_newton_step(self) -> np.ndarray:
        """δ = H⁻¹g of the last linearization, or :class:`IndeterminantLinearSystem` naming the
        variable where the factorization stopped."""
        try:
            return self._solve(None)
        except NotPositiveDefinite as exc:
            raise self._singular(exc) from None

    def _singular(self, exc: NotPositiveDefinite, variable: int | None = None) -> IndeterminantLinearSystem:
        """The refusal of a singular system, naming the variable where the factorization stopped
        (``variable``, an index into the problem's variables, or found from ``exc.column``)."""
        P = self.problem
        if variable is None:
            variable = self.system.variable_at(exc.column)
        where = "" if variable is None else f" near variable {key_name(P.var_keys[variable])}"
        return IndeterminantLinearSystem(
            f"{self._method}: the linear system is singular{where}: {exc}; the graph does not determine "
            "every variable - add a prior or use Levenberg-Marquardt", variable)

    def _require_determined(self) -> None:
        """Gauss–Newton and dogleg: refuse, before the first factorization, a graph whose structure
        leaves a variable undetermined (:meth:`Problem.undetermined`: exact, whatever the rounding)."""
        if self._structure_checked:
            return
        finding = self.problem.undetermined()
        if finding is not None:
            raise finding.error(f"{self._method}: the linear system is singular",
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
        if self._small is not None and self._iterations == 0:
            result = self._run_small(progress)
        else:
            result = lm.default_optimize(self, self.params, progress)
        t1 = time.perf_counter()
        result.values = self.values() if values else None
        self.timings["values"] += time.perf_counter() - t1
        result.seconds = time.perf_counter() - t0 + self.timings["setup"]
        timings = dict(self.timings)
        timings["other"] = result.seconds - sum(v for k, v in timings.items() if k != "other")
        result.timings = timings
        result.linear_solver = self.linear_solver
        return result

    def _small_losses(self):
        """Each factor's (loss id, parameter, scale) by graph index for the small path, or None
        (Gaussian, scale 1: this class's objective)."""
        return None

    def _run_small(self, progress) -> OptimizeResult:
        """The small path's solve (:class:`lie_factors.batch.small.SmallSolve`), its iterations
        reported to ``progress`` after it; the optimizer then holds its estimate."""
        if self.gauss_newton:
            self._require_determined()
        try:
            result = self._small.run(self._small_losses())
        except small.Singular as exc:
            raise self._singular(exc, exc.variable) from None
        self._error = result.final_error
        self._iterations = result.iterations
        self._inner = result.inner_iterations
        if result.lambdas:
            self._lambda = result.lambdas[-1]
        if progress is not None:
            for info in result.history:
                progress(info)
        if str(self.params.getVerbosity()) == "TERMINATION":
            lm.print_termination(self.params, result.errors, result.iterations, self._small.gave_up)
        return result


def optimize(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values,
             params: gtsam.LevenbergMarquardtParams | gtsam.GaussNewtonParams | gtsam.DoglegParams | None = None,
             progress: Callable[[IterationInfo], None] | None = None,
             linear_solver: str = "auto", **hooks) -> OptimizeResult:
    """Batch Levenberg–Marquardt, Gauss–Newton or dogleg (see :class:`BatchLevenbergMarquardt`;
    ``hooks``: ``reweight``, ``cost``); ``seconds``: the solver's construction and iterations,
    numba compilation excluded (as :func:`lie_factors.optimize`'s)."""
    clock = Stopwatch()
    opt = BatchLevenbergMarquardt(graph, initial, params, linear_solver=linear_solver, **hooks)
    result = opt.optimize(progress)
    result.seconds = clock.seconds()
    return result
