"""Group elements as matrices from GTSAM's bulk parameterisations, vectorized in numpy (no numba).

Shared by the readers that fill (N, m, m) element arrays without one Python
call per pose: :mod:`lie_factors.factors` (the drop-in optimizers'
evaluation plan), :mod:`lie_factors.batch.graph` (a GTSAM ``Values`` read
into arrays) and :mod:`lie_factors.initialize_arrays` (initializers' [x, y, θ]).
"""

from __future__ import annotations

import numpy as np


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
