"""False loop closures: which factors are loop closures, planting random wrong ones, scoring a classification.

A *loop closure* is an edge between poses whose ids are not consecutive
(:func:`lie_factors.posegraph.graph.is_loop_closure`); the consecutive ones are
odometry.  The robust CLI options and GNC's known inliers use this split; the
outlier benchmark and the tests plant false loop closures with
:func:`plant_false_loop_closures`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import gtsam

from ..posegraph.graph import is_loop_closure

__all__ = ["loop_closure_mask", "plant_false_loop_closures", "plant_clustered_false_loop_closures",
           "Classification", "classify"]


def loop_closure_mask(graph: gtsam.NonlinearFactorGraph) -> np.ndarray:
    """(size,) bool: True for the two-key factors that are loop closures (unary factors: False)."""
    mask = np.zeros(graph.size(), dtype=bool)
    for k in range(graph.size()):
        keys = graph.at(k).keys()
        mask[k] = len(keys) == 2 and bool(is_loop_closure(keys[0], keys[1]))
    return mask


def _random_pose(rng, is3d: bool, translation_scale: float):
    if is3d:
        w = rng.normal(size=3)
        w *= rng.uniform(0, np.pi) / np.linalg.norm(w)
        return gtsam.Pose3(gtsam.Rot3.Expmap(w), rng.uniform(-translation_scale, translation_scale, 3))
    t = rng.uniform(-translation_scale, translation_scale, 2)
    return gtsam.Pose2(t[0], t[1], rng.uniform(-np.pi, np.pi))


def _copy(between: gtsam.NonlinearFactorGraph):
    """(a copy of ``between``, its edges as sorted key pairs, the noise models a planted closure
    draws from: the loop closures', or every edge's if there is none)."""
    graph = gtsam.NonlinearFactorGraph()
    existing, lc, every = set(), [], []
    for k in range(between.size()):
        f = between.at(k)
        graph.add(f)
        i, j = f.keys()
        existing.add((min(i, j), max(i, j)))
        every.append(f.noiseModel())
        if is_loop_closure(i, j):
            lc.append(f.noiseModel())
    return graph, existing, lc or every


def plant_false_loop_closures(between: gtsam.NonlinearFactorGraph, keys: list[int], count: int,
                              seed: int, is3d: bool, translation_scale: float = 10.0):
    """A copy of ``between`` with ``count`` random false loop closures appended.

    Each false edge joins two random poses at least 2 ids apart with a uniformly
    random measurement (rotation angle up to π, translation up to
    ``translation_scale`` per axis) and the noise model of a randomly chosen
    existing loop closure (of an edge, if there is none), so that it looks like
    a real one.  Returns ``(graph, outlier_slots)`` with the new edges' indices.
    """
    rng = np.random.default_rng(seed)
    graph, existing, pool = _copy(between)
    Between = gtsam.BetweenFactorPose3 if is3d else gtsam.BetweenFactorPose2
    keys = list(keys)
    if len(keys) < 3 and count:
        raise ValueError("need at least 3 poses to plant a false loop closure")
    slots = []
    while len(slots) < count:
        a, b = rng.choice(len(keys), size=2, replace=False)
        i, j = keys[a], keys[b]
        pair = (min(i, j), max(i, j))
        if not is_loop_closure(i, j) or pair in existing:
            continue
        existing.add(pair)
        noise = pool[rng.integers(len(pool))]
        graph.add(Between(i, j, _random_pose(rng, is3d, translation_scale), noise))
        slots.append(graph.size() - 1)
    return graph, np.array(slots, dtype=np.int64)


def _odometry_chain(between: gtsam.NonlinearFactorGraph, keys: list[int]) -> dict:
    """key → measured pose of the odometry edge from ``key`` to the next key (either direction)."""
    odo = {}
    for k in range(between.size()):
        f = between.at(k)
        i, j = f.keys()
        if j == i + 1:
            odo.setdefault(i, f.measured())
        elif i == j + 1:
            odo.setdefault(j, f.measured().inverse())
    return odo


def plant_clustered_false_loop_closures(between: gtsam.NonlinearFactorGraph, keys: list[int], count: int,
                                        seed: int, is3d: bool, size: tuple[int, int] = (3, 10),
                                        translation_scale: float = 10.0):
    """A copy of ``between`` with ``count`` false loop closures appended in clusters that agree
    with one another, as perceptual aliasing makes them.

    Each cluster takes two random stretches of the odometry chain, i, i+1, …, i+s−1 and j, …,
    j+s−1 (s uniform in ``size``, the stretches at least s ids apart), and one wrong relative
    pose M drawn as in :func:`plant_false_loop_closures`; its closures are
    i+k → j+k with measurement O_{i,i+k}⁻¹ · M · O_{j,j+k}, O the odometry measurements
    composed.  Two closures of a cluster and the odometry between their ends close a cycle
    exactly: pairwise they are consistent, and only the odometry between the stretches (or
    the true closures) can tell them false.  Noise models as in
    :func:`plant_false_loop_closures`.  Returns ``(graph, outlier_slots)``.
    """
    rng = np.random.default_rng(seed)
    graph, existing, pool = _copy(between)
    odo = _odometry_chain(between, keys)
    Between = gtsam.BetweenFactorPose3 if is3d else gtsam.BetweenFactorPose2
    Identity = gtsam.Pose3 if is3d else gtsam.Pose2
    keyset = set(keys)
    slots = []
    attempts = 0
    while len(slots) < count:
        attempts += 1
        if attempts > 100 * (count + 10):
            raise ValueError("could not place the clusters: too few odometry stretches")
        s = int(rng.integers(size[0], size[1] + 1))
        s = min(s, count - len(slots))
        i, j = (int(x) for x in rng.choice(keys, size=2, replace=False))
        if abs(i - j) < 2 * s:
            continue
        if not all(k in odo for k in range(i, i + s - 1)) or not all(k in odo for k in range(j, j + s - 1)):
            continue
        if not all((i + k) in keyset and (j + k) in keyset for k in range(s)):
            continue
        pairs = [(min(i + k, j + k), max(i + k, j + k)) for k in range(s)]
        if any(p in existing for p in pairs):
            continue
        M = _random_pose(rng, is3d, translation_scale)
        noise = pool[rng.integers(len(pool))]
        Oi, Oj = Identity(), Identity()
        for k in range(s):
            if k:
                Oi = Oi.compose(odo[i + k - 1])
                Oj = Oj.compose(odo[j + k - 1])
            existing.add(pairs[k])
            graph.add(Between(i + k, j + k, Oi.inverse().compose(M).compose(Oj), noise))
            slots.append(graph.size() - 1)
    return graph, np.array(slots, dtype=np.int64)


@dataclass
class Classification:
    """Precision/recall of rejected edges against the planted ones."""

    true_positives: int
    false_positives: int
    false_negatives: int

    @property
    def precision(self) -> float:
        n = self.true_positives + self.false_positives
        return self.true_positives / n if n else 1.0

    @property
    def recall(self) -> float:
        n = self.true_positives + self.false_negatives
        return self.true_positives / n if n else 1.0


def classify(rejected, planted) -> Classification:
    r = {int(i) for i in rejected}
    p = {int(i) for i in planted}
    return Classification(len(r & p), len(r - p), len(p - r))
