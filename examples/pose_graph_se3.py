"""SE(3) pose-graph optimization with lie_factors' GTSAM factors.

A robot drives three laps of a wavy circle.  It measures its motion between
consecutive poses (odometry) and, whenever it passes a place it has seen one
lap earlier, the relative pose to it (loop closure).  Composing the noisy
odometry drifts; Levenberg-Marquardt on the pose graph pulls the trajectory
back.  We print the graph error and the ATE (RMSE of positions against the
ground truth) before and after, and save a plot.

    python examples/pose_graph_se3.py [output.png]

(with lie_factors installed, `pip install -e .`, or `PYTHONPATH=.` in a checkout)
"""

import sys

import gtsam
import matplotlib

matplotlib.use("Agg")  # no display needed
import matplotlib.pyplot as plt
import numpy as np

from lie_factors.factors import BetweenFactorPose3, PriorFactorPose3

N, PER_LAP = 240, 80
SIGMAS = np.array([0.01, 0.01, 0.01, 0.05, 0.05, 0.05])  # Pose3 tangent order: [ω (rad), v (m)]
rng = np.random.default_rng(42)

# Ground truth: angle θ, radius growing 0.5 m per lap, height a wave, heading along the path.
truth = []
for i in range(N):
    th = 2 * np.pi * i / PER_LAP
    r = 10 + 0.5 * i / PER_LAP
    R = gtsam.Rot3.Ypr(th + np.pi / 2, -np.arctan2(3 * np.cos(2 * th), r), 0.1 * np.sin(th))
    truth.append(gtsam.Pose3(R, np.array([r * np.cos(th), r * np.sin(th), 1.5 * np.sin(2 * th)])))


def measure(i, j):
    """Relative pose T_i⁻¹ T_j, perturbed on the right by Exp(ξ), ξ ~ N(0, diag(SIGMAS²))."""
    return truth[i].between(truth[j]).compose(gtsam.Pose3.Expmap(rng.normal(0, SIGMAS)))


noise = gtsam.noiseModel.Diagonal.Sigmas(SIGMAS)
graph = gtsam.NonlinearFactorGraph()
# The prior pins pose 0 at its true value: fixes the gauge, so no ATE alignment is needed.
graph.add(PriorFactorPose3(0, truth[0], gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
initial = gtsam.Values()
initial.insert(0, truth[0])
for i in range(N - 1):
    Z = measure(i, i + 1)
    graph.add(BetweenFactorPose3(i, i + 1, Z, noise))
    initial.insert(i + 1, initial.atPose3(i).compose(Z))  # dead reckoning = initial guess
for j in range(PER_LAP, N, 3):  # revisits: same angle, one lap earlier
    graph.add(BetweenFactorPose3(j - PER_LAP, j, measure(j - PER_LAP, j), noise))


def positions(values):
    return np.array([values.atPose3(i).translation() for i in range(N)])


def ate(values):
    return np.sqrt(np.mean(np.sum((positions(values) - positions_true) ** 2, axis=1)))


positions_true = np.array([T.translation() for T in truth])
optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams())
result = optimizer.optimize()

print(f"{N} poses, {graph.size()} factors, {optimizer.iterations()} LM iterations")
print(f"error: {graph.error(initial):12.3f} -> {graph.error(result):.3f}")
print(f"ATE:   {ate(initial):12.3f} m -> {ate(result):.3f} m")

fig = plt.figure(figsize=(11, 5))
top, ax3 = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2, projection="3d")
for label, P, style in [("ground truth", positions_true, "k--"), ("initial", positions(initial), "r-"),
                        ("optimized", positions(result), "b-")]:
    top.plot(P[:, 0], P[:, 1], style, lw=1, label=label)
    ax3.plot(P[:, 0], P[:, 1], P[:, 2], style, lw=1)
top.set_aspect("equal")
top.set_title("top view")
top.legend()
ax3.set_title("3-D")
out = sys.argv[1] if len(sys.argv) > 1 else "pose_graph_se3.png"
fig.savefig(out, dpi=100)
print(f"saved {out}")
