"""The input check: every line of a g2o file, then the file as a graph.

:func:`check_g2o` is our own check of every line, so a bad file gives
``file:line: what was expected`` instead of GTSAM silently skipping lines or
reading garbage.  It returns a :class:`G2oSummary` (the parsed rows) that the
readers take.  No numba here: the parse imports its numba scan only for files
where it pays (:func:`lie_factors.g2o.parse.parse`).
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field

import numpy as np

import gtsam

from ..util.arrays import sorted_unique
from ..errors import InputError
from ..posegraph.topology import components
from .parse import parse_file
from .records import RECORDS, Rows, first_true


@dataclass
class G2oSummary:
    """What :func:`check_g2o` learned about a file (all records parsed, all checks passed).

    ``rows``: tag → :class:`~lie_factors.g2o.records.Rows`; ``is3d``: which
    of GTSAM's readers the file is for; ``comment_lines``: lines starting
    with ``#``; ``fragile_lines``: 2-D lines whose 2nd/3rd field GTSAM's
    second pass cannot read as an integer (it stops reading there, see
    :func:`lie_factors.g2o.read.read_with_gtsam`).
    """

    path: str
    is3d: bool
    rows: dict[str, Rows]
    comment_lines: list[int] = field(default_factory=list)
    fragile_lines: list[int] = field(default_factory=list)

    def of_kind(self, kind: str, gtsam_only: bool = False) -> list[Rows]:
        """The rows of every tag of record kind ``kind`` (``gtsam_only``: of tags GTSAM reads)."""
        return [r for tag, r in self.rows.items()
                if RECORDS[tag].kind == kind and (RECORDS[tag].gtsam or not gtsam_only)]

    def _ids(self, kind: str) -> np.ndarray:
        parts = [r.ids[:, 0] for r in self.of_kind(kind)]
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)

    @property
    def group(self) -> str:
        """GTSAM type of the poses: Pose2, Pose3 or Similarity3."""
        return RECORDS[next(iter(self.rows))].group_name

    @property
    def pose_vertex_ids(self) -> np.ndarray:
        return self._ids("pose")

    @property
    def landmark_vertex_ids(self) -> np.ndarray:
        return self._ids("landmark")

    @property
    def vertices(self) -> dict[int, int]:
        """Pose vertex id → line."""
        out: dict[int, int] = {}
        for r in self.of_kind("pose"):
            out.update(zip(r.ids[:, 0].tolist(), r.lines.tolist()))
        return out

    @property
    def edges(self) -> list[tuple[int, int, int]]:
        """Pose–pose edges (id1, id2, line), in tag order."""
        out = []
        for r in self.of_kind("between"):
            out.extend(zip(r.ids[:, 0].tolist(), r.ids[:, 1].tolist(), r.lines.tolist()))
        return out

    @property
    def between_count(self) -> int:
        return sum(len(r) for r in self.of_kind("between"))

    @property
    def observation_count(self) -> int:
        return sum(len(r) for r in self.of_kind("observation"))

    @property
    def gtsam_factor_count(self) -> int:
        """Factors ``gtsam.readG2o`` builds from this file."""
        return self.between_count + sum(len(r) for r in self.of_kind("observation", True))

    @property
    def pose_ids(self) -> list[int]:
        """Every pose id: vertices, pose–pose edges, observing poses (sorted)."""
        return self.pose_id_array.tolist()

    @functools.cached_property
    def pose_id_array(self) -> np.ndarray:
        """:attr:`pose_ids` as an int64 array (computed once)."""
        vertices = self.pose_vertex_ids
        others = [r.ids[:, :2] for r in self.of_kind("between")] + [r.ids[:, 0] for r in self.of_kind("observation")]
        P = len(vertices)
        if P and np.array_equal(vertices, np.arange(P)) and all(
                not len(ids) or (ids.min() >= 0 and ids.max() < P) for ids in others):
            return vertices  # poses 0 … P−1 in order, every measurement among them: nothing to sort
        return sorted_unique(np.concatenate([vertices] + [ids.ravel() for ids in others]))

    @property
    def landmark_ids(self) -> list[int]:
        parts = [self.landmark_vertex_ids] + [r.ids[:, 1] for r in self.of_kind("observation")]
        return sorted_unique(np.concatenate(parts)).tolist()


def check_g2o(path: str) -> G2oSummary:
    """Validate a g2o file; raise :class:`InputError` naming the first bad line.

    Per line (:mod:`lie_factors.g2o.parse`): known tag (see
    :data:`~lie_factors.g2o.records.RECORDS`), one dimension per file, field
    count, integer ids in [0, 2^56), numbers C++ reads (no inf/nan/hex) and
    finite; per record: normalizable quaternions, positive-definite
    information, positive ranges and standard deviations.  Per file: no
    duplicate vertex, no self-loop, at least one measurement, landmark
    measurements in 3-D refer to existing vertices and an identity
    ``PARAMS_SE3OFFSET`` (GTSAM's rules), and one connected graph (a second
    component would have no prior: its gauge is free and the system singular).
    """
    name = os.path.basename(path)
    rows, comments, fragile = parse_file(path)
    if not rows:
        raise InputError(f"{name}: empty graph (no vertices and no edges)")
    is3d = RECORDS[next(iter(rows))].dim == 3
    summary = G2oSummary(path, is3d, rows, comments, fragile)
    _check_rows(name, summary)
    _check_graph(name, summary)
    return summary


def _check_rows(name: str, summary: G2oSummary) -> None:
    """Run every record's row checks; raise at the earliest bad line."""
    problems: list[tuple[int, str]] = []
    for tag, r in summary.rows.items():
        rec = RECORDS[tag]
        if rec.kind == "between":
            bad = first_true(r.ids[:, 0] == r.ids[:, 1])
            if bad is not None:
                problems.append((int(r.lines[bad]),
                                 f"edge connects vertex {r.ids[bad, 0]} to itself"))
        for check in rec.checks:
            for row, msg in check(r):
                problems.append((int(r.lines[row]), msg))
                break
    if problems:
        lineno, msg = min(problems)
        raise InputError(f"{name}:{lineno}: {msg}")


def _duplicates(ids: np.ndarray, lines: np.ndarray):
    """First duplicated id (by line of its second definition): (id, first line, second line)."""
    if len(ids) < 2 or np.all(ids[1:] > ids[:-1]):  # none, or increasing ids: no duplicate
        return None
    order = np.lexsort((lines, ids))
    s_ids, s_lines = ids[order], lines[order]
    dup = np.flatnonzero(s_ids[1:] == s_ids[:-1])
    if dup.size == 0:
        return None
    k = dup[np.argmin(s_lines[dup + 1])]
    return int(s_ids[k]), int(s_lines[k]), int(s_lines[k + 1])


def _check_graph(name: str, s: G2oSummary) -> None:
    for kind, label in (("pose", "vertex"), ("landmark", "landmark vertex"), ("param", "PARAMS_SE3OFFSET")):
        parts = s.of_kind(kind)
        if not parts:
            continue
        ids = np.concatenate([r.ids[:, 0] for r in parts])
        lines = np.concatenate([r.lines for r in parts])
        dup = _duplicates(ids, lines)
        if dup is not None:
            vid, first, second = dup
            tail = " (GTSAM would keep the first)" if kind == "param" else ""
            raise InputError(f"{name}:{second}: {label} {vid} already defined on line {first}{tail}")

    if s.between_count + s.observation_count == 0:
        raise InputError(f"{name}: empty graph (no edges, nothing to optimize)")

    if s.is3d:
        _check_3d_references(name, s)

    # Pose–pose edges to poses without a vertex: in 2-D GTSAM's reader chains
    # them from the edge; in 3-D it leaves them without a value (refuse).
    pose_vertices = s.pose_vertex_ids
    if s.is3d and len(pose_vertices):
        for r in s.of_kind("between"):
            for col in (0, 1):
                bad = first_true(~np.isin(r.ids[:, col], pose_vertices))
                if bad is not None:
                    i, j = r.ids[bad]
                    raise InputError(
                        f"{name}:{r.lines[bad]}: edge {i}-{j} refers to pose {r.ids[bad, col]}, "
                        f"which has no vertex (gtsam.readG2o gives it no initial value in 3-D)")
    _check_connected(name, s)


def _check_3d_references(name: str, s: G2oSummary) -> None:
    """GTSAM's EDGE_SE3_TRACKXYZ rules: existing pose and landmark vertices, identity offset."""
    track = s.rows.get("EDGE_SE3_TRACKXYZ")
    if track is None:
        return
    poses, lms = s.pose_vertex_ids, s.landmark_vertex_ids
    bad = first_true(~np.isin(track.ids[:, 0], poses) | ~np.isin(track.ids[:, 1], lms))
    if bad is not None:
        p, l = track.ids[bad, :2]
        raise InputError(f"{name}:{track.lines[bad]}: EDGE_SE3_TRACKXYZ refers to pose {p} and "
                             f"landmark {l}, which need VERTEX_SE3:QUAT/VERTEX3 and VERTEX_TRACKXYZ "
                             f"lines (gtsam.readG2o refuses it too)")
    params = s.rows.get("PARAMS_SE3OFFSET")
    identity: dict[int, bool] = {}
    if params is not None:
        for pid, v in zip(params.ids[:, 0].tolist(), params.values):
            q = v[3:7]
            offset = gtsam.Pose3(gtsam.Rot3.Quaternion(q[3], q[0], q[1], q[2]), v[:3])
            # GTSAM accepts an offset equal to the identity within 1e-9 (checked on the wheel).
            identity[pid] = bool(offset.equals(gtsam.Pose3(), 1e-9))
    for row, pid in enumerate(track.ids[:, 2].tolist()):
        if pid not in identity:
            raise InputError(f"{name}:{track.lines[row]}: EDGE_SE3_TRACKXYZ uses sensor offset "
                                 f"{pid}, but no PARAMS_SE3OFFSET {pid} line defines it")
        if not identity[pid]:
            raise InputError(f"{name}:{track.lines[row]}: EDGE_SE3_TRACKXYZ uses sensor offset "
                                 f"{pid}, which is not the identity (gtsam.readG2o supports only "
                                 f"identity offsets)")


def _check_connected(name: str, s: G2oSummary) -> None:
    """One connected graph of poses and landmarks (:func:`lie_factors.posegraph.topology.components`)."""
    poses = s.pose_id_array
    lms = np.asarray(s.landmark_ids, dtype=np.int64)
    P = len(poses)
    us, vs = [], []
    for r in s.of_kind("between"):
        us.append(np.searchsorted(poses, r.ids[:, 0]))
        vs.append(np.searchsorted(poses, r.ids[:, 1]))
    for r in s.of_kind("observation"):
        us.append(np.searchsorted(poses, r.ids[:, 0]))
        vs.append(P + np.searchsorted(lms, r.ids[:, 1]))
    u = np.concatenate(us) if us else np.zeros(0, dtype=np.int64)
    v = np.concatenate(vs) if vs else np.zeros(0, dtype=np.int64)
    labels = components(P + len(lms), u, v)
    root = labels[0]
    lost = np.flatnonzero(labels != root)
    if lost.size:
        k = int(lost[0])
        what = f"pose {poses[k]}" if k < P else f"landmark {lms[k - P]}"
        raise InputError(
            f"{name}: graph is not connected: {what} cannot be reached from pose {poses[0]} "
            f"({lost.size} of {len(labels)} variables unreachable; only pose {poses[0]} gets a prior)")
