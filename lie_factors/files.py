"""Files in and out at the front door: g2o pose graphs, TUM and KITTI trajectories, and the
evaluation of a trajectory against a reference (:func:`evaluate`)."""

from __future__ import annotations

import os


from .errors import InputError
from .evaluation.metrics import Evaluation, evaluate_trajectories
from .evaluation.trajectory import FORMATS, Trajectory, planar_poses, read_trajectory as _read, write_trajectory_file
from .g2o import read_pose_graph
from .posegraph.graph import PoseGraph
from .result import Result

__all__ = ["read_g2o", "write_g2o", "read_trajectory", "write_trajectory", "trajectory_of", "evaluate",
           "write_covariances", "read_covariances"]


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


def read_trajectory(path: str, format: str | None = None) -> Trajectory:
    """A TUM (``stamp tx ty tz qx qy qz qw``) or KITTI (a 3×4 matrix per row) trajectory file; the
    format from the extension (``.tum``, ``.kitti``) or ``format``.  Every line is checked (its
    columns, a unit quaternion, an orthonormal rotation); a bad one raises
    :class:`~lie_factors.errors.InputError` naming the file and the line."""
    return _read(path, format)


def trajectory_of(source, name: str = "") -> Trajectory:
    """A :class:`~lie_factors.evaluation.trajectory.Trajectory` of ``source``: a trajectory, a
    :class:`~lie_factors.result.Result` of a pose graph (its estimate, stamped by pose key),
    a :class:`~lie_factors.posegraph.graph.PoseGraph` (its start: the vertices, else the edges
    composed), or a path: a TUM or KITTI file, or a g2o file (its vertices)."""
    if isinstance(source, Trajectory):
        return source
    if isinstance(source, Result):
        return Trajectory(source.keys, planar_poses(source.poses), True, name or "estimate")
    if isinstance(source, PoseGraph):
        return Trajectory(source.keys, planar_poses(source.start_poses), True, name or source.name)
    if isinstance(source, (str, os.PathLike)):
        path = os.fspath(source)
        if os.path.splitext(path)[1].lower() in FORMATS:
            return _read(path)
        return trajectory_of(read_pose_graph(path))
    raise InputError(f"expected a trajectory, a Result, a PoseGraph or a path, got {type(source).__name__}")


def write_trajectory(source, path: str, format: str | None = None) -> None:
    """Write ``source`` (a :class:`~lie_factors.result.Result`, a
    :class:`~lie_factors.posegraph.graph.PoseGraph` or a trajectory) as TUM or KITTI, atomically:
    the format from the extension (``.tum``, ``.kitti``) or ``format``.  A stamp is the pose key
    (or the stamp a TUM input carried); 2-D poses are written as planar 3-D ones."""
    if isinstance(source, (str, os.PathLike)):
        raise InputError("write_trajectory: give a Result, a PoseGraph or a Trajectory, not a path")
    write_trajectory_file(trajectory_of(source), path, format)


def evaluate(estimate, reference, align: str = "se3", delta: int = 1) -> Evaluation:
    """The absolute (ATE) and relative (RPE) trajectory errors of ``estimate`` against
    ``reference``, as evo computes them (``evo_ape -a``/``-as``, ``evo_rpe -d DELTA -u f``).

    ``estimate``, ``reference``: results, pose graphs, trajectories or files (g2o, TUM,
    KITTI: :func:`trajectory_of`); poses are associated by stamp (pose id for g2o);
    ``align``: ``se3`` (Umeyama, rigid), ``sim3`` (with scale) or ``none``; ``delta``: the
    RPE's step in poses.  Returns an :class:`~lie_factors.evaluation.metrics.Evaluation`
    (``ate``, ``rpe``: RMSE, mean, median, std, min, max; ``to_dict()`` for JSON).
    """
    return evaluate_trajectories(trajectory_of(estimate, "estimate"), trajectory_of(reference, "reference"),
                                 align, delta)


def write_covariances(result: Result, path: str, keys=None) -> None:
    """Write the marginal covariances of ``result`` (:meth:`~lie_factors.result.Result.covariances`
    of ``keys``, default every pose) as a NumPy ``.npz``, atomically: ``keys`` (n,) int64,
    ``covariances`` (n, d, d) in GTSAM's tangent order, and ``group`` (its name)."""
    import numpy as np

    from .util.atomic import replace_atomically

    if not isinstance(result, Result):
        raise InputError(f"write_covariances: expected a Result, got {type(result).__name__}")
    if result.group is None:
        raise InputError("write_covariances: the estimate holds no pose variable; the file holds poses' "
                         "covariances (result.covariances() gives every variable's)")
    keys = result.keys if keys is None else np.asarray(keys, dtype=np.int64).reshape(-1)
    covariances = result.marginals.covariances(keys)

    def write(tmp: str) -> None:
        with open(tmp, "wb") as fh:  # a file object: np.savez would add ".npz" to a name
            np.savez(fh, keys=keys, covariances=covariances, group=np.array(result.group))

    replace_atomically(path, write, suffix=".npz")


def read_covariances(path: str) -> tuple:
    """``(keys (n,), covariances (n, d, d), group)`` of a file :func:`write_covariances` wrote."""
    import numpy as np

    try:
        with np.load(path) as f:
            return f["keys"], f["covariances"], str(f["group"])
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (OSError, ValueError, KeyError) as exc:
        raise InputError(f"{path}: not a covariance file written by write_covariances ({exc})") from None
