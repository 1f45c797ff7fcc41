"""A pose graph as arrays: the one representation the reader, the initializers and the solvers share."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class PoseGraph:
    """A pose graph as arrays, in GTSAM's conventions (what ``readG2o`` would build from a file).

    ``group``: Pose2, Pose3 or Similarity3 (m×m matrices, n-dimensional
    tangent: 3×3/3, 4×4/6, 4×4/7).  ``keys`` (P,) int64: every pose id,
    sorted.  ``edge_keys`` (E, 2) int64, ``measured`` (E, m, m) and
    ``information`` (E, n, n): the pose–pose edges in file order (edge k of
    the file is factor k of GTSAM's graph), information in GTSAM's tangent
    order.  ``vertices`` (P, m, m): the file's pose vertices in key order, or
    None if the file has no pose vertex.  ``lines`` (E,): the edges' line numbers.
    """

    group: str
    keys: np.ndarray
    edge_keys: np.ndarray
    measured: np.ndarray
    information: np.ndarray
    vertices: np.ndarray | None
    lines: np.ndarray

    @property
    def is3d(self) -> bool:
        return self.group != "Pose2"
