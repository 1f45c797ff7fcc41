"""GTSAM's own initializers on the GTSAM graph built from a pose graph: no numba.

``gtsam.InitializePose3.initialize`` (a Pose2 graph as its planar Pose3 graph,
:mod:`lie_factors.initialization.planar`) and ``gtsam.lago.initialize``, run on
:meth:`PoseGraph.factor_graph` of GTSAM's own factor classes (its initializers
recognise no other).  The ``--backend native`` path uses these, and every path
where cvxopt's CHOLMOD is missing; ours (:mod:`~lie_factors.initialization.chordal`,
:mod:`~lie_factors.initialization.lago`) give the same poses to ~1e-10.

GTSAM's elimination recurses once per level: it runs on a large-stack thread
(:mod:`lie_factors.util.stack`).  A graph that uses GTSAM's anchor key 99999999 is
renumbered for the call and mapped back.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ..util import stack
from ..errors import InitializationError
from ..interop import matrices_from_values
from ..posegraph.graph import PoseGraph
from . import anchor, planar
from .lago import check_diagonal, odometric_path_complete


def _run(pg: PoseGraph, call, what: str) -> np.ndarray:
    """``call(GTSAM graph of pg)`` → the poses (P, m, m) in key order."""
    keys = pg.keys
    if anchor.ANCHOR_KEY in set(keys.tolist()):
        pg = pg.renumbered()
    try:
        values = stack.call(call, pg.factor_graph())
    except (RuntimeError, ValueError, IndexError) as exc:  # e.g. IndeterminantLinearSystemException
        text = str(exc).strip().splitlines()
        raise InitializationError(f"GTSAM failed: {text[0] if text else type(exc).__name__}") from None
    try:
        return matrices_from_values(values, pg.group, pg.keys)
    except KeyError as exc:
        raise InitializationError(f"{what} has no value for pose {keys[pg.index([exc.args[0]])[0]]}") from None
    except TypeError as exc:
        raise InitializationError(f"{what}: pose {keys[pg.index([exc.args[0]])[0]]} is not a {pg.group}") from None


def chordal(pg: PoseGraph) -> np.ndarray:
    """``gtsam.InitializePose3.initialize``: poses (P, m, m) of a Pose3 or (planar) Pose2 graph."""
    anchor.require(pg, ("Pose2", "Pose3"), "GTSAM's chordal initializer")
    pg = anchor.prepared(pg)
    if pg.group == "Pose3":
        return _run(pg, gtsam.InitializePose3.initialize, "chordal initializer")
    return planar.pose2_of(_run(planar.planar_pose3(pg), gtsam.InitializePose3.initialize, "chordal initializer"))


def lago(pg: PoseGraph) -> np.ndarray:
    """``gtsam.lago.initialize``: poses (P, 3, 3) of a Pose2 graph, on the odometric path where it
    reaches every pose (:func:`~lie_factors.initialization.lago.odometric_path_complete`)."""
    anchor.require(pg, ("Pose2",), "LAGO")
    pg = anchor.prepared(pg)
    check_diagonal(pg)
    path = odometric_path_complete(pg.keys, pg.edge_keys)
    return _run(pg, lambda graph: gtsam.lago.initialize(graph, path), "LAGO")
