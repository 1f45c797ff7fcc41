"""Powell's dogleg as GTSAM runs it, written once for every optimizer of lie_factors.

GTSAM's ``DoglegOptimizer.cpp`` (``iterate``) and ``DoglegOptimizerImpl.h`` / ``.cpp``
(``Iterate``, ``ComputeDoglegPoint``, ``ComputeBlend``) are the specification.  One
iteration linearizes once and computes two points of the quadratic model
M(δ) = ½‖Aδ − b‖² (H = AᵀA, g = Aᵀb):

* the steepest-descent (Cauchy) point δ_u = (gᵀg / gᵀHg)·g, the minimum of M along the
  gradient (GTSAM's ``optimizeGradientSearch``);
* the Gauss–Newton point δ_n = H⁻¹g (GTSAM's ``optimize`` of the eliminated system).

Within a trust region of radius Δ, the dogleg point :func:`dogleg_point` is δ_u scaled to the
boundary (Δ < ‖δ_u‖), the point of the segment δ_u → δ_n on the boundary (‖δ_u‖ ≤ Δ <
‖δ_n‖: ‖(1 − τ)δ_u + τδ_n‖ = Δ, a quadratic in τ), or δ_n (Δ ≥ ‖δ_n‖).  The gain ratio
ρ = (f(x) − f(x ⊕ δ)) / (M(0) − M(δ)) (0.5 where either change is below 1e-15) then decides
(:func:`next_radius`): ρ ≥ 0.75, Δ ← max(Δ, 3‖δ‖); 0.25 ≤ ρ < 0.75, Δ kept; 0 ≤ ρ < 0.25, Δ
halved unless at most 1e-5; ρ < 0 (the error grew, or is not a number), Δ is halved and the
point computed again, and at Δ ≤ 1e-5 the iteration ends without a step.  The adaptation
modes say whether a step that changed Δ is tried again within the same iteration.

Steps are written as ``a·δ_u + b·δ_n`` (the coefficients, not the vectors), so that GTSAM's
``VectorValues`` (the drop-in :class:`lie_factors.optimizers.DoglegOptimizer`), the batch
solver's arrays (:class:`lie_factors.batch.BatchLevenbergMarquardt` with
``gtsam.DoglegParams``) and the smoother's (:mod:`lie_factors.incremental.dogleg`, ISAM2's
Dogleg) share this code.  :class:`Dogleg` is the iteration of GTSAM's ``DoglegOptimizer``
over hooks that supply the linear algebra; :func:`line_search` is the outward search of
``ISAM2DoglegLineSearchParams``.

This module imports numpy only.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

__all__ = ["MIN_DELTA", "MODES", "ONE_STEP_PER_ITERATION", "SEARCH_EACH_ITERATION", "SEARCH_REDUCE_ONLY",
           "TAKE", "RETRY", "GIVE_UP", "dogleg_point", "gain_ratio", "next_radius", "iterate", "line_search",
           "Dogleg"]

#: GTSAM's ``DoglegOptimizerImpl::TrustRegionAdaptationMode``.
SEARCH_EACH_ITERATION, SEARCH_REDUCE_ONLY, ONE_STEP_PER_ITERATION = ("SEARCH_EACH_ITERATION", "SEARCH_REDUCE_ONLY",
                                                                      "ONE_STEP_PER_ITERATION")
MODES = (SEARCH_EACH_ITERATION, SEARCH_REDUCE_ONLY, ONE_STEP_PER_ITERATION)

#: Δ is not halved below this (GTSAM's constant).
MIN_DELTA = 1e-5
#: What :func:`next_radius` says of a trial step.
TAKE, RETRY, GIVE_UP = "take", "retry", "give up"
#: Changes of f or M below this make ρ 0.5 (GTSAM's absolute test).
_TINY_CHANGE = 1e-15
_EPS = float(np.finfo(float).eps)


def dogleg_point(delta: float, uu: float, nn: float, un: float, verbose: bool = False) -> tuple[float, float]:
    """(a, b): the dogleg point is a·δ_u + b·δ_n for the trust-region radius ``delta``, given
    ‖δ_u‖² = ``uu``, ‖δ_n‖² = ``nn`` and δ_u·δ_n = ``un`` (GTSAM's ``ComputeDoglegPoint`` and
    ``ComputeBlend``): on the steepest-descent leg (b = 0), on the blend (a = 1 − τ, b = τ with
    ‖(1 − τ)δ_u + τδ_n‖ = Δ), or the Gauss–Newton point itself (a = 0, b = 1).  ``verbose``
    prints GTSAM's lines (``verbosityDL`` VERBOSE)."""
    delta_sq = delta * delta
    if verbose:
        print(f"Steepest descent magnitude {math.sqrt(uu)}, Newton's method magnitude {math.sqrt(nn)}")
    if delta_sq < uu:
        fraction = math.sqrt(delta_sq / uu)
        if verbose:
            print(f"In steepest descent region with fraction {fraction} of steepest descent magnitude")
        return fraction, 0.0
    if delta_sq < nn:
        # τ with ‖(1 − τ) δ_u + τ δ_n‖ = Δ: a τ² + b τ + c = 0; the root in [0, 1] (to rounding).
        a = uu - 2.0 * un + nn
        b = 2.0 * (un - uu)
        c = uu - delta_sq
        root = math.sqrt(b * b - 4.0 * a * c)
        tau1 = (-b + root) / (2.0 * a)
        tau2 = (-b - root) / (2.0 * a)
        tau = tau1 if -_EPS <= tau1 <= 1.0 + _EPS else tau2
        if verbose:
            print(f"In blend region with fraction {tau} of Newton's method point")
        return 1.0 - tau, tau
    if verbose:
        print("In pure Newton's method region")
    return 0.0, 1.0


def gain_ratio(f_change: float, m_change: float) -> float:
    """ρ = Δf / ΔM, the actual decrease of the error over the model's; 0.5 where either is
    below 1e-15 in magnitude (GTSAM's)."""
    if abs(f_change) < _TINY_CHANGE or abs(m_change) < _TINY_CHANGE:
        return 0.5
    return f_change / m_change


def next_radius(rho: float, delta: float, step_norm: float) -> tuple[str, float]:
    """(what to do with the trial step, the new radius) for the gain ratio ``rho`` of a step of
    norm ``step_norm`` taken inside radius ``delta`` (GTSAM's rule, module docstring):
    :data:`TAKE`, :data:`RETRY` (a smaller region) or :data:`GIVE_UP` (no step this iteration).
    A ρ that is not a number is a failed step, as in GTSAM, where NaN fails every comparison."""
    if rho >= 0.75:
        return TAKE, max(delta, 3.0 * step_norm)
    if rho >= 0.25:
        return TAKE, delta
    if rho >= 0.0:
        return TAKE, 0.5 * delta if delta > MIN_DELTA else delta
    if delta > MIN_DELTA:
        return RETRY, 0.5 * delta
    return GIVE_UP, delta


def iterate(delta: float, mode: str, norms: tuple[float, float, float], evaluate: Callable,
            f_error: float, m_error: float, verbose: bool = False) -> tuple:
    """One dogleg iteration (GTSAM's ``DoglegOptimizerImpl::Iterate``, module docstring).

    ``norms``: (‖δ_u‖², ‖δ_n‖², δ_u·δ_n); ``evaluate(a, b)`` → (f at x ⊕ (a·δ_u + b·δ_n), the
    model's decrease M(0) − M there, ‖a·δ_u + b·δ_n‖); ``f_error``, ``m_error``: f(x) and M(0).
    Returns (a, b, f of the step taken, new Δ), or (0, 0, ``f_error``, Δ) when no step
    decreases f.  Outside ``ONE_STEP_PER_ITERATION``, a step that changed Δ is tried again at
    the new Δ (growing only in ``SEARCH_EACH_ITERATION``), without turning back within the
    iteration."""
    uu, nn, un = norms
    last = None  # "increased" or "decreased": Δ does not go back and forth within one iteration
    while True:
        a, b = dogleg_point(delta, uu, nn, un, verbose)
        new_f, m_change, norm = evaluate(a, b)
        if verbose:
            print(f"delta = {delta}, dx_d_norm = {norm}")
            print(f"f error: {f_error} -> {new_f}")
            print(f"M error: {m_error} -> {m_error - m_change}")
        rho = gain_ratio(f_error - new_f, m_change)
        if verbose:
            print(f"rho = {rho}")
        action, new_delta = next_radius(rho, delta, norm)
        if action == GIVE_UP:
            if verbose:
                print("Warning:  Dog leg stopping because cannot decrease error with minimum delta")
            return 0.0, 0.0, f_error, delta
        if action == RETRY:
            delta, last = new_delta, "decreased"
            continue
        if mode != ONE_STEP_PER_ITERATION:
            grew = (rho >= 0.75 and mode == SEARCH_EACH_ITERATION and abs(new_delta - delta) >= _TINY_CHANGE
                    and last != "decreased")
            shrank = rho < 0.25 and delta > MIN_DELTA and last != "increased"
            if grew or shrank:
                delta, last = new_delta, "increased" if grew else "decreased"
                continue
        return a, b, new_f, new_delta


def line_search(norms: tuple[float, float, float], evaluate: Callable, f_error: float, min_delta: float,
                max_delta: float, step_size: float, sufficient_decrease: float) -> tuple:
    """The outward line search along the dogleg path of riSAM (McGann, Rogers and Kaess,
    "Robust Incremental Smoothing and Mapping", ICRA 2023; its ``DoglegLineSearch``), whose
    parameters GTSAM's ``ISAM2DoglegLineSearchParams`` carries: from the radius
    min(``min_delta``, ‖δ_n‖), the radius grows by ``step_size`` up to min(``max_delta``,
    ‖δ_n‖); a point is taken when its f is below f(x) − ``sufficient_decrease``·radius, and the
    search stops at the first such point that is worse than the one taken.  ``norms`` and
    ``evaluate`` as :func:`iterate` takes them.  Returns (a, b, f, radius) of the point taken
    (the first one when none decreases f enough)."""
    uu, nn, un = norms
    gn = math.sqrt(nn)
    largest = min(max_delta, gn)
    radius = min(min_delta, gn)
    a, b = dogleg_point(radius, uu, nn, un)
    best = (a, b, evaluate(a, b)[0], radius)
    stay = radius < largest
    while stay:
        radius *= step_size
        a, b = dogleg_point(radius, uu, nn, un)
        new_f = evaluate(a, b)[0]
        sufficient = new_f < f_error - sufficient_decrease * radius
        stay = not (sufficient and new_f > best[2]) and radius < largest
        if sufficient:
            best = (a, b, new_f, radius)
    return best


class Dogleg:
    """GTSAM's ``DoglegOptimizer::iterate``: :func:`iterate` in ``ONE_STEP_PER_ITERATION`` mode
    over an optimizer's own linear algebra.

    A subclass calls :meth:`_dl_init` with its ``gtsam.DoglegParams``, sets ``_error`` and
    ``_iterations``, and defines the hooks:

    * ``_dl_linearize() → lin`` (anything the other hooks take);
    * ``_dl_points(lin) → (δ_u, δ_n)``, and ``_dl_dots(δ_u, δ_n) → (‖δ_u‖², ‖δ_n‖², δ_u·δ_n)``;
    * ``_dl_combine(a, δ_u, b, δ_n) → δ`` and ``_dl_norm(δ)``;
    * ``_dl_model(lin, δ) → (M(0), M(δ), M(0) − M(δ))``;
    * ``_dl_evaluate(δ) → (trial point, its error)``, ``_dl_accept(trial point, error)``, and
      ``_dl_keep()`` (no step: the current point stays, as a new state);
    * ``_dl_print_delta(δ)`` (``verbosity`` DELTA).

    Every iteration counts, stepped or not.
    """

    _error: float
    _iterations: int

    def _dl_init(self, params) -> None:
        self._delta = float(params.getDeltaInitial())
        self._verbose_dl = str(params.getVerbosityDL()) != "SILENT"
        self._print_delta = str(params.getVerbosity()) in ("DELTA", "LINEAR")

    def getDelta(self) -> float:
        """The current trust-region radius Δ."""
        return self._delta

    def iterate(self):
        """One iteration (module docstring); returns the linearization (``_dl_linearize``'s)."""
        lin = self._dl_linearize()
        dx_u, dx_n = self._dl_points(lin)
        tried = {}

        def evaluate(a: float, b: float) -> tuple[float, float, float]:
            dx_d = self._dl_combine(a, dx_u, b, dx_n)
            trial, new_f = self._dl_evaluate(dx_d)
            m_change = self._dl_model(lin, dx_d)[2]
            tried[(a, b)] = (dx_d, trial)
            return new_f, m_change, self._dl_norm(dx_d)

        zero = self._dl_combine(0.0, dx_u, 0.0, dx_n)
        m_error = self._dl_model(lin, zero)[0] if self._verbose_dl else 0.0  # M(0), printed only
        a, b, new_f, self._delta = iterate(self._delta, ONE_STEP_PER_ITERATION, self._dl_dots(dx_u, dx_n),
                                           evaluate, self._error, m_error, self._verbose_dl)
        taken = tried.get((a, b)) if (a, b) != (0.0, 0.0) else None
        if self._print_delta:
            # GTSAM prints a zero step where it takes none.
            self._dl_print_delta(taken[0] if taken else zero)
        if taken is None:
            self._dl_keep()
        else:
            self._dl_accept(taken[1], new_f)
            self._error = new_f
        self._iterations += 1
        return lin
