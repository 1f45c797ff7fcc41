"""Poses from the measurements composed along a breadth-first spanning tree.

Edge i→j with measurement Z means X_j = X_i·Z, hence X_i = X_j·Z⁻¹.  A
breadth-first tree (rather than plain odometry order) reaches every pose of a
connected graph even when ids are not a chain, and takes each pose through
the fewest measurements, so drift stays smallest.  Numpy only (matrix
products); every initialization path and the loading of files without
vertices use it.
"""

from __future__ import annotations

import numpy as np

from ..errors import InitializationError
from ..pose_graph import PoseGraph
from ..topology import along_tree, bfs_tree
from . import anchor


def compose(pg: PoseGraph, root_key: int, root_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(poses (P, m, m), reached (P,)): ``root_pose`` on ``root_key``, every pose the edges reach
    from it composed along the tree (:func:`lie_factors.topology.bfs_tree`); the others are
    left as the identity."""
    P, m = len(pg.keys), pg.info.mat
    ij = pg.index(pg.edge_keys.reshape(-1)).reshape(-1, 2)
    root = int(pg.index([root_key])[0])
    parent, edge = bfs_tree(P, ij[:, 0], ij[:, 1], root)
    step = np.broadcast_to(np.eye(m), (P, m, m)).copy()
    child = np.flatnonzero(edge >= 0)
    e = edge[child]
    forward = ij[e, 0] == parent[child]
    step[child] = np.where(forward[:, None, None], pg.measured[e], np.linalg.inv(pg.measured[e]))
    rel, on_tree = along_tree(parent, step, root, np.matmul)
    poses = np.broadcast_to(np.eye(m), (P, m, m)).copy()
    poses[on_tree] = np.asarray(root_pose, dtype=np.float64) @ rel[on_tree]
    poses[root] = root_pose
    return poses, on_tree


def initialize(pg: PoseGraph) -> np.ndarray:
    """The ``spanning-tree`` initialization: poses (P, m, m) composed from the first prior
    (its key and element; the identity on the smallest key without a prior)."""
    pg = anchor.prepared(pg)
    root_key = int(pg.prior_keys[0])
    poses, on_tree = compose(pg, root_key, pg.prior_measured[0])
    if not on_tree.all():
        lost = int(pg.keys[np.argmin(on_tree)])
        raise InitializationError(f"graph is not connected: pose {lost} cannot be reached from pose {root_key}")
    return poses
