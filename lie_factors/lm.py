"""Levenberg–Marquardt as GTSAM runs it, written once for every optimizer of lie_factors.

GTSAM 4.3's ``LevenbergMarquardtOptimizer.cpp`` (``iterate``, ``tryLambda``),
``LevenbergMarquardtState.h`` (the λ schedule), ``LevenbergMarquardtParams.h``
(the defaults the Python wrapper cannot set) and ``NonlinearOptimizer.cpp``
(``defaultOptimize``, ``checkConvergence``) are the specification:

* :class:`LevenbergMarquardt`: one iteration and the trial of one λ, with the
  λ schedule and ``diagonalDamping``'s clamp.  Its subclasses differ only in
  how a damped step is solved, its linearized cost change computed and the
  trial point evaluated and accepted (the ``_lm_*`` hooks):
  :class:`lie_factors.optimizers.LevenbergMarquardtOptimizer` (GTSAM's
  elimination on ``Values`` held in Python) and
  :class:`lie_factors.batch.BatchLevenbergMarquardt` (normal equations on arrays).
* :func:`default_optimize`: ``defaultOptimize``'s loop and stopping rule on
  any optimizer with ``iterate()``/``error()``/``iterations()`` (ours, or
  GTSAM's own stepped from Python), recorded as an :class:`OptimizeResult`.
* :func:`check_convergence`: GTSAM's ``checkConvergence``.
* What they print, with GTSAM's verbosity levels, is GTSAM's text to the
  digit: numbers go through :data:`COUT`, which formats as ``std::cout`` does.

This module imports GTSAM and numpy only (never numba): the CLI's native
backend runs GTSAM's optimizer through :func:`default_optimize`.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from gtsam import gtsam  # the compiled extension: GTSAM's own classes, whatever is assigned into the package

from .util.timing import Stopwatch

__all__ = [
    "MIN_MODEL_FIDELITY", "MIN_DIAGONAL", "MAX_DIAGONAL", "VERBOSITY", "VERBOSITY_LM", "COUT",
    "IterationInfo", "OptimizeResult", "format_iteration", "ieee_divide", "converged", "check_convergence", "default_optimize",
    "lambda_after_success", "lambda_after_failure", "judge_step", "damping_diagonal", "LevenbergMarquardt",
    "SUMMARY_HEADER",
]

#: ``LevenbergMarquardtParams`` fields without a Python setter (GTSAM's defaults).
MIN_MODEL_FIDELITY = 1e-3
MIN_DIAGONAL = 1e-6
MAX_DIAGONAL = 1e32

#: ``NonlinearOptimizerParams::Verbosity`` and ``LevenbergMarquardtParams::VerbosityLM``, in order.
VERBOSITY = {name: i for i, name in enumerate(("SILENT", "TERMINATION", "ERROR", "VALUES", "DELTA", "LINEAR"))}
VERBOSITY_LM = {name: i for i, name in enumerate(
    ("SILENT", "SUMMARY", "TERMINATION", "LAMBDA", "TRYLAMBDA", "TRYCONFIG", "DAMPED", "TRYDELTA"))}

_SILENT, _TERMINATION, _ERROR, _VALUES = 0, 1, 2, 3
GIVING_UP = "Warning:  Levenberg-Marquardt giving up because cannot decrease error with maximum lambda"
_SUMMARY, _TRYLAMBDA, _DAMPED, _TRYDELTA = 1, 4, 6, 7
_EPS = float(np.finfo(float).eps)

#: Header of the SUMMARY table, GTSAM 4.3's.
SUMMARY_HEADER = "iter      cost      cost_change    lambda  success lin_time  solve_time total_time"


# --------------------------------------------------------------------------- #
# GTSAM's printing
# --------------------------------------------------------------------------- #

class _Cout:
    """``std::cout`` as GTSAM's prints use it: a double is printed as printf's
    ``%.{precision}g`` (C++'s default float format), and ``setprecision`` stays
    in force for every later print of the process.  GTSAM's SUMMARY table sets
    it to 2 after a row's first number, ``checkConvergence`` to 12 when it
    prints: the same runs therefore print the same digits here as in GTSAM.

    Every line is flushed (as ``std::endl`` flushes) so that it stays in order
    with what GTSAM's C++ prints; before GTSAM prints (``Values::print``),
    :meth:`sync` gives C++'s ``std::cout`` the precision printed here.
    """

    def __init__(self):
        self.precision = 6
        self._cpp = 6  # what this process's std::cout is known to have

    def sync(self) -> None:
        """Flush, and set C++'s ``std::cout`` to this precision (12 or 2: the only values
        GTSAM's optimizers set) by running GTSAM's own code that sets it, its text discarded."""
        sys.stdout.flush()
        if self.precision == self._cpp or self.precision not in (2, 12):
            return
        capture = gtsam.RedirectCout()
        try:
            if self.precision == 12:
                gtsam.checkConvergence(0.0, 0.0, 0.0, 2.0, 1.0, gtsam.NonlinearOptimizerParams.Verbosity.ERROR)
            else:  # one SUMMARY row of an empty problem (λ = 1e-5 reaches the bound 1e-4 at once)
                p = gtsam.LevenbergMarquardtParams()
                p.setVerbosityLM("SUMMARY")
                p.setlambdaUpperBound(1e-4)
                gtsam.LevenbergMarquardtOptimizer(gtsam.NonlinearFactorGraph(), gtsam.Values(), p).iterate()
        finally:
            del capture
        self._cpp = self.precision

    def gtsam_printed(self, precision: int) -> None:
        """GTSAM's C++ code (its own optimizer's prints) set ``std::cout``'s precision."""
        self.precision = self._cpp = precision

    def num(self, x, width: int = 0, precision: int | None = None) -> str:
        """``std::setw(width) << std::setprecision(precision) << x`` (precision stays)."""
        if precision is not None:
            self.precision = precision
        x = float(x)
        text = f"{x:.{max(self.precision, 1)}g}"
        if x != x and math.copysign(1.0, x) < 0:
            text = "-nan"  # glibc prints the sign of a NaN
        return text.rjust(width)

    @staticmethod
    def line(text: str) -> None:
        sys.stdout.write(text + "\n")
        sys.stdout.flush()


#: The one stream state of the process (see :class:`_Cout`).
COUT = _Cout()


def ieee_divide(a: float, b: float) -> float:
    """``a / b`` in IEEE arithmetic (C++'s): ±inf or nan where Python would raise."""
    if b != 0.0:
        return a / b
    if a != a or a == 0.0:
        return math.nan
    return math.copysign(math.inf, a) * math.copysign(1.0, b)


# --------------------------------------------------------------------------- #
# The record of a run
# --------------------------------------------------------------------------- #

@dataclass
class IterationInfo:
    """One iteration: its number (1-based), the error and λ after it, its wall seconds
    (numba compilation excluded)."""

    iteration: int
    error: float
    lambda_: float
    seconds: float


@dataclass(repr=False)
class OptimizeResult:
    """One optimization run, whichever optimizer ran it.

    ``errors[0]`` is the initial error and ``errors[k]`` the error after
    iteration k; ``lambdas`` likewise λ (0 for Gauss–Newton, and for
    optimizers without a λ); ``history`` the :class:`IterationInfo` of each
    iteration.  (A GNC run records its initial error and final weighted cost
    only.)  ``seconds``: wall time of the run as its caller measures it;
    ``timings``: the batch solver's split of it (``batch.TIMING_KEYS``);
    ``inner_iterations``: λ tried, as GTSAM's ``getInnerIterations`` (0 where
    the optimizer does not say: GTSAM's own from Python);
    ``linear_solver``: the batch solver's; ``start``: the values LM started
    from (set by the CLI's run).  ``values`` may be None where the caller
    builds them on demand.
    """

    values: gtsam.Values | None
    iterations: int
    errors: list[float]
    lambdas: list[float]
    seconds: float
    converged: bool
    history: list[IterationInfo] = field(default_factory=list)
    inner_iterations: int = 0
    timings: dict = field(default_factory=dict)
    linear_solver: str = ""
    start: gtsam.Values | None = None

    @property
    def initial_error(self) -> float:
        return self.errors[0]

    @property
    def final_error(self) -> float:
        return self.errors[-1]

    def __repr__(self) -> str:
        state = "converged" if self.converged else "not converged"
        return (f"<OptimizeResult: error {self.initial_error:.6g} -> {self.final_error:.6g}, "
                f"{self.iterations} iterations, {state}, {self.seconds:.3f} s>")


def format_iteration(info: IterationInfo) -> str:
    """One progress line of the CLI (stderr): iteration, error, λ, seconds (where the iteration
    was timed on its own: the small path times its solve as a whole)."""
    line = f"iter {info.iteration:4d}  error {info.error:.6e}  lambda {info.lambda_:.2e}"
    return line if math.isnan(info.seconds) else line + f"  time {info.seconds:.3f} s"


# --------------------------------------------------------------------------- #
# defaultOptimize
# --------------------------------------------------------------------------- #

def converged(relative_tol: float, absolute_tol: float, error_tol: float, current: float, new: float) -> bool:
    """GTSAM's ``checkConvergence``, silent (:func:`check_convergence` prints it too).  Plain
    arithmetic: compiled code runs this very function (:mod:`lie_factors.batch.small_kernels`)."""
    if new <= error_tol:
        return True
    absolute = current - new
    return (relative_tol != 0.0 and ieee_divide(absolute, current) <= relative_tol) or absolute <= absolute_tol


def check_convergence(relative_tol: float, absolute_tol: float, error_tol: float,
                      current: float, new: float, verbosity: int = _SILENT) -> bool:
    """GTSAM's ``checkConvergence``: the new error is ≤ errorTol, or the decrease
    ``current − new`` is ≤ absoluteErrorTol, or (relativeErrorTol ≠ 0) the relative
    decrease ``(current − new)/current`` is ≤ relativeErrorTol.  Prints what GTSAM
    prints at ``verbosity`` (a :data:`VERBOSITY` level)."""
    say, num = COUT.line, COUT.num
    if verbosity >= _ERROR:
        say(f"errorThreshold: {num(new)} {'<' if new <= error_tol else '>'} {num(error_tol)}")
    if new <= error_tol:
        return True
    absolute = current - new
    if verbosity >= _ERROR:
        say(f"absoluteDecrease: {num(absolute, precision=12)} {'<' if absolute <= absolute_tol else '>='} "
            f"{num(absolute_tol)}")
    relative = ieee_divide(absolute, current)
    if verbosity >= _ERROR:
        say(f"relativeDecrease: {num(relative, precision=12)} {'<' if relative <= relative_tol else '>='} "
            f"{num(relative_tol)}")
    done = converged(relative_tol, absolute_tol, error_tol, current, new)
    if verbosity >= _TERMINATION and done:
        say("converged" if absolute >= 0.0 else
            "Warning:  stopping nonlinear iterations because error increased")
        say(f"errorThreshold: {num(new)} <? {num(error_tol)}")
        say(f"absoluteDecrease: {num(absolute, precision=12)} <? {num(absolute_tol)}")
        say(f"relativeDecrease: {num(relative, precision=12)} <? {num(relative_tol)}")
    return done


def _print_values(opt, title: str) -> None:
    values = opt.values()
    if values is not None:  # an optimizer may build its values only at the end
        COUT.sync()
        values.print(title)


def default_optimize(opt, params, progress: Callable[[IterationInfo], None] | None = None) -> OptimizeResult:
    """GTSAM's ``NonlinearOptimizer::defaultOptimize`` on ``opt``, recorded.

    ``opt``: anything with ``iterate()``, ``error()``, ``iterations()`` and
    ``values()`` (``lambda_()`` if it has a λ): our optimizers, or GTSAM's own
    stepped from Python.  ``params``: its GTSAM params.  Nothing runs if the
    error is already ≤ errorTol (converged) or iterations ≥ maxIterations;
    otherwise ``iterate()`` while iterations < maxIterations, not
    :func:`check_convergence` and the error before the step is finite.  After
    each iteration ``params.iterationHook(iterations, before, after)`` (as
    GTSAM), then ``progress(IterationInfo)``.  Prints as GTSAM at the params'
    verbosity.

    Returns an :class:`OptimizeResult` without values (``values=None``);
    ``seconds``: this loop's, numba compilation excluded; ``converged``: the
    last convergence test (also evaluated, silently, on the iteration that
    reaches maxIterations, where GTSAM stops without it).
    """
    clock = Stopwatch()
    say, num = COUT.line, COUT.num
    verbosity = VERBOSITY.get(str(params.getVerbosity()), _SILENT)
    error_tol = float(params.getErrorTol())
    max_iterations = int(params.getMaxIterations())
    lambda_of = getattr(opt, "lambda_", None)
    new = float(opt.error())
    errors = [new]
    lambdas = [float(lambda_of()) if lambda_of is not None else 0.0]
    history: list[IterationInfo] = []
    converged = False

    def result() -> OptimizeResult:
        inner = getattr(opt, "getInnerIterations", None)
        return OptimizeResult(None, int(opt.iterations()), errors, lambdas, clock.seconds(), converged,
                              history, int(inner()) if inner is not None else 0)

    if new <= error_tol:
        if verbosity >= _ERROR:
            say(f"Exiting, as error = {num(new)} < {num(error_tol)}")
        converged = True
        return result()
    if verbosity >= _VALUES:
        _print_values(opt, "Initial values")
    if verbosity >= _ERROR:
        say(f"Initial error: {num(new)}")
    if opt.iterations() >= max_iterations:
        if verbosity >= _TERMINATION:
            _say_iterations(opt.iterations(), max_iterations, False)
        return result()
    relative_tol = float(params.getRelativeErrorTol())
    absolute_tol = float(params.getAbsoluteErrorTol())
    hook = params.iterationHook
    # GTSAM's own optimizer prints in C++ (at std::cout's precision), and its LM's SUMMARY
    # rows leave std::cout at precision 2.
    gtsams = isinstance(opt, gtsam.NonlinearOptimizer)
    summary_in_cpp = (gtsams and isinstance(params, gtsam.LevenbergMarquardtParams)
                      and str(params.getVerbosityLM()) == "SUMMARY")
    step = Stopwatch()
    while True:
        current = new
        if gtsams:
            COUT.sync()
        step.restart()
        opt.iterate()
        seconds = step.seconds()
        if summary_in_cpp:
            COUT.gtsam_printed(2)
        new = float(opt.error())
        iterations = int(opt.iterations())
        if hook is not None:
            hook(iterations, current, new)
        lam = float(lambda_of()) if lambda_of is not None else 0.0
        errors.append(new)
        lambdas.append(lam)
        info = IterationInfo(iterations, new, lam, seconds)
        history.append(info)
        if progress is not None:
            progress(info)
        if verbosity >= _VALUES:
            _print_values(opt, "newValues")
        if verbosity >= _ERROR:
            say(f"newError: {num(new)}")
        if iterations >= max_iterations:
            converged = check_convergence(relative_tol, absolute_tol, error_tol, current, new)
            break
        converged = check_convergence(relative_tol, absolute_tol, error_tol, current, new, verbosity)
        if converged or not math.isfinite(current):
            break
    if verbosity >= _TERMINATION:
        _say_iterations(opt.iterations(), max_iterations)
    return result()


def _say_iterations(iterations: int, max_iterations: int, ran: bool = True) -> None:
    """GTSAM's last lines at TERMINATION (whether it stopped at the maximum: when the loop ``ran``)."""
    COUT.line(f"iterations: {iterations} >? {max_iterations}")
    if ran and iterations >= max_iterations:
        COUT.line("Terminating because reached maximum iterations")


def print_termination(params, errors: list, iterations: int, gave_up: int) -> None:
    """What :func:`default_optimize` prints at verbosity TERMINATION, for a loop run elsewhere
    (the small path's compiled one), from its record: ``errors`` (the initial error, then each
    iteration's), the ``iterations`` taken, and ``gave_up``, the times LM stopped at its maximum
    λ (each warned during its iteration, before the last convergence test)."""
    max_iterations = int(params.getMaxIterations())
    if errors[0] <= params.getErrorTol():
        return  # converged at the start: TERMINATION prints nothing
    if len(errors) > 1:  # (else no iteration was allowed)
        for _ in range(gave_up):
            COUT.line(GIVING_UP)
        if iterations < max_iterations:  # (the test on the iteration reaching the maximum is silent)
            check_convergence(float(params.getRelativeErrorTol()), float(params.getAbsoluteErrorTol()),
                              float(params.getErrorTol()), errors[-2], errors[-1], _TERMINATION)
    _say_iterations(iterations, max_iterations, len(errors) > 1)


# --------------------------------------------------------------------------- #
# iterate / tryLambda
# --------------------------------------------------------------------------- #

def lambda_after_success(lam: float, factor: float, fidelity: float, fixed_factor: bool,
                         lower: float) -> tuple[float, float]:
    """(λ, factor) after an accepted step (GTSAM 4.3's ``decreaseLambda``): λ/factor with a fixed
    factor, else λ·max(1/3, 1 − (2·fidelity − 1)³) and the factor back to 2; λ not below
    ``lower``.  Plain arithmetic, which compiled code runs too."""
    if fixed_factor:
        lam = lam / factor
    else:
        lam = lam * max(1.0 / 3.0, 1.0 - (2.0 * fidelity - 1.0) ** 3)
        factor = 2.0  # GTSAM 4.3's decreaseLambda starts the next rejections' factor at 2
    return max(lower, lam), factor


def lambda_after_failure(lam: float, factor: float, fixed_factor: bool) -> tuple[float, float]:
    """(λ, factor) after a rejected step (GTSAM's ``increaseLambda``): λ·factor, and the factor
    doubles unless fixed."""
    return lam * factor, factor if fixed_factor else 2.0 * factor


def judge_step(linear_change: float, old_linear: float, error: float, new_error: float,
               min_model_fidelity: float, relative_tol: float) -> tuple[bool, bool, float]:
    """(accepted, stop trying, model fidelity) of a step GTSAM's ``tryLambda`` evaluated: the
    fidelity Δcost/Δlinear is tested only when Δlinear > ε·(linearized error), and a cost change
    below relativeErrorTol·error stops the iteration."""
    cost_change = error - new_error
    fidelity = 0.0
    success = False
    if linear_change > _EPS * old_linear:
        fidelity = cost_change / linear_change
        success = fidelity > min_model_fidelity
    return success, abs(cost_change) < relative_tol * error, fidelity


def damping_diagonal(hessian_diagonal: np.ndarray) -> np.ndarray:
    """``diagonalDamping``'s D: diag(JᵀJ) clamped to [minDiagonal, maxDiagonal] (GTSAM's
    ``iterate``; the damped system adds λ·D to JᵀJ)."""
    return np.minimum(np.maximum(hessian_diagonal, MIN_DIAGONAL), MAX_DIAGONAL)


class LevenbergMarquardt:
    """GTSAM's ``LevenbergMarquardtOptimizer::iterate``/``tryLambda`` and ``LevenbergMarquardtState``.

    * each iteration linearizes once (and, with ``diagonalDamping``, computes
      D = :func:`damping_diagonal` once); then λ is tried until a step is
      accepted or LM gives up;
    * a try solves the damped system ``JᵀJ + λ·I`` (or ``+ λ·D``); a system
      that cannot be solved counts as a failed try; the step is retracted and
      evaluated only if the linearized cost decreases (Δlinear ≥ 0); it is
      accepted if ``fidelity = Δcost / Δlinear > minModelFidelity``, tested
      only when ``Δlinear > ε·(linearized error)``;
    * accepted: ``λ ← max(lambdaLowerBound, λ·max(1/3, 1 − (2·fidelity − 1)³))``
      and the factor becomes 2, or ``λ ← λ/factor`` with ``useFixedLambdaFactor``;
    * rejected: ``λ ← λ·factor``, the factor doubles unless fixed; LM gives up
      once ``λ ≥ lambdaUpperBound``; it stops trying (no step) when
      ``|Δcost| < relativeErrorTol·error``.

    Prints as GTSAM at the params' ``verbosityLM`` (and ``verbosity``
    TERMINATION's warning); SUMMARY's table has GTSAM 4.3's columns.

    A subclass calls :meth:`_lm_init` with its params, sets ``_error`` (the
    error at the current estimate) and ``_iterations``, and defines the hooks:

    * ``_lm_linearize() → lin`` (anything the other hooks take);
    * ``_lm_hessian_diagonal(lin) → diag(JᵀJ)`` (flat, only with diagonalDamping);
    * ``_lm_damping(lin, D or None) → damping``: what ``_lm_solve`` needs for every λ;
    * ``_lm_solve(lin, damping) → δ``, or None if the damped system at ``_lambda`` cannot be solved;
    * ``_lm_linear_change(lin, δ) → (linearized error at 0, at δ, the decrease)`` (GTSAM's ``deltaError``);
    * ``_lm_evaluate(δ) → (trial point, its error)`` and ``_lm_accept(trial point, error)``;
    * ``_lm_size()``: number of values; ``_lm_delta_norm(δ)``, ``_lm_print_delta(δ)`` for the prints.
    """

    _error: float
    _iterations: int

    def _lm_init(self, params, min_model_fidelity: float = MIN_MODEL_FIDELITY) -> None:
        """Read the schedule from ``params`` (``gtsam.LevenbergMarquardtParams``; other params,
        e.g. Gauss–Newton's: λ stays 0) and start it (:meth:`_lm_reset`)."""
        self._verbosity = VERBOSITY.get(str(params.getVerbosity()), _SILENT)
        self._relative_tol = float(params.getRelativeErrorTol())
        self._min_model_fidelity = float(min_model_fidelity)
        if isinstance(params, gtsam.LevenbergMarquardtParams):
            self._lambda_initial = float(params.getlambdaInitial())
            self._lambda_factor = float(params.getlambdaFactor())
            self._lambda_upper = float(params.getlambdaUpperBound())
            self._lambda_lower = float(params.getlambdaLowerBound())
            self._diagonal_damping = bool(params.getDiagonalDamping())
            self._fixed_factor = bool(params.getUseFixedLambdaFactor())
            self._verbosity_lm = VERBOSITY_LM.get(str(params.getVerbosityLM()), _SILENT)
            self._log_file = params.getLogFile()
        else:
            self._lambda_initial = self._lambda_factor = 0.0
            self._lambda_upper, self._lambda_lower = math.inf, 0.0
            self._diagonal_damping = self._fixed_factor = False
            self._verbosity_lm = _SILENT
            self._log_file = ""
        self._start = time.perf_counter()
        self._lm_reset()

    def _lm_reset(self) -> None:
        """λ and its factor back to the params' initial values, no λ tried."""
        self._lambda = self._lambda_initial
        self._factor = self._lambda_factor
        self._inner = 0

    # ------------------------------------------------------------ state
    def error(self) -> float:
        """The error at the current estimate."""
        return self._error

    def iterations(self) -> int:
        """Number of iterations (accepted steps) so far."""
        return self._iterations

    def lambda_(self) -> float:
        """The current λ."""
        return self._lambda

    def getInnerIterations(self) -> int:
        """Total number of λ tried (GTSAM's ``getInnerIterations``)."""
        return self._inner

    # ------------------------------------------------------------ the schedule
    def _decrease_lambda(self, fidelity: float) -> None:
        self._lambda, self._factor = lambda_after_success(self._lambda, self._factor, fidelity, self._fixed_factor,
                                                          self._lambda_lower)
        self._inner += 1

    def _increase_lambda(self) -> None:
        self._lambda, self._factor = lambda_after_failure(self._lambda, self._factor, self._fixed_factor)
        self._inner += 1

    def _write_log(self, error: float) -> None:
        """GTSAM's ``writeLogFile``: inner iterations, seconds, error, λ, iterations (a fresh stream)."""
        with open(self._log_file, "a") as fh:
            fh.write(f"{self._inner},{time.perf_counter() - self._start:.6g},{error:.6g},"
                     f"{self._lambda:.6g},{self._iterations}\n")

    # ------------------------------------------------------------ iterate / tryLambda
    def iterate(self):
        """One iteration: linearize once, then try λ until a step is accepted or LM gives up.
        Returns the linearization (``_lm_linearize``'s)."""
        start = time.perf_counter()
        if self._verbosity_lm >= _DAMPED:
            COUT.line("linearizing = ")
        lin = self._lm_linearize()
        self._lin_seconds = time.perf_counter() - start
        self._iteration_start = start
        if self._inner == 0:
            if self._log_file:
                self._write_log(self._error)
            if self._verbosity_lm == _SUMMARY:
                COUT.line(f"Initial error: {COUT.num(self._error)}, values: {self._lm_size()}")
        diagonal = damping_diagonal(self._lm_hessian_diagonal(lin)) if self._diagonal_damping else None
        damping = self._lm_damping(lin, diagonal)
        while not self._try_lambda(lin, damping):
            if self._log_file:
                self._write_log(self._error)
        return lin

    def _try_lambda(self, lin, damping) -> bool:
        """One λ; True when the iteration is over (accepted, given up, or no progress possible)."""
        start = time.perf_counter()
        level = self._verbosity_lm
        verbose = level >= _TRYLAMBDA
        say, num = COUT.line, COUT.num
        if verbose:
            say(f"trying lambda = {num(self._lambda)}")
        if level >= _DAMPED:
            say(f"building damped system with lambda {num(self._lambda)}")
        delta = self._lm_solve(lin, damping)
        fidelity = 0.0
        success = stop = False
        new_error = math.inf
        cost_change = 0.0
        trial = None
        if delta is not None:
            if verbose:
                say(f"linear delta norm = {num(self._lm_delta_norm(delta))}")
            if level >= _TRYDELTA:
                COUT.sync()
                self._lm_print_delta(delta)
            old_linear, new_linear, linear_change = self._lm_linear_change(lin, delta)
            if verbose:
                say(f"newLinearizedError = {num(new_linear)}  linearizedCostChange = {num(linear_change)}")
            if linear_change >= 0:
                if verbose:
                    say("calculating error:")
                trial, new_error = self._lm_evaluate(delta)
                if verbose:
                    say(f"old error ({num(self._error)}) new (tentative) error ({num(new_error)})")
                cost_change = self._error - new_error
                success, stop, fidelity = judge_step(linear_change, old_linear, self._error, new_error,
                                                     self._min_model_fidelity, self._relative_tol)
                if verbose and linear_change > _EPS * old_linear:
                    say(f"modelFidelity: {num(fidelity)}")
                if verbose and stop:
                    say(f"abs(costChange)={num(abs(cost_change))}  "
                        f"minAbsoluteTolerance={num(self._relative_tol * self._error)} "
                        f"(relativeErrorTol={num(self._relative_tol)})")
        if level == _SUMMARY:
            self._summary_row(new_error, cost_change, delta is not None, start)
        if success:
            self._decrease_lambda(fidelity)
            self._lm_accept(trial, new_error)
            self._error = new_error
            self._iterations += 1
            return True
        if not stop:
            if verbose:
                say("increasing lambda")
            self._increase_lambda()
            if self._lambda >= self._lambda_upper:
                if self._verbosity >= _TERMINATION or level == _SUMMARY:
                    say(GIVING_UP)
                return True
            return False
        if verbose:
            say("Levenberg-Marquardt: stopping as relative cost reduction is small")
        return True

    def _summary_row(self, new_error: float, cost_change: float, solved: bool, start: float) -> None:
        """A row of GTSAM 4.3's SUMMARY table (the header before the first iteration's rows):
        the linearization's, this try's and the iteration's seconds so far."""
        now = time.perf_counter()
        num = COUT.num
        if self._iterations == 0:
            COUT.line(SUMMARY_HEADER)
        COUT.line(f"{self._iterations:4d} {num(new_error, 12)} {num(cost_change, 12, 2)} "
                  f"{num(self._lambda, 10, 2)} {int(solved):6d} {num(self._lin_seconds, 10, 2)} "
                  f"{num(now - start, 10, 2)} {num(now - self._iteration_start, 10, 2)}")
