"""g2o files: find, check, read and write them (the formats have one home here).

* :func:`resolve_dataset` — a path, or the name of a file shipped with GTSAM.
* :func:`check_g2o` — our own line-by-line check, so a bad file gives
  ``file:line: what was expected`` instead of GTSAM silently skipping lines.
* :func:`read_g2o` — ``gtsam.readG2o`` on a checked file.
* :func:`write_g2o` — ``gtsam.writeG2o``, atomically.

Supported records (g2o, and the TORO-style ``EDGE3``/``VERTEX3`` GTSAM ships):

=================  ====  ====================================================
tag                dim   fields after the tag
=================  ====  ====================================================
VERTEX_SE2         2     id x y θ
EDGE_SE2           2     id1 id2 x y θ + 6 upper-triangular information
VERTEX_SE3:QUAT    3     id x y z qx qy qz qw
EDGE_SE3:QUAT      3     id1 id2 x y z qx qy qz qw + 21 information
VERTEX3            3     id x y z roll pitch yaw
EDGE3              3     id1 id2 x y z roll pitch yaw + 21 information
VERTEX_SIM3:EXPMAP 3     id ω1 ω2 ω3 u1 u2 u3 λ fx fy cx cy
EDGE_SIM3:EXPMAP   3     id1 id2 ω1 ω2 ω3 u1 u2 u3 λ + 28 information
=================  ====  ====================================================

Information ordering: g2o writes SE(3) information as [t, R]; GTSAM's Pose3
tangent is [ω, v], and ``readG2o`` permutes the blocks of ``EDGE_SE3:QUAT``
information accordingly (checked: a file diag(100·I₃, 25·I₃) yields the noise
model diag(25·I₃, 100·I₃)).  ``EDGE3`` information is taken by ``readG2o`` as
is (no permutation).  SE(2) information is [x, y, θ] in both.  We never touch
the noise models: both backends get exactly the ones ``readG2o`` built.

Sim(3) records (g2o's ``types_seven_dof_expmap``, written by ORB-SLAM-style
systems) are read and written here, not by GTSAM, which does not know them.
g2o's ``Sim3`` (R, t, s) acts as p ↦ s·R·p + t, its vertex estimate is the
world→camera transform S_iw, and its edge measurement is S_ji = S_jw·S_iw⁻¹ with
error log(S_ji·S_iw·S_jw⁻¹).  What the file holds is the 7-vector
``log(S_iw⁻¹)`` (vertex: camera→world) or ``log(S_ji⁻¹)`` (edge), in g2o's
tangent order [ω, υ, σ] with exp(ω, υ, σ) = (exp(ω×), W·υ, e^σ), i.e. the
matrix exponential of [[ω× + σI, υ], [0, 0]].  The conversion to GTSAM:

* element: g2o (R, t, s) is GTSAM's ``Similarity3(R, t/s, s)`` — the same
  similarity, since GTSAM's matrix [[R, t/s], [0, 1/s]] is g2o's [[sR, t], [0, 1]]
  divided by s (a homogeneous matrix means the same map after scaling);
* tangent: [[ω×, υ], [0, −σ]] (GTSAM's ``Hat``) = [[ω× + σI, υ], [0, 0]] − σI₄,
  and σI₄ commutes with everything, so GTSAM's ``Expmap([ω, υ, σ])`` is g2o's
  exp of the same 7 numbers, divided by e^σ: *the file's vector is GTSAM's
  Similarity3 tangent, unchanged*;
* poses: camera→world S_iw⁻¹ is the GTSAM pose X_i (body→world, as everywhere
  in GTSAM), and S_ji⁻¹ = S_iw·S_jw⁻¹ = X_i⁻¹·X_j is the ``measured`` of
  ``BetweenFactorSimilarity3(i, j, ...)``;
* errors and information: g2o's error log(S_ji·S_iw·S_jw⁻¹) = log(Z⁻¹·X_i⁻¹·X_j)
  is GTSAM's between error, so the 7×7 information (upper triangle, row-major)
  is used as is, without permutation.

So a vertex becomes ``Similarity3(sim3.exp(v))`` and is written as
``sim3.log(X.matrix())``; we use the exact exp/log of :mod:`lie_factors.sim3`
(g2o's own ``Sim3(Vector7)`` treats |σ| < 1e-5 as σ = 0 in W, which moves t by
up to |σ|/2 relative).  The vertex's four camera values (focal lengths and
principal point, unused by pose graphs) are checked for being numbers and
dropped; we write g2o's defaults ``1 1 0 0``.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections import deque
from dataclasses import dataclass

import numpy as np

import gtsam

from .atomic import replace_atomically
from .errors import PoseGraphError


def resolve_dataset(name: str) -> str:
    """Return a readable file path for ``name``: an existing path, else a GTSAM example.

    Raises :class:`PoseGraphError` if it is neither.
    """
    if os.path.isdir(name):
        raise PoseGraphError(f"{name}: is a directory, expected a g2o file")
    if os.path.isfile(name):
        return name
    # Only bare names are looked up among GTSAM's examples: a path with a
    # directory that does not exist is a typo, not a dataset name.
    if os.path.dirname(name) == "":
        try:
            return gtsam.findExampleDataFile(name)
        except (RuntimeError, OSError):  # the Python wrapper raises FileNotFoundError
            pass
        raise PoseGraphError(
            f"{name}: no such file, and not a dataset shipped with GTSAM "
            f"(gtsam.findExampleDataFile)"
        )
    raise PoseGraphError(f"{name}: no such file")


@dataclass(frozen=True)
class _Record:
    kind: str  # "vertex" or "edge"
    dim: int  # 2 or 3
    ids: int
    pose: int
    info: int
    pose_desc: str
    extra: int = 0  # trailing values that are read but not used (VERTEX_SIM3's camera)
    group: str = ""  # GTSAM type, when the dimension alone does not say it

    @property
    def nfields(self) -> int:
        return self.ids + self.pose + self.extra + self.info

    @property
    def tangent_dim(self) -> int:
        """n of the n×n information matrix (edges)."""
        return int(round((math.sqrt(8 * self.info + 1) - 1) / 2))

    @property
    def group_name(self) -> str:
        return self.group or ("Pose3" if self.dim == 3 else "Pose2")


_RECORDS = {
    "VERTEX_SE2": _Record("vertex", 2, 1, 3, 0, "x y θ"),
    "EDGE_SE2": _Record("edge", 2, 2, 3, 6, "x y θ"),
    "VERTEX_SE3:QUAT": _Record("vertex", 3, 1, 7, 0, "x y z qx qy qz qw"),
    "EDGE_SE3:QUAT": _Record("edge", 3, 2, 7, 21, "x y z qx qy qz qw"),
    "VERTEX3": _Record("vertex", 3, 1, 6, 0, "x y z roll pitch yaw"),
    "EDGE3": _Record("edge", 3, 2, 6, 21, "x y z roll pitch yaw"),
    "VERTEX_SIM3:EXPMAP": _Record("vertex", 3, 1, 7, 0, "ω1 ω2 ω3 u1 u2 u3 λ", extra=4,
                                  group="Similarity3"),
    "EDGE_SIM3:EXPMAP": _Record("edge", 3, 2, 7, 28, "ω1 ω2 ω3 u1 u2 u3 λ", group="Similarity3"),
}
SIM3_TAGS = ("VERTEX_SIM3:EXPMAP", "EDGE_SIM3:EXPMAP")

#: Largest accepted |λ| of a Sim(3) record: e^±700 is still a normal double.
SIM3_MAX_LOG_SCALE = 700.0

#: Largest accepted | ‖q‖ − 1 | for a g2o quaternion.  Files print 6–7 digits
#: (the shared datasets deviate by ≤ 2e-6); GTSAM does not renormalize, so a
#: clearly non-unit quaternion would become a non-orthogonal "rotation".
QUAT_NORM_TOL = 1e-3


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def _expects(tag: str, rec: _Record) -> str:
    parts = [_plural(rec.ids, "id"), _plural(rec.pose, "pose value")]
    if rec.extra:
        parts.append(_plural(rec.extra, "camera value"))
    if rec.info:
        parts.append(_plural(rec.info, "information value"))
    text = ", ".join(parts[:-1]) + " and " + parts[-1]
    return f"{tag} expects {text} ({rec.nfields} fields)"


def _upper_to_symmetric(values: np.ndarray, n: int) -> np.ndarray:
    """Row-major upper triangle, shape (n(n+1)/2,) → symmetric (n, n)."""
    M = np.zeros((n, n))
    M[np.triu_indices(n)] = values
    return M + np.triu(M, 1).T


@dataclass
class G2oSummary:
    """What :func:`check_g2o` learned about a file.

    ``vertices``: id → line number; ``edges``: list of (id1, id2, line number);
    ``is3d``: SE(3) file; ``has_comments``: lines GTSAM's reader mishandles;
    ``group``: the GTSAM type of the poses (Pose2, Pose3 or Similarity3).
    """

    path: str
    is3d: bool
    vertices: dict[int, int]
    edges: list[tuple[int, int, int]]
    has_comments: bool = False
    group: str = ""

    def __post_init__(self):
        if not self.group:
            self.group = "Pose3" if self.is3d else "Pose2"

    @property
    def pose_ids(self) -> list[int]:
        ids = set(self.vertices)
        for i, j, _ in self.edges:
            ids.add(i)
            ids.add(j)
        return sorted(ids)


def check_g2o(path: str) -> G2oSummary:
    """Validate a g2o file line by line; raise :class:`PoseGraphError` on the first problem.

    Checks: known tag, field count, integer ids, numeric and finite values,
    one dimension (2-D or 3-D) and one pose type per file, unit quaternions,
    Sim(3) log-scales whose exponential is a finite non-zero number, positive-definite
    information, no duplicate vertex, no self-loop, edges only between known
    vertices (when the file has vertices), at least one edge, and a connected
    graph (a second component would have no prior: its gauge is free and the
    linear system singular).
    """
    name = os.path.basename(path)
    try:
        with open(path, "r", encoding="utf-8", errors="replace") as fh:
            lines = fh.read().splitlines()
    except OSError as exc:
        raise PoseGraphError(f"{path}: cannot read ({exc.strerror})") from None

    dim = None
    dim_line = 0
    vertices: dict[int, int] = {}
    edges: list[tuple[int, int, int]] = []
    has_comments = False
    for lineno, line in enumerate(lines, start=1):
        tokens = line.split()
        if not tokens:
            continue
        if tokens[0].startswith("#"):
            has_comments = True
            continue
        tag, fields = tokens[0], tokens[1:]
        where = f"{name}:{lineno}"
        rec = _RECORDS.get(tag)
        if rec is None:
            known = ", ".join(_RECORDS)
            raise PoseGraphError(f"{where}: unknown tag {tag!r} (expected one of {known})")
        if dim is None:
            dim, dim_line, group = rec.dim, lineno, rec.group_name
        elif rec.dim != dim:
            raise PoseGraphError(
                f"{where}: {tag} is a {rec.dim}-D record but line {dim_line} made this a "
                f"{dim}-D file"
            )
        elif rec.group_name != group:
            raise PoseGraphError(
                f"{where}: {tag} is a {rec.group_name} record but line {dim_line} made this a "
                f"{group} file"
            )
        if len(fields) != rec.nfields:
            raise PoseGraphError(f"{where}: {_expects(tag, rec)}, got {len(fields)} fields")
        ids = []
        for k in range(rec.ids):
            try:
                ids.append(int(fields[k]))
            except ValueError:
                raise PoseGraphError(
                    f"{where}: field {k + 2} ({fields[k]!r}) should be an integer id"
                ) from None
            if ids[-1] < 0:
                raise PoseGraphError(f"{where}: field {k + 2}: negative id {ids[-1]}")
        values = np.empty(rec.nfields - rec.ids)
        for k, tok in enumerate(fields[rec.ids:]):
            try:
                values[k] = float(tok)
            except ValueError:
                raise PoseGraphError(
                    f"{where}: field {rec.ids + k + 2} ({tok!r}) is not a number"
                ) from None
            if not math.isfinite(values[k]):
                raise PoseGraphError(f"{where}: field {rec.ids + k + 2} ({tok!r}) is not finite")
        pose = values[: rec.pose]
        if rec.group == "Similarity3" and not abs(pose[6]) < SIM3_MAX_LOG_SCALE:
            raise PoseGraphError(
                f"{where}: log-scale λ = {pose[6]:.6g} is out of range (|λ| < {SIM3_MAX_LOG_SCALE:g}, "
                f"the scale e^λ must be a finite, non-zero double)"
            )
        if tag.endswith(":QUAT"):
            qnorm = float(np.linalg.norm(pose[3:7]))
            if abs(qnorm - 1.0) > QUAT_NORM_TOL:
                raise PoseGraphError(
                    f"{where}: quaternion qx qy qz qw has norm {qnorm:.6g}, expected 1"
                )
        if rec.kind == "vertex":
            (vid,) = ids
            if vid in vertices:
                raise PoseGraphError(
                    f"{where}: vertex {vid} already defined on line {vertices[vid]}"
                )
            vertices[vid] = lineno
            continue
        i, j = ids
        if i == j:
            raise PoseGraphError(f"{where}: edge connects vertex {i} to itself")
        info = _upper_to_symmetric(values[rec.pose:], rec.tangent_dim)
        eig_min = float(np.linalg.eigvalsh(info)[0])
        # Relative threshold: a PSD-but-singular matrix printed with rounding
        # can show −1e-17; that is still not usable as a noise model.
        if not eig_min > 1e-12 * max(1.0, float(np.max(np.abs(info)))):
            raise PoseGraphError(
                f"{where}: information matrix is not positive definite "
                f"(smallest eigenvalue {eig_min:.3g})"
            )
        edges.append((i, j, lineno))

    if dim is None:
        raise PoseGraphError(f"{name}: empty graph (no vertices and no edges)")
    if not edges:
        raise PoseGraphError(f"{name}: empty graph (no edges, nothing to optimize)")
    if vertices:
        for i, j, lineno in edges:
            for v in (i, j):
                if v not in vertices:
                    raise PoseGraphError(f"{name}:{lineno}: edge {i}-{j} refers to unknown vertex {v}")
    summary = G2oSummary(path, dim == 3, vertices, edges, has_comments, group)
    _check_connected(summary, name)
    return summary


def _adjacency(pairs) -> dict[int, list[int]]:
    adj: dict[int, list[int]] = {}
    for i, j in pairs:
        adj.setdefault(i, []).append(j)
        adj.setdefault(j, []).append(i)
    return adj


def _check_connected(summary: G2oSummary, name: str) -> None:
    ids = summary.pose_ids
    adj = _adjacency((i, j) for i, j, _ in summary.edges)
    seen = {ids[0]}
    queue = deque([ids[0]])
    while queue:
        for nb in adj.get(queue.popleft(), ()):
            if nb not in seen:
                seen.add(nb)
                queue.append(nb)
    if len(seen) != len(ids):
        lost = next(v for v in ids if v not in seen)
        raise PoseGraphError(
            f"{name}: graph is not connected: pose {lost} cannot be reached from pose {ids[0]} "
            f"({len(ids) - len(seen)} of {len(ids)} poses unreachable; only pose {ids[0]} gets a prior)"
        )


def read_g2o(path: str, summary: G2oSummary):
    """``gtsam.readG2o`` on a file :func:`check_g2o` accepted: (graph, initial).

    Sim(3) files are read by :func:`read_sim3_g2o` (GTSAM has no reader for them).
    """
    if summary.group == "Similarity3":
        return read_sim3_g2o(path)
    if not summary.has_comments:
        return gtsam.readG2o(path, summary.is3d)
    # GTSAM's reader stops reading edges after a comment line; give it a copy without them.
    fd, tmp = tempfile.mkstemp(suffix=".g2o")
    try:
        with os.fdopen(fd, "w") as out, open(path, encoding="utf-8", errors="replace") as src:
            for line in src:
                if not line.lstrip().startswith("#"):
                    out.write(line)
        return gtsam.readG2o(tmp, summary.is3d)
    finally:
        os.unlink(tmp)


def write_g2o(path: str, between: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
    """``gtsam.writeG2o`` via a temporary file (Sim(3) graphs: :func:`write_sim3_g2o`).

    ``between`` must be the native graph: writeG2o only recognises GTSAM's own
    BetweenFactor classes, so custom factors would silently lose the edges.
    """
    if _is_sim3_graph(between):
        write_sim3_g2o(path, between, values)
        return
    replace_atomically(path, lambda tmp: gtsam.writeG2o(between, values, tmp), suffix=".g2o")


# --------------------------------------------------------------------------- #
# Sim(3) records (the conversion is derived in the module docstring)
# --------------------------------------------------------------------------- #

def similarity3_from_g2o(v) -> gtsam.Similarity3:
    """The GTSAM element of a g2o Sim(3) record's 7 numbers [ω, υ, σ]: ``Expmap`` of them.

    Shapes: ``v`` (7,).  Exact (``lie_factors.sim3.exp``).
    """
    from . import sim3

    return gtsam.Similarity3(sim3.exp(np.asarray(v, dtype=np.float64)))


def similarity3_to_g2o(X: gtsam.Similarity3) -> np.ndarray:
    """The 7 numbers g2o writes for GTSAM element ``X``: its ``Logmap`` [ω, u, λ], shape (7,)."""
    from . import sim3

    return sim3.log(np.asarray(X.matrix(), dtype=np.float64))


def _is_sim3_graph(graph: gtsam.NonlinearFactorGraph) -> bool:
    return graph.size() > 0 and isinstance(graph.at(0), gtsam.BetweenFactorSimilarity3)


def read_sim3_g2o(path: str):
    """(graph of ``gtsam.BetweenFactorSimilarity3``, Values of ``gtsam.Similarity3``) of a Sim(3) file.

    The file must have passed :func:`check_g2o` (every line is a known Sim(3)
    record with the right number of finite fields).  Noise models are
    ``Gaussian.Information`` of the file's 7×7 information matrices.
    """
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            tokens = line.split()
            if not tokens or tokens[0].startswith("#"):
                continue
            rec = _RECORDS[tokens[0]]
            nums = np.array(tokens[1 + rec.ids:], dtype=np.float64)
            if rec.kind == "vertex":
                initial.insert(int(tokens[1]), similarity3_from_g2o(nums[: rec.pose]))
            else:
                info = _upper_to_symmetric(nums[rec.pose:], rec.tangent_dim)
                graph.add(gtsam.BetweenFactorSimilarity3(
                    int(tokens[1]), int(tokens[2]), similarity3_from_g2o(nums[: rec.pose]),
                    gtsam.noiseModel.Gaussian.Information(info)))
    return graph, initial


def _numbers(values) -> str:
    # repr: the shortest text that reads back as the same double
    return " ".join(repr(float(v)) for v in values)


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
