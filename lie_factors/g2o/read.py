"""Reading a checked g2o file (:func:`lie_factors.g2o.check.check_g2o`'s summary).

* :func:`read_with_gtsam` — as GTSAM reads it: ``gtsam.readG2o`` on the file (or on a
  cleaned copy of it), plus the factors of the records GTSAM's reader skips
  (``LANDMARK2``), or our Sim(3) reader for Sim(3) records;
* :func:`read_arrays` — a pose graph as :class:`lie_factors.posegraph.graph.PoseGraph`,
  the same numbers with no GTSAM object.

The numbers' conventions are in :mod:`lie_factors.g2o.conventions`.
"""

from __future__ import annotations

import math
import os
import tempfile

import numpy as np

import gtsam

from ..errors import InputError, first_line
from ..posegraph.graph import PoseGraph
from .check import G2oSummary, check_g2o
from .conventions import (bearing_range_information_2d, elements, information, landmark_key, similarity3_from_g2o)
from .records import RECORDS, Rows


def landmark2_factors(rows: Rows) -> list:
    """``BearingRangeFactor2D`` s for ``LANDMARK2`` rows: pose key, landmark key ``l``."""
    out = []
    for (i, j), v, info in zip(rows.ids.tolist(), rows.values, information(rows)):
        p = v[:2]
        noise = gtsam.noiseModel.Gaussian.Information(bearing_range_information_2d(p, info))
        out.append(gtsam.BearingRangeFactor2D(i, landmark_key(j), gtsam.Rot2(math.atan2(p[1], p[0])),
                                              float(math.hypot(p[0], p[1])), noise))
    return out


def _gtsam_copy(path: str, summary: G2oSummary) -> str | None:
    """A copy of a 2-D file GTSAM reads correctly, or None if the file itself is safe.

    ``load2D``'s second pass reads ``id1 id2`` from every line that is not a
    pose edge before looking at the tag; a line whose 2nd or 3rd field is not
    an unsigned integer prefix (a comment, ``VERTEX_SE2 3 .5 0 0``) makes the
    stream fail and every later edge is silently dropped.  The copy leaves out
    comment lines and writes such vertex values as Python's repr of the same double.
    """
    if summary.is3d or not (summary.comment_lines or summary.fragile_lines):
        return None
    skip = set(summary.comment_lines)
    fix = set(summary.fragile_lines)
    fd, tmp = tempfile.mkstemp(suffix=".g2o")
    with os.fdopen(fd, "wb") as out, open(path, "rb") as src:
        for lineno, line in enumerate(src.read().split(b"\n"), start=1):
            if lineno in skip:
                continue
            if lineno in fix:
                # Same doubles, spelled so that a size_t read of them succeeds.
                tokens = line.split()
                line = b" ".join(tokens[:2] + [repr(float(t)).encode() for t in tokens[2:]])
            out.write(line + b"\n")
    return tmp


def read_with_gtsam(path: str, summary: G2oSummary):
    """Read a checked file: (graph, initial) as ``gtsam.readG2o`` builds them, plus LANDMARK2 factors.

    Verifies that GTSAM read as many factors and vertices as the check found
    (a disagreement is refused rather than half a file optimized).  Sim(3)
    files are read by :func:`_read_sim3` (GTSAM's reader does not know them).
    """
    if summary.group == "Similarity3":
        return _read_sim3(summary)
    tmp = _gtsam_copy(path, summary)
    try:
        try:
            graph, initial = gtsam.readG2o(tmp or path, summary.is3d)
        except (RuntimeError, ValueError) as exc:
            msg = first_line(exc)
            raise InputError(f"{os.path.basename(path)}: gtsam.readG2o refused it: {msg}") from None
    finally:
        if tmp is not None:
            os.unlink(tmp)
    expected = summary.gtsam_factor_count
    if graph.size() != expected:
        raise InputError(f"{os.path.basename(path)}: gtsam.readG2o read {graph.size()} factors, "
                             f"the file has {expected}")
    rows = summary.rows.get("LANDMARK2")
    if rows is not None:
        for f in landmark2_factors(rows):
            graph.add(f)
    return graph, initial


def _read_sim3(summary: G2oSummary):
    """(graph of ``gtsam.BetweenFactorSimilarity3``, Values of ``gtsam.Similarity3``) of a checked Sim(3) file.

    Noise models are ``Gaussian.Information`` of the file's 7×7 information matrices.
    """
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    vertices = summary.rows.get("VERTEX_SIM3:EXPMAP")
    if vertices is not None:
        for (i,), v in zip(vertices.ids.tolist(), vertices.values):
            initial.insert(i, similarity3_from_g2o(v[:7]))
    edges = summary.rows.get("EDGE_SIM3:EXPMAP")
    if edges is not None:
        for (i, j), v, info in zip(edges.ids.tolist(), edges.values, information(edges)):
            graph.add(gtsam.BetweenFactorSimilarity3(i, j, similarity3_from_g2o(v[:7]),
                                                     gtsam.noiseModel.Gaussian.Information(info)))
    return graph, initial


def read_sim3_g2o(path: str):
    """:func:`~lie_factors.g2o.check.check_g2o` + the Sim(3) reading of a file: (graph, initial)."""
    return _read_sim3(check_g2o(path))


# --------------------------------------------------------------------------- #
# Reading into arrays (no GTSAM objects)
# --------------------------------------------------------------------------- #

def arrays_supported(summary: G2oSummary) -> bool:
    """Can :func:`read_arrays` represent this file?  Pose–pose files whose poses all have a
    vertex, or none has one (landmark records and 2-D files whose edges introduce
    poses GTSAM chains from odometry are read by GTSAM, :func:`read_with_gtsam`)."""
    if any(RECORDS[t].kind not in ("pose", "between") for t in summary.rows):
        return False
    vertices = summary.pose_vertex_ids
    return len(vertices) == 0 or len(vertices) == len(summary.pose_id_array)


def read_arrays(summary: G2oSummary) -> PoseGraph:
    """The checked file's poses and edges as :class:`PoseGraph`, with no GTSAM object.

    The same numbers as ``gtsam.readG2o`` (quaternions normalized, SE(3)
    information permuted to [ω, v]; Sim(3) records as :func:`read_with_gtsam`),
    computed per record type on the arrays :func:`~lie_factors.g2o.check.check_g2o` parsed.
    Raises :class:`~lie_factors.errors.InputError` for files :func:`arrays_supported` refuses.
    """
    if not arrays_supported(summary):
        raise InputError(f"{summary.path}: landmark records or poses without a vertex line: "
                         "use read_with_gtsam")
    keys = summary.pose_id_array
    edges = summary.of_kind("between")
    # GTSAM's factor order is the file's line order (one tag: the rows are in it already)
    order = None if len(edges) == 1 else np.argsort(np.concatenate([r.lines for r in edges]), kind="stable")
    edge_keys = _in_order([r.ids[:, :2] for r in edges], order)
    measured = _in_order([elements(r) for r in edges], order)
    info = _in_order([information(r) for r in edges], order)
    lines = _in_order([r.lines for r in edges], order)
    vertices = None
    poses = summary.of_kind("pose")
    if poses:
        ids = np.concatenate([r.ids[:, 0] for r in poses])
        X = np.concatenate([elements(r) for r in poses]) if len(poses) > 1 else elements(poses[0])
        # every pose has exactly one vertex (arrays_supported, check_g2o): sorted ids are the keys
        vertices = X if np.all(ids[1:] > ids[:-1]) else X[np.argsort(ids)]
    return PoseGraph(summary.group, keys, np.ascontiguousarray(edge_keys), measured, info, vertices, lines)


def _in_order(parts: list, order: np.ndarray | None) -> np.ndarray:
    """The parts concatenated, rows taken in ``order`` (None: as they are, one part not copied)."""
    if order is None and len(parts) == 1:
        return parts[0]
    whole = np.concatenate(parts)
    return whole if order is None else whole[order]
