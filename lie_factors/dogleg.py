"""One Dogleg policy: Powell's dogleg step inside a trust region, as GTSAM's ``DoglegOptimizerImpl``.

The dogleg path runs from the steepest-descent (Cauchy) point ``dx_u`` to the
Gauss–Newton point ``dx_n``; the step is where it leaves the trust region of
radius Δ (:func:`dogleg_point`), and Δ follows the gain ratio
ρ = (f(x) − f(x ⊕ dx)) / (M(0) − M(dx)) of the nonlinear error f to its
quadratic model M (:func:`iterate`, GTSAM's ``DoglegOptimizerImpl::Iterate``):
ρ ≥ 0.75: Δ ← max(Δ, 3‖dx‖); 0.25 ≤ ρ < 0.75: Δ kept; 0 ≤ ρ < 0.25: Δ halved (not
below 1e-5); ρ < 0: Δ halved and the step tried again, or at Δ ≤ 1e-5 no step.
ρ is 0.5 when either change is below 1e-15.  The adaptation modes say whether a
step that changed Δ is tried again within the same iteration.

The steps are written as ``a·dx_u + b·dx_n`` (the coefficients, not the vectors),
so that GTSAM's ``VectorValues`` (the drop-in :class:`lie_factors.optimizers.DoglegOptimizer`)
and the smoother's flat arrays (:mod:`lie_factors.incremental`, ISAM2's Dogleg) share this code.
"""

from __future__ import annotations

import math
from typing import Callable

#: GTSAM's ``DoglegOptimizerImpl::TrustRegionAdaptationMode``.
SEARCH_EACH_ITERATION, SEARCH_REDUCE_ONLY, ONE_STEP_PER_ITERATION = ("SEARCH_EACH_ITERATION", "SEARCH_REDUCE_ONLY",
                                                                      "ONE_STEP_PER_ITERATION")
MODES = (SEARCH_EACH_ITERATION, SEARCH_REDUCE_ONLY, ONE_STEP_PER_ITERATION)

#: Δ is not halved below this (GTSAM's constant).
MIN_DELTA = 1e-5

_EPS = 2.220446049250313e-16


def dogleg_point(delta: float, uu: float, nn: float, un: float, verbose: bool = False) -> tuple[float, float]:
    """(a, b): the dogleg point a·dx_u + b·dx_n for the trust-region radius ``delta``, from
    ``uu`` = ‖dx_u‖², ``nn`` = ‖dx_n‖², ``un`` = dx_u·dx_n (GTSAM's ``ComputeDoglegPoint``): on
    the steepest-descent leg (b = 0), on the blend (a = 1 − τ, b = τ with ‖(1 − τ)dx_u + τ dx_n‖
    = Δ), or the Gauss–Newton point itself (a = 0, b = 1)."""
    delta_sq = delta * delta
    if verbose:
        print(f"Steepest descent magnitude {math.sqrt(uu)}, Newton's method magnitude {math.sqrt(nn)}")
    if delta_sq < uu:
        if verbose:
            print(f"In steepest descent region with fraction {math.sqrt(delta_sq / uu)} "
                  "of steepest descent magnitude")
        return math.sqrt(delta_sq / uu), 0.0
    if delta_sq < nn:
        # τ with ‖(1 − τ) dx_u + τ dx_n‖ = Δ, 0 ≤ τ ≤ 1: a quadratic in τ.
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


def iterate(delta: float, mode: str, norms: tuple[float, float, float], evaluate: Callable,
            f_error: float, m_error: float, verbose: bool = False) -> tuple:
    """One Dogleg iteration (GTSAM's ``DoglegOptimizerImpl::Iterate``, module docstring).

    ``norms``: (‖dx_u‖², ‖dx_n‖², dx_u·dx_n); ``evaluate(a, b)`` → (f at x ⊕ (a·dx_u + b·dx_n),
    M there, ‖a·dx_u + b·dx_n‖); ``f_error``, ``m_error``: f(x) and M(0).  Returns (a, b,
    f_error of the step taken, new Δ); (0, 0, f_error, Δ) when no step decreases f."""
    uu, nn, un = norms
    last = None  # "increased" or "decreased": Δ does not go back and forth within one iteration
    while True:
        a, b = dogleg_point(delta, uu, nn, un, verbose)
        new_f, new_m, norm = evaluate(a, b)
        if verbose:
            print(f"delta = {delta}, dx_d_norm = {norm}")
            print(f"f error: {f_error} -> {new_f}")
            print(f"M error: {m_error} -> {new_m}")
        if abs(f_error - new_f) < 1e-15 or abs(m_error - new_m) < 1e-15:
            rho = 0.5
        else:
            rho = (f_error - new_f) / (m_error - new_m)
        if verbose:
            print(f"rho = {rho}")
        if rho >= 0.75:
            new_delta = max(delta, 3.0 * norm)
            stay = mode == SEARCH_EACH_ITERATION and abs(new_delta - delta) >= 1e-15 and last != "decreased"
            delta = new_delta
            if not stay:
                return a, b, new_f, delta
            last = "increased"
        elif rho >= 0.25:
            return a, b, new_f, delta
        elif rho >= 0.0:
            at_minimum = delta <= MIN_DELTA
            if not at_minimum:
                delta *= 0.5
            if mode == ONE_STEP_PER_ITERATION or last == "increased" or at_minimum:
                return a, b, new_f, delta
            last = "decreased"
        else:
            # f increased (or is NaN): shrink the region and try again, down to MIN_DELTA.
            if delta > MIN_DELTA:
                delta *= 0.5
                last = "decreased"
                continue
            if verbose:
                print("Warning:  Dog leg stopping because cannot decrease error with minimum delta")
            return 0.0, 0.0, f_error, delta


def line_search(norms: tuple[float, float, float], evaluate: Callable, f_error: float, min_delta: float,
                max_delta: float, step_size: float, sufficient_decrease: float) -> tuple:
    """The outward line search along the dogleg path of riSAM (McGann, Rogers and Kaess,
    "Robust Incremental Smoothing and Mapping", ICRA 2023; its ``DoglegLineSearch``), whose
    parameters GTSAM's ``ISAM2DoglegLineSearchParams`` carries: from the radius
    min(``min_delta``, ‖dx_n‖), the radius grows by ``step_size`` up to min(``max_delta``,
    ‖dx_n‖); a point is taken when its f is below f(x) − ``sufficient_decrease``·radius, and the
    search stops at the first such point that is worse than the one taken.  ``norms`` and
    ``evaluate`` as :func:`iterate` takes them.  Returns (a, b, f_error, radius) of the point
    taken (the first one when none decreases f enough)."""
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
