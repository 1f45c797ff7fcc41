"""The SE(3) odometry-chain example: simulate, optimize, measure ATE.

A robot drives ``laps`` laps of a circle (radius growing a little per lap)
while its height follows a wave, so every lap revisits the places of the
previous one; those revisits become loop closures.  Odometry and closures are
the true relative poses perturbed on the right, Z = T_rel · Exp(ξ) with
ξ ~ N(0, diag(σ²)) in GTSAM's Pose3 tangent order [ω, v] — the same model the
noise model assumes, so the optimum is statistically meaningful.

The first pose gets a tight prior at its true value and the initial guess
starts there, so the gauge is fixed and ATE needs no alignment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import gtsam

#: Odometry / loop-closure noise, Pose3 tangent order [ω (rad), v (m)].
SIGMAS = np.array([0.01, 0.01, 0.01, 0.05, 0.05, 0.05])
#: The first pose is known (to 1 mm / 1 mrad): it fixes the gauge.
PRIOR_SIGMAS = np.full(6, 1e-3)
LAPS = 3
RADIUS = 10.0


def ground_truth(n: int) -> list[gtsam.Pose3]:
    """``n`` true poses (n ≥ 2): ``LAPS`` laps of a wavy circle, heading along the path.

    Pose i sits at angle θ_i = 2π i / per_lap, so poses i and i + per_lap are
    at the same angle one lap apart (0.5 m further out, same height): revisits.
    Shapes: returns a list of ``n`` gtsam.Pose3.
    """
    per_lap = max(4, int(np.ceil(n / LAPS)))
    poses = []
    for i in range(n):
        th = 2 * np.pi * i / per_lap
        r = RADIUS + 0.5 * i / per_lap  # a spiral: laps 0.5 m apart, no seam
        z = 1.5 * np.sin(2 * th)
        dz = 3.0 * np.cos(2 * th)  # dz/dθ
        yaw = th + np.pi / 2  # tangent of the circle
        pitch = -np.arctan2(dz, r)  # climb along the wave (Ypr: positive pitch points down)
        roll = 0.1 * np.sin(th)  # lean a little, so all three rotation axes are exercised
        R = gtsam.Rot3.Ypr(yaw, pitch, roll)
        poses.append(gtsam.Pose3(R, np.array([r * np.cos(th), r * np.sin(th), z])))
    return poses


def loop_closure_pairs(n: int, stride: int = 3) -> list[tuple[int, int]]:
    """(i − per_lap, i) for every ``stride``-th pose from the second lap on."""
    per_lap = max(4, int(np.ceil(n / LAPS)))
    return [(i - per_lap, i) for i in range(per_lap, n, stride)]


def noisy(T: gtsam.Pose3, rng: np.random.Generator) -> gtsam.Pose3:
    """T · Exp(ξ), ξ ~ N(0, diag(SIGMAS²)), shape (6,) in [ω, v]."""
    return T.compose(gtsam.Pose3.Expmap(rng.normal(0.0, SIGMAS)))


@dataclass
class Problem:
    """Everything a demo optimizes (this one's poses are Pose3, the Sim(3) demo's Similarity3).

    ``truth``: n true poses; ``odometry``: n−1 measured Z_{i,i+1};
    ``closures``: list of (i, j, measured Z_ij); ``initial``: Values by composing odometry.
    """

    truth: list
    odometry: list
    closures: list
    initial: gtsam.Values


def dead_reckoning(start, odometry: list) -> gtsam.Values:
    """Pose 0 at ``start``, pose i + 1 = pose i · ``odometry[i]``: the drift the closures must remove."""
    initial = gtsam.Values()
    pose = start
    initial.insert(0, pose)
    for i, Z in enumerate(odometry):
        pose = pose.compose(Z)
        initial.insert(i + 1, pose)
    return initial


def simulate(n: int = 300, seed: int = 0) -> Problem:
    """A seeded problem with ``n`` poses (same seed → same problem)."""
    if n < 2:
        raise ValueError(f"need at least 2 poses, got {n}")
    rng = np.random.default_rng(seed)
    truth = ground_truth(n)
    odometry = [noisy(truth[i].between(truth[i + 1]), rng) for i in range(n - 1)]
    closures = [(i, j, noisy(truth[i].between(truth[j]), rng)) for i, j in loop_closure_pairs(n)]
    return Problem(truth, odometry, closures, dead_reckoning(truth[0], odometry))


def chain_graph(problem: Problem, factors, group: str, prior_noise, odometry_noise,
                closure_noise) -> gtsam.NonlinearFactorGraph:
    """Prior on pose 0 (at its true value) + odometry + closures on ``group`` (GTSAM's type name),
    built with ``factors``' constructors (``lie_factors.factors`` or ``gtsam``: both name them
    like GTSAM)."""
    graph = gtsam.NonlinearFactorGraph()
    graph.add(getattr(factors, f"PriorFactor{group}")(0, problem.truth[0], prior_noise))
    Between = getattr(factors, f"BetweenFactor{group}")
    for i, Z in enumerate(problem.odometry):
        graph.add(Between(i, i + 1, Z, odometry_noise))
    for i, j, Z in problem.closures:
        graph.add(Between(i, j, Z, closure_noise))
    return graph


def build_graph(problem: Problem, factors) -> gtsam.NonlinearFactorGraph:
    """The demo's graph (:func:`chain_graph`), every edge with the noise model of :data:`SIGMAS`."""
    noise = gtsam.noiseModel.Diagonal.Sigmas(SIGMAS)
    return chain_graph(problem, factors, "Pose3", gtsam.noiseModel.Diagonal.Sigmas(PRIOR_SIGMAS), noise, noise)


def without_prior(full: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
    """``full`` less its factor 0 (the prior :func:`build_graph` puts first)."""
    graph = gtsam.NonlinearFactorGraph()
    for k in range(1, full.size()):
        graph.add(full.at(k))
    return graph


def between_graph(problem: Problem) -> gtsam.NonlinearFactorGraph:
    """The measurements as native GTSAM factors (no prior), for ``gtsam.writeG2o``."""
    return without_prior(build_graph(problem, gtsam))


def ate_rmse(values: gtsam.Values, truth: list[gtsam.Pose3]) -> float:
    """Absolute trajectory error: sqrt(mean_i ‖t_i − t_i^true‖²), metres.

    No alignment: the prior already puts both trajectories in the same frame.
    """
    est = np.array([values.atPose3(i).translation() for i in range(len(truth))])
    ref = np.array([T.translation() for T in truth])
    return float(np.sqrt(np.mean(np.sum((est - ref) ** 2, axis=1))))
