"""The figures a sweep reports of one run against what was planted and the clean optimum; the
outlier benchmark (benchmarks/outliers.py) computes its tables with the same functions.

- precision and recall of the rejected closures against the planted ones
  (:func:`lie_factors.testing.outliers.classify`);
- the map's deviation from the clean optimum: the RMSE of the positions, in % of the
  diagonal of the clean optimum's bounding box (:func:`map_error_percent`);
- the planted closures that fit the clean optimum (:func:`consistent_planted`: riSAM's rule,
  such a closure is not an outlier) and precision and recall with them left out of the count.
"""

from __future__ import annotations

import numpy as np

__all__ = ["positions", "rmse", "diagonal", "map_error_percent", "consistent_planted", "stage_counts",
           "STAGES"]

#: The stages of the false-closure pipeline that reject a closure, in their order (``online``: the
#: online rejection of a replay, :mod:`lie_factors.robust.online`).
STAGES = ("gate", "clique", "gnc", "final", "online")


def positions(poses: np.ndarray) -> np.ndarray:
    """(n, 3) the positions of (n, m, m) group elements (z = 0 in 2-D): a pose's translation, a
    similarity [[R, t], [0, 1/s]]'s image of the origin s·t."""
    X = np.asarray(poses, dtype=np.float64)
    d = X.shape[1] - 1
    P = np.zeros((len(X), 3))
    P[:, :d] = X[:, :d, d] / X[:, d, d][:, None]
    return P


def rmse(P: np.ndarray, ref: np.ndarray) -> float:
    """The root mean square of the distances between the rows of ``P`` and ``ref`` (n, 3)."""
    return float(np.sqrt(np.mean(np.sum((np.asarray(P) - np.asarray(ref)) ** 2, axis=1))))


def diagonal(ref: np.ndarray) -> float:
    """The length of the diagonal of the bounding box of the positions ``ref`` (n, 3)."""
    ref = np.asarray(ref)
    return float(np.linalg.norm(ref.max(axis=0) - ref.min(axis=0)))


def map_error_percent(P: np.ndarray, ref: np.ndarray) -> float:
    """The map's deviation from the reference: :func:`rmse` of the positions (n, 3), unaligned (both
    estimates are fixed by the same prior on the first pose), in % of :func:`diagonal` of ``ref``."""
    return 100.0 * rmse(P, ref) / diagonal(ref)


def consistent_planted(between, planted, ref_values, dim: int) -> np.ndarray:
    """The planted closures that fit the clean optimum: χ² = 2·error ≤ χ²_dim(0.95) under their
    own noise model (riSAM's rule: such a closure is not an outlier, whatever it was planted as).

    ``between``: a ``gtsam.NonlinearFactorGraph`` holding them, ``planted`` their slots in it,
    ``ref_values`` the clean optimum (``gtsam.Values``), ``dim`` the poses' tangent dimension."""
    from ..robust.statistics import chi2_inlier_threshold

    limit = 2.0 * chi2_inlier_threshold(dim, 0.95)
    return np.array([k for k in np.asarray(planted).tolist() if 2.0 * between.at(int(k)).error(ref_values) <= limit],
                    dtype=np.int64)


def stage_counts(rejected_by: dict) -> str:
    """How many closures each stage rejected, in the stages' order ("gate 28, clique 107, gnc 21")."""
    counts: dict[str, int] = {}
    for v in rejected_by.values():
        counts[v] = counts.get(v, 0) + 1
    return ", ".join(f"{k} {counts[k]}" for k in STAGES if k in counts)
