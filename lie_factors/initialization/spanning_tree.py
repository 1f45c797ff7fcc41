"""Poses from the measurements composed along a breadth-first spanning tree
(:meth:`lie_factors.posegraph.graph.PoseGraph.tree_poses`).

A breadth-first tree (rather than plain odometry order) reaches every pose of a
connected graph even when ids are not a chain, and takes each pose through
the fewest measurements, so drift stays smallest.  Numpy only.
"""

from __future__ import annotations

import numpy as np

from ..errors import InitializationError
from ..posegraph.graph import PoseGraph
from . import anchor


def initialize(pg: PoseGraph) -> np.ndarray:
    """The ``spanning-tree`` initialization: poses (P, m, m) composed from the first prior
    (its key and element; the identity on the smallest key without a prior)."""
    pg = anchor.prepared(pg)
    root_key = int(pg.prior_keys[0])
    poses, on_tree = pg.tree_poses(root_key, pg.prior_measured[0])
    if not on_tree.all():
        lost = int(pg.keys[np.argmin(on_tree)])
        raise InitializationError(f"graph is not connected: pose {lost} cannot be reached from pose {root_key}")
    return poses
