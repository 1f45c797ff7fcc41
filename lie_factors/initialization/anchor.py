"""The anchor and the priors as GTSAM's initializers treat them (``InitializePose.h``).

Every prior becomes a between factor from a fictitious pose at the identity,
with key ``initialize::kAnchorKey`` = 99999999, which alone gets a prior.  A
graph without any prior would leave the orientation system singular: it gets
one at the identity on its smallest key (:meth:`PoseGraph.anchored`), and
every pose must be joined to a prior by edges.
"""

from __future__ import annotations

import numpy as np

from ..errors import InitializationError
from ..posegraph.graph import PoseGraph
from ..posegraph.gauge import free_gauge

#: ``initialize::kAnchorKey`` in GTSAM's InitializePose.h (not exposed to Python).
ANCHOR_KEY = 99999999


def require(pg: PoseGraph, groups: tuple[str, ...], who: str) -> None:
    """Raise the one-line reason unless ``pg``'s group is one of ``groups`` (``who`` takes those)."""
    if pg.group not in groups:
        raise InitializationError(f"{who} is for {'/'.join(groups)} graphs; this one is {pg.group}")


def prepared(pg: PoseGraph) -> PoseGraph:
    """``pg`` checked (:meth:`PoseGraph.validate`) and anchored, every pose joined to a prior.

    Raises ``ValueError`` for malformed arrays and
    :class:`~lie_factors.errors.InitializationError` for a pose with no path to a prior.
    """
    pg = pg.validate().anchored()
    P = len(pg.keys)
    ij = pg.index(pg.edge_keys.reshape(-1)).reshape(-1, 2)
    # the edges are relative and the priors anchor: a pose with no path to a prior is in a
    # component whose gauge is free (decided on the structure, before any factorization)
    lost = free_gauge(P, ij[:, 0], ij[:, 1], pg.index(pg.prior_keys))
    if lost.any():
        raise InitializationError(f"graph is not connected: pose {int(pg.keys[np.argmax(lost)])} has no path "
                                  f"to a prior ({int(lost.sum())} of {P} poses unreachable)")
    return pg


def anchored_edges(pg: PoseGraph):
    """(n, i, j, Z, information): the edges by pose index, then each prior as an edge from the
    anchor (index n = number of poses), in GTSAM's order (the order LAGO's spanning tree
    depends on).  Z (E + Q, m, m), information (E + Q, d, d)."""
    n = len(pg.keys)
    ij = pg.index(pg.edge_keys.reshape(-1)).reshape(-1, 2)
    Q = len(pg.prior_keys)
    i = np.concatenate([ij[:, 0], np.full(Q, n, dtype=np.int64)])
    j = np.concatenate([ij[:, 1], pg.index(pg.prior_keys)])
    return (n, i, j, np.concatenate([pg.measured, pg.prior_measured]),
            np.concatenate([pg.information, pg.prior_information]))
