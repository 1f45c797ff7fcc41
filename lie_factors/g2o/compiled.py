"""The compiled side of reading a large g2o file: what numpy would do in many passes over
the rows, in one pass.  Imported only where numba is loaded already (the scan's rule,
:func:`lie_factors.g2o.parse.parse`), so the check of a small file stays free of numba."""

from __future__ import annotations

import numpy as np

from ..kernels.jit import inline_kernel, kernel
from .rotations import quaternion_rotation

_rotation = inline_kernel(quaternion_rotation)


@kernel
def _fill_quaternion_poses(v, X):
    for k in range(len(v)):
        R = _rotation(v[k, 3], v[k, 4], v[k, 5], v[k, 6])
        for r in range(3):
            for c in range(3):
                X[k, r, c] = R[3 * r + c]
            X[k, r, 3] = v[k, r]
            X[k, 3, r] = 0.0
        X[k, 3, 3] = 1.0


def quaternion_poses(v: np.ndarray) -> np.ndarray:
    """The Pose3 matrices of rows ``v`` = (x, y, z, qx, qy, qz, qw, ...), shape (N, ≥7) → (N, 4, 4).

    The rotation is :func:`~lie_factors.g2o.rotations.quaternion_rotation`'s, bit for bit.
    """
    X = np.empty((len(v), 4, 4))
    _fill_quaternion_poses(v, X)
    return X
