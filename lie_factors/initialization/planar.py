"""A Pose2 graph as the planar Pose3 graph the chordal initializer takes, and back.

GTSAM has no chordal initializer for Pose2.  For planar measurements and a
decoupled out-of-plane information the chordal relaxation keeps every rotation
about z and the Gauss–Newton step keeps z = 0, so (x, y, yaw) of the Pose3
result is the chordal initialization of the Pose2 graph.  Ours and GTSAM's
(``InitializePose3``) both run on :func:`planar_pose3`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..interop import pose2_matrices
from ..posegraph.graph import PoseGraph


def pose2_information_to_pose3(info2: np.ndarray) -> np.ndarray:
    """(..., 3, 3) information on Pose2's [x, y, θ] → (..., 6, 6) on Pose3's [ω, v] for planar edges.

    The in-plane block as given ([x, y, θ] → [v_x, v_y, ω_z]); the out-of-plane
    components (ω_x, ω_y, v_z) decoupled, with θ's and x's information.  The
    chordal relaxation weighs each edge by its ω_x information, so ω_x gets θ's:
    the weights are then the edge's rotation precision, as for a 3-D graph.
    """
    info2 = np.asarray(info2, dtype=np.float64)
    idx = [3, 4, 2]  # x, y, θ → v_x, v_y, ω_z
    info3 = np.zeros(info2.shape[:-2] + (6, 6))
    info3[..., np.array(idx)[:, None], np.array(idx)[None, :]] = info2
    info3[..., 0, 0] = info3[..., 1, 1] = info2[..., 2, 2]
    info3[..., 5, 5] = info2[..., 0, 0]
    return info3


def _pose3_of(X: np.ndarray) -> np.ndarray:
    """Pose2 matrices (K, 3, 3) → the same rigid motions of the plane as Pose3 matrices (K, 4, 4)."""
    T = np.zeros((len(X), 4, 4))
    T[:, :2, :2] = X[:, :2, :2]
    T[:, :2, 3] = X[:, :2, 2]
    T[:, 2, 2] = T[:, 3, 3] = 1.0
    return T


def planar_pose3(pg: PoseGraph) -> PoseGraph:
    """The Pose2 graph ``pg`` as a Pose3 graph in the plane z = 0 (same keys, edges and priors)."""
    return dataclasses.replace(
        pg, group="Pose3", measured=_pose3_of(pg.measured), information=pose2_information_to_pose3(pg.information),
        vertices=None if pg.vertices is None else _pose3_of(pg.vertices),
        prior_measured=_pose3_of(pg.prior_measured),
        prior_information=pose2_information_to_pose3(pg.prior_information))


def pose2_of(T: np.ndarray) -> np.ndarray:
    """Pose3 matrices (K, 4, 4) → Pose2 matrices (K, 3, 3) of (x, y, yaw)."""
    return pose2_matrices(np.stack([T[:, 0, 3], T[:, 1, 3], np.arctan2(T[:, 1, 0], T[:, 0, 0])], axis=1))
