"""Group elements as (N, m, m) matrices, to and from GTSAM's objects, in numpy (no numba).

The one place where element matrices meet ``gtsam.Values``: the batch
reader, the drop-in optimizers' evaluation plan, the initializers and the
command line all convert through these functions.  GTSAM's bulk
parameterisations (``gtsam.utilities.extractPose3`` / ``extractPose2``: one
C++ pass over a ``Values``) are turned into matrices vectorized, without a
Python call per pose.  Groups are named by GTSAM type (``"Pose3"``) or kernel
module (``"se3"``), as :func:`lie_factors.kernels.registry.group` reads them.
"""

from __future__ import annotations

import numpy as np

from .kernels.registry import group as _group

__all__ = ["pose2_matrices", "pose3_from_rows", "to_gtsam", "values_from_matrices", "matrices_from_values"]


def pose2_matrices(x: np.ndarray) -> np.ndarray:
    """[x, y, θ] rows (N, 3) → Pose2 matrices (N, 3, 3), as ``Pose2(x, y, θ).matrix()``
    (``gtsam.utilities.extractPose2`` gives these rows)."""
    c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
    X = np.zeros((len(x), 3, 3))
    X[:, 0, 0], X[:, 0, 1], X[:, 1, 0], X[:, 1, 1] = c, -s, s, c
    X[:, 0, 2], X[:, 1, 2], X[:, 2, 2] = x[:, 0], x[:, 1], 1.0
    return X


def pose3_from_rows(rows: np.ndarray, X: np.ndarray) -> None:
    """Write (N, 4, 4) Pose3 matrices into ``X`` from ``gtsam.utilities.extractPose3``'s
    (N, 12) rows (the rotation's 9 entries row-major, then the translation): the
    entries ``.matrix()`` gives."""
    X[:, :3, :3] = rows[:, :9].reshape(-1, 3, 3)
    X[:, :3, 3] = rows[:, 9:12]
    X[:, 3, :3] = 0.0
    X[:, 3, 3] = 1.0


def to_gtsam(group: str, M: np.ndarray):
    """The GTSAM object of the element matrix ``M`` (m, m) of ``group``.

    Pose2 and Similarity2 have no constructor from a matrix in GTSAM's Python
    wrapper: they are built from ``Rot2.atan2(R10, R00)``, which keeps cos and sin
    exactly as given (a unit pair is not renormalized), so the matrix of
    ``Pose2(x, y, θ)`` converts back to that pose bit for bit; going through the
    angle θ would not (atan2 then cos/sin is off by an ulp for about 2 % of
    angles).  Then the translation, and for Similarity2 the scale 1/M[2, 2].
    """
    import gtsam

    name = _group(group).gtsam
    if name == "Pose2":
        return gtsam.Pose2(gtsam.Rot2.atan2(M[1, 0], M[0, 0]), np.array([M[0, 2], M[1, 2]]))
    if name == "Similarity2":
        return gtsam.Similarity2(gtsam.Rot2.atan2(M[1, 0], M[0, 0]), np.array([M[0, 2], M[1, 2]]),
                                 1.0 / M[2, 2])
    return getattr(gtsam, name)(M)


def values_from_matrices(group: str, keys, X: np.ndarray):
    """A ``gtsam.Values`` holding the element ``X[i]`` (N, m, m) of ``group`` at ``keys[i]``."""
    import gtsam

    values = gtsam.Values()
    for k, M in zip(np.asarray(keys).tolist(), X):
        values.insert(int(k), to_gtsam(group, M))
    return values


def matrices_from_values(values, group: str, keys) -> np.ndarray:
    """(N, m, m) element matrices of ``keys`` in ``values`` (a ``gtsam.Values``), each a ``group``.

    Raises ``KeyError(key)`` for the first key that is missing and
    ``TypeError(key)`` for the first that holds another type; callers word
    the message.  Pose3 and Pose2 are read in one C++ pass.
    """
    import gtsam

    info = _group(group)
    keys = [int(k) for k in keys]
    X = np.empty((len(keys), info.mat, info.mat))
    for k in keys:
        if not values.exists(k):
            raise KeyError(k)
    if info.gtsam in ("Pose3", "Pose2"):
        # Bulk extraction in C++ (all values of that type, in key order).
        if info.gtsam == "Pose3":
            typed = gtsam.utilities.allPose3s(values)
            E = np.asarray(gtsam.utilities.extractPose3(values))
        else:
            typed = gtsam.utilities.allPose2s(values)
            E = np.asarray(gtsam.utilities.extractPose2(values))
        tkeys = np.asarray(typed.keys(), dtype=np.uint64)
        want = np.asarray(keys, dtype=np.uint64)
        pos = np.searchsorted(tkeys, want)
        pos = np.minimum(pos, max(len(tkeys) - 1, 0))
        bad = np.nonzero((len(tkeys) == 0) | (tkeys[pos] != want))[0] if len(want) else []
        if len(bad):
            raise TypeError(keys[bad[0]])
        E = E[pos]
        if info.gtsam == "Pose3":
            pose3_from_rows(E, X)
        else:
            X[:] = pose2_matrices(E)
        return X
    at = getattr(values, f"at{info.gtsam}")
    for j, k in enumerate(keys):
        try:
            X[j] = at(k).matrix()
        except RuntimeError:
            raise TypeError(k) from None
    return X
