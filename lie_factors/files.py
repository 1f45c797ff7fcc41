"""Files in and out at the front door: :func:`read_g2o` and :func:`write_g2o`."""

from __future__ import annotations

from .errors import InputError
from .g2o import read_pose_graph
from .posegraph.graph import PoseGraph
from .result import Result

__all__ = ["read_g2o", "write_g2o"]


def read_g2o(path: str) -> PoseGraph:
    """The pose graph of a g2o file: a path, or the name of a file shipped with GTSAM
    (``sphere2500.txt``). Every line is checked first: a malformed one raises
    :class:`~lie_factors.errors.InputError` with ``file:line: what was expected``.

    2-D ``VERTEX_SE2``/``EDGE_SE2``, 3-D ``VERTEX_SE3:QUAT``/``EDGE_SE3:QUAT`` and ``EDGE3``,
    Sim(3) ``VERTEX_SIM3:EXPMAP``/``EDGE_SIM3:EXPMAP``; landmark records are kept as
    GTSAM's factors (``pose_graph.landmarks``).
    """
    return read_pose_graph(path)


def write_g2o(result_or_pose_graph: Result | PoseGraph, path: str) -> None:
    """Write a g2o file, atomically (a failure leaves any existing file as it was).

    Given a :class:`~lie_factors.result.Result` of a pose graph: the graph's edges and
    landmark measurements at the optimized values. Given a
    :class:`~lie_factors.posegraph.graph.PoseGraph`: its edges at its own start
    (the vertices, else the edges composed along a spanning tree).
    """
    from .g2o import write_g2o as write

    if isinstance(result_or_pose_graph, Result):
        pg = result_or_pose_graph.pose_graph
        if pg is None:
            raise InputError("write_g2o: this result is of a GTSAM graph, not a pose graph; "
                             "write it with lie_factors.g2o.write_g2o(path, graph, result.values)")
        values = result_or_pose_graph.values
    elif isinstance(result_or_pose_graph, PoseGraph):
        pg, values = result_or_pose_graph, result_or_pose_graph.initial
    else:
        raise InputError(f"write_g2o: expected a Result or a PoseGraph, got {type(result_or_pose_graph).__name__}")
    write(path, pg.factor_graph(), values)
