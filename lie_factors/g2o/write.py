"""Writing g2o files, atomically (:func:`lie_factors.util.atomic.replace_atomically`).

* :func:`write_g2o` — ``gtsam.writeG2o`` plus the landmark records it drops;
* :func:`write_sim3_g2o` — Sim(3) records, which GTSAM does not know.

Numbers we write are Python's ``repr`` of the double: the shortest text that
reads back as the same number.
"""

from __future__ import annotations

import math

import numpy as np

import gtsam

from ..util.atomic import replace_atomically
from .conventions import point_information_2d, similarity3_to_g2o


def _numbers(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def _landmark2_lines(graph: gtsam.NonlinearFactorGraph) -> list[str]:
    """``LANDMARK2`` lines for the graph's BearingRangeFactor2D s (gtsam.writeG2o drops them)."""
    lines = []
    for k in range(graph.size()):
        f = graph.at(k)
        if not isinstance(f, gtsam.BearingRangeFactor2D):
            continue
        i, l = f.keys()
        br = f.measured()
        b, r = br.bearing().theta(), br.range()
        R = f.noiseModel().R()
        info = point_information_2d(b, r, R.T @ R)
        x, y = r * math.cos(b), r * math.sin(b)
        vals = (x, y, info[0, 0], info[0, 1], info[1, 1])
        lines.append(f"LANDMARK2 {gtsam.Symbol(i).index()} {gtsam.Symbol(l).index()} " + _numbers(vals))
    return lines


def _landmark_vertex_lines(values: gtsam.Values, written: set[int]) -> list[str]:
    """VERTEX_XY / VERTEX_TRACKXYZ lines for the landmarks gtsam.writeG2o did not write.

    A Point2/Point3 inserted from Python is stored as a dynamic-size vector,
    which writeG2o silently skips; those written by GTSAM are in ``written``.
    """
    lines = []
    for key in sorted(values.keys()):
        sym = gtsam.Symbol(key)
        if sym.chr() != ord("l") or sym.index() in written:
            continue
        # Stored as fixed-size (GTSAM's reader) or dynamic (from Python): try both getters.
        try:
            p = np.asarray(values.atPoint3(key), dtype=float)
        except RuntimeError:
            p = np.asarray(values.atPoint2(key), dtype=float)
        tag = "VERTEX_TRACKXYZ" if p.size == 3 else "VERTEX_XY"
        lines.append(f"{tag} {sym.index()} " + _numbers(p))
    return lines


def _pose_vertex_lines(values: gtsam.Values) -> dict[str, list[str]]:
    """Full-precision ``VERTEX_SE2`` / ``VERTEX_SE3:QUAT`` lines, per tag, in the order gtsam.writeG2o
    writes them (each type's keys ascending)."""
    out: dict[str, list[str]] = {"VERTEX_SE2": [], "VERTEX_SE3:QUAT": []}
    poses2, poses3 = gtsam.utilities.allPose2s(values), gtsam.utilities.allPose3s(values)
    for key in sorted(poses2.keys()):
        x = poses2.atPose2(key)
        out["VERTEX_SE2"].append(f"VERTEX_SE2 {gtsam.Symbol(key).index()} "
                                 + _numbers((x.x(), x.y(), x.theta())))
    for key in sorted(poses3.keys()):
        x = poses3.atPose3(key)
        out["VERTEX_SE3:QUAT"].append(f"VERTEX_SE3:QUAT {gtsam.Symbol(key).index()} " + _pose3_numbers(x))
    return out


def _pose3_numbers(x: gtsam.Pose3) -> str:
    q = x.rotation().toQuaternion()
    return _numbers((*np.asarray(x.translation()), q.x(), q.y(), q.z(), q.w()))


def _pose_edge_lines(graph: gtsam.NonlinearFactorGraph) -> dict[str, list[str]]:
    """Full-precision ``EDGE_SE2`` / ``EDGE_SE3:QUAT`` lines of the graph's Pose2/Pose3 between
    factors, per tag, in factor order (gtsam.writeG2o's).  The information is RᵀR of the Gaussian
    noise model, upper triangle by rows; a Pose3 edge's reordered from GTSAM's (rotation,
    translation) to g2o's (translation, rotation)."""
    out: dict[str, list[str]] = {"EDGE_SE2": [], "EDGE_SE3:QUAT": []}
    upper = {3: np.triu_indices(3), 6: np.triu_indices(6)}
    swap = np.ix_(np.r_[3:6, 0:3], np.r_[3:6, 0:3])
    for k in range(graph.size()):
        f = graph.at(k)
        if isinstance(f, gtsam.BetweenFactorPose2):
            m = f.measured()
            R = np.asarray(f.noiseModel().R())
            info = R.T @ R
            tag, numbers = "EDGE_SE2", _numbers((m.x(), m.y(), m.theta()))
        elif isinstance(f, gtsam.BetweenFactorPose3):
            R = np.asarray(f.noiseModel().R())
            info = (R.T @ R)[swap]
            tag, numbers = "EDGE_SE3:QUAT", _pose3_numbers(f.measured())
        else:
            continue
        i, j = f.keys()
        out[tag].append(f"{tag} {gtsam.Symbol(i).index()} {gtsam.Symbol(j).index()} {numbers} "
                        + _numbers(info[upper[info.shape[0]]]))
    return out


def _full_precision(lines: list[str], graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> list[str]:
    """gtsam.writeG2o's ``lines`` with its pose vertices and pose edges, which it prints to six
    significant digits, rewritten from ``graph`` and ``values`` in full (each the shortest text that
    reads back as the same double).  Each rewritten line must name the same ids as GTSAM's: anything
    else means the two disagree on what they write, and raises ``RuntimeError`` (nothing is written)."""
    ours = {**_pose_vertex_lines(values), **_pose_edge_lines(graph)}
    taken = dict.fromkeys(ours, 0)
    out = []
    for line in lines:
        tag = line.split(" ", 1)[0]
        if tag not in ours:
            out.append(line)
            continue
        n = taken[tag]
        ids = 2 if tag.startswith("EDGE") else 1
        if n >= len(ours[tag]) or ours[tag][n].split()[:ids + 1] != line.split()[:ids + 1]:
            raise RuntimeError(f"write_g2o: GTSAM wrote {line.split()[:ids + 1]} where "
                               f"{ours[tag][n].split()[:ids + 1] if n < len(ours[tag]) else 'nothing'} was expected")
        out.append(ours[tag][n])
        taken[tag] = n + 1
    return out


def write_g2o(path: str, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
    """``gtsam.writeG2o`` + the landmark records it drops, via a temporary file, with its pose
    vertices and pose edges in full precision (GTSAM prints six significant digits).

    GTSAM writes poses, pose–pose edges and 3-D landmark measurements
    (``EDGE_SE3_TRACKXYZ`` with an identity ``PARAMS_SE3OFFSET``); we add
    the landmark vertices and the 2-D landmark measurements as ``LANDMARK2``
    (pose-frame x y + information, exact inverse of how we read them).
    writeG2o recognises only GTSAM's own BetweenFactorPose2/3 and BearingRangeFactor3D,
    so lie_factors' factors equal to GTSAM's (:mod:`lie_factors.factors`' Between/Prior
    factors, the ready bearing-range and range factors of :mod:`lie_factors.expressions.ready`)
    are written as GTSAM's own (their ``as_gtsam()``); any other custom factor would
    silently lose its edge.  A graph of ``BetweenFactorSimilarity3`` is written by
    :func:`write_sim3_g2o`.
    """
    graph = _as_gtsam(graph)
    if _is_sim3_graph(graph):
        write_sim3_g2o(path, graph, values)
        return

    def write(tmp: str) -> None:
        gtsam.writeG2o(graph, values, tmp)
        with open(tmp, encoding="utf-8") as fh:
            lines = fh.read().splitlines()
        lines = _full_precision(lines, graph, values)
        written = {int(line.split()[1]) for line in lines
                   if line.startswith(("VERTEX_XY ", "VERTEX_TRACKXYZ "))}
        lines += _landmark_vertex_lines(values, written) + _landmark2_lines(graph)
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write("\n".join(lines) + "\n" if lines else "")

    replace_atomically(path, write, suffix=".g2o")


def _as_gtsam(graph: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
    """``graph`` with each factor that has GTSAM's own equal (``as_gtsam()``) replaced by it;
    ``graph`` itself where none has."""
    factors = [graph.at(k) for k in range(graph.size())]
    if not any(hasattr(f, "as_gtsam") for f in factors):
        return graph
    out = gtsam.NonlinearFactorGraph()
    for f in factors:
        if f is not None:
            out.add(f.as_gtsam() if hasattr(f, "as_gtsam") else f)
    return out


def _is_sim3_graph(graph: gtsam.NonlinearFactorGraph) -> bool:
    return graph.size() > 0 and isinstance(graph.at(0), gtsam.BetweenFactorSimilarity3)


def write_sim3_g2o(path: str, between: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
    """Write ``VERTEX_SIM3:EXPMAP`` / ``EDGE_SIM3:EXPMAP`` lines, atomically.

    ``between``: native ``gtsam.BetweenFactorSimilarity3`` factors (anything else
    raises ``TypeError``, nothing is written); ``values``: ``gtsam.Similarity3``
    per key, written in key order.  Each vertex gets g2o's default camera
    ``1 1 0 0``; each edge the information matrix of its Gaussian noise model.
    """
    lines = []
    for key in sorted(values.keys()):
        v = similarity3_to_g2o(values.atSimilarity3(key))
        lines.append(f"VERTEX_SIM3:EXPMAP {key} {_numbers(v)} 1 1 0 0\n")
    iu = np.triu_indices(7)
    for k in range(between.size()):
        f = between.at(k)
        if not isinstance(f, gtsam.BetweenFactorSimilarity3):
            raise TypeError(f"write_sim3_g2o: factor {k} is a {type(f).__name__}, "
                            "expected gtsam.BetweenFactorSimilarity3")
        noise = f.noiseModel()
        if not isinstance(noise, gtsam.noiseModel.Gaussian) or isinstance(
                noise, (gtsam.noiseModel.Robust, gtsam.noiseModel.Constrained)):
            raise TypeError(f"write_sim3_g2o: factor {k} has a {type(noise).__name__} noise model; "
                            "g2o stores only Gaussian information matrices")
        info = np.asarray(noise.information())
        i, j = f.keys()
        lines.append(f"EDGE_SIM3:EXPMAP {i} {j} {_numbers(similarity3_to_g2o(f.measured()))} "
                     f"{_numbers(info[iu])}\n")
    text = "".join(lines)

    def write(tmp):
        with open(tmp, "w", encoding="utf-8") as out:
            out.write(text)

    replace_atomically(path, write, suffix=".g2o")
