"""The monocular scale-drift example: a Sim(3) pose graph, ours against GTSAM's factors.

A camera flies ``LAPS`` laps of a wavy loop.  Monocular visual odometry cannot
observe metric scale, so each relative motion it reports carries a small
*scale* change and, like every odometry, a small rotation bias: measurement
``Z_i = (X_i⁻¹ X_{i+1}) · Exp(DRIFT + ξ_i)``, ξ_i ~ N(0, diag(SIGMAS²)), in
GTSAM's Similarity3 tangent order [ω (3), u (3), λ], where ``DRIFT`` is a
constant bias the noise model does not know about.  Composing that odometry
(the initial guess) shrinks or inflates the trajectory exponentially (the scale
of pose i is e^{i·DRIFT[6]}) and bends it.  Where the camera passes a place it
saw one lap earlier, loop closures measure the true relative similarity
(relative scale ≈ 1) with noise CLOSURE_SIGMAS; the closures disagree with the
accumulated odometry, so at the optimum the residuals are the spread drift, not
just noise — the regime in which GTSAM's ``BetweenFactorSimilarity3``
Jacobians (no Logmap derivative) are visibly wrong.

The true poses are Similarity3 elements with scale 1, X_i = [[R_i, p_i], [0, 1]];
the camera centre of any Similarity3 X (action p ↦ s(Rp + t)) is X(0) = s·t,
which is what the ATE compares.  The first pose gets a tight prior at its true
value and the initial guess starts there, so the gauge (7 dof) is fixed and
the ATE needs no alignment.

The same graph is optimized with lie_factors' factors and with GTSAM's native
ones (same Levenberg–Marquardt parameters, same start); each result's *true*
gradient ‖Σ_k H_kᵀ Σ_k⁻¹ e_k‖ is computed with the exact Jacobians of
:mod:`lie_factors.factors` (GTSAM's errors are exact, only its Jacobians are
not, so this is the gradient of the cost both optimizers minimize).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from .demo import Problem, chain_graph, dead_reckoning, without_prior

#: Odometry noise model, Similarity3 tangent order [ω (rad), u (m), λ].
SIGMAS = np.array([0.003, 0.003, 0.003, 0.03, 0.03, 0.03, 0.01])
#: Loop-closure noise model (same order).
CLOSURE_SIGMAS = np.array([0.003, 0.003, 0.003, 0.05, 0.05, 0.05, 0.01])
#: Unmodelled odometry bias per step: rotation drift (rad) and scale drift (λ; e^0.01 = 1 %).
DRIFT = np.array([0.003, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01])
#: The first pose is known: it fixes the gauge (rotation, translation and scale).
PRIOR_SIGMAS = np.full(7, 1e-4)
LAPS = 2
RADIUS = 20.0
#: Loop closures per lap (at evenly spaced revisits).
CLOSURES_PER_LAP = 6


def _per_lap(n: int) -> int:
    return max(4, int(np.ceil(n / LAPS)))


def ground_truth(n: int) -> list[gtsam.Similarity3]:
    """``n`` true poses (scale 1): ``LAPS`` laps of a loop that rises and falls three times
    per lap, the camera heading along the path.  Pose i and i + per_lap are one lap apart
    (1 m further out, same height): revisits.  Returns a list of ``n`` gtsam.Similarity3."""
    per_lap = _per_lap(n)
    poses = []
    for i in range(n):
        th = 2 * np.pi * i / per_lap
        r = RADIUS + 1.0 * i / per_lap
        z = 2.0 * np.sin(3 * th)
        dz = 6.0 * np.cos(3 * th)  # dz/dθ
        R = gtsam.Rot3.Ypr(th + np.pi / 2, -np.arctan2(dz, r), 0.05 * np.sin(th))
        poses.append(gtsam.Similarity3(R, np.array([r * np.cos(th), r * np.sin(th), z]), 1.0))
    return poses


def loop_closure_pairs(n: int) -> list[tuple[int, int]]:
    """(i − per_lap, i) at ``CLOSURES_PER_LAP`` evenly spaced poses of every lap after the first."""
    per_lap = _per_lap(n)
    stride = max(1, per_lap // CLOSURES_PER_LAP)
    return [(i - per_lap, i) for i in range(per_lap, n, stride)]


def simulate(n: int = 150, seed: int = 0) -> Problem:
    """A seeded problem with ``n`` poses (same seed → same problem)."""
    if n < 2:
        raise ValueError(f"need at least 2 poses, got {n}")
    rng = np.random.default_rng(seed)
    truth = ground_truth(n)
    S = gtsam.Similarity3
    odometry = [truth[i].between(truth[i + 1]).compose(S.Expmap(DRIFT + rng.normal(0.0, SIGMAS)))
                for i in range(n - 1)]
    closures = [(i, j, truth[i].between(truth[j]).compose(S.Expmap(rng.normal(0.0, CLOSURE_SIGMAS))))
                for i, j in loop_closure_pairs(n)]
    # Dead reckoning: scale and rotation drift accumulate.
    return Problem(truth, odometry, closures, dead_reckoning(truth[0], odometry))


def build_graph(problem: Problem, factors) -> gtsam.NonlinearFactorGraph:
    """The demo's graph (:func:`lie_factors.app.demo.chain_graph`) on Similarity3: odometry with
    :data:`SIGMAS`, closures with :data:`CLOSURE_SIGMAS`."""
    Sigmas = gtsam.noiseModel.Diagonal.Sigmas
    return chain_graph(problem, factors, "Similarity3", Sigmas(PRIOR_SIGMAS), Sigmas(SIGMAS),
                       Sigmas(CLOSURE_SIGMAS))


def between_graph(problem: Problem) -> gtsam.NonlinearFactorGraph:
    """The measurements as native GTSAM factors (no prior), for writing a g2o file."""
    return without_prior(build_graph(problem, gtsam))


def camera_centres(values: gtsam.Values, n: int) -> np.ndarray:
    """X_i(0) = s_i·t_i for keys 0 … n−1, shape (n, 3)."""
    origin = np.zeros(3)
    return np.array([values.atSimilarity3(i).transformFrom(origin) for i in range(n)]).reshape(n, 3)


def true_centres(truth: list[gtsam.Similarity3]) -> np.ndarray:
    """Camera centres of the true poses, shape (n, 3)."""
    origin = np.zeros(3)
    return np.array([T.transformFrom(origin) for T in truth]).reshape(len(truth), 3)


def ate_rmse(values: gtsam.Values, truth: list[gtsam.Similarity3]) -> float:
    """sqrt(mean_i ‖c_i − c_i^true‖²) of the camera centres, no alignment (the prior fixes the frame)."""
    diff = camera_centres(values, len(truth)) - true_centres(truth)
    return float(np.sqrt(np.mean(np.sum(diff ** 2, axis=1))))


def true_gradient_norm(exact_graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> float:
    """‖∇(½ Σ‖R_k e_k‖²)‖ at ``values`` w.r.t. the right retraction X·Exp(δ).

    ``exact_graph`` must be built with exact Jacobians (:mod:`lie_factors.factors`):
    GTSAM's ``gradientAtZero`` of the linearization is Σ H_kᵀ R_kᵀ R_k e_k.
    """
    g = exact_graph.linearize(values).gradientAtZero()
    return float(np.sqrt(g.dot(g)))


def lm_params(max_iterations: int = 100) -> gtsam.LevenbergMarquardtParams:
    """GTSAM's LM defaults, except tolerances tight enough that stopping is decided by
    the optimizer reaching its fixed point, not by a 1e-5 relative decrease."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-12)
    return params


@dataclass
class Comparison:
    """Ours and GTSAM's native factors on one problem: results, ATEs, true gradient norms.

    ``ours``/``native``: :class:`lie_factors.Result`; ``graph``: the
    graph ours optimized; gradients are ‖∇cost‖ at the start and at each result.
    """

    problem: Problem
    graph: gtsam.NonlinearFactorGraph
    ours: object
    native: object
    ate_initial: float
    ate_ours: float
    ate_native: float
    gradient_initial: float
    gradient_ours: float
    gradient_native: float

    @property
    def stationary(self) -> bool:
        """ours' true gradient ≤ 1e-6 of the initial one."""
        return self.gradient_ours <= 1e-6 * self.gradient_initial


def compare(problem: Problem, backend: str = "batch", max_iterations: int = 100, events=None) -> Comparison:
    """Optimize ``problem`` with our factors (``backend`` batch or dropin, :func:`lie_factors.optimize`)
    and with GTSAM's native ones in GTSAM's optimizer, same start and :func:`lm_params`; ``events``
    (:class:`lie_factors.Events`) hears our iterations."""
    import lie_factors as lf
    from .. import factors

    graph = build_graph(problem, factors)
    native_graph = build_graph(problem, gtsam)
    ours = lf.optimize(graph, problem.initial, lm_params(max_iterations), backend=backend, events=events)
    native = lf.optimize(native_graph, problem.initial, lm_params(max_iterations), backend="native")
    return Comparison(
        problem, graph, ours, native,
        ate_rmse(problem.initial, problem.truth), ate_rmse(ours.values, problem.truth),
        ate_rmse(native.values, problem.truth),
        true_gradient_norm(graph, problem.initial), true_gradient_norm(graph, ours.values),
        true_gradient_norm(graph, native.values),
    )

