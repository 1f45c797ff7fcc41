"""g2o files: find, check, read and write them (the formats have one home here).

* :func:`resolve_dataset` — a path, or the name of a file shipped with GTSAM.
* :func:`check_g2o` — our own check of every line, so a bad file gives
  ``file:line: what was expected`` instead of GTSAM silently skipping lines or
  reading garbage; vectorized (lines grouped by tag, numbers parsed by numpy).
* :func:`read_g2o` — ``gtsam.readG2o`` on a checked file, plus the records
  GTSAM's reader skips (``LANDMARK2``) as GTSAM-native factors.
* :func:`write_g2o` — ``gtsam.writeG2o`` (+ the 2-D landmark measurements it
  drops), atomically.

The records are the table :data:`RECORDS`: one :class:`Record` per tag, naming
its integer and real fields and the vectorized check of its rows.  A new record
type is one entry there (plus, if GTSAM's reader does not build its factor, a
branch in :func:`read_g2o`).

What GTSAM 4.3's ``readG2o`` accepts (its ``dataset.cpp``, checked against the
wheel): in 2-D (``load2D``) ``VERTEX_SE2``/``VERTEX2``/``VERTEX``,
``VERTEX_XY``, ``EDGE_SE2``/``EDGE2``/``EDGE``/``ODOMETRY``, ``BR`` and
``LANDMARK``; in 3-D (``load3D``) ``VERTEX3``, ``VERTEX_SE3:QUAT``,
``VERTEX_TRACKXYZ``, ``EDGE3``, ``EDGE_SE3:QUAT``, ``EDGE_SE3_TRACKXYZ`` and
``PARAMS_SE3OFFSET``.  Every other tag is skipped without a word; we refuse it
(a skipped line is a lost measurement), except ``LANDMARK2`` (pose id,
landmark id, x y in the pose frame, 2×2 information — the SE-Sync landmark
format of the shipped ``cityTrees``/``victoriaPark`` files), which we read
ourselves.

Conventions that are GTSAM's, never touched by us: g2o writes SE(3)
information as [t, R]; ``readG2o`` permutes ``EDGE_SE3:QUAT`` information to
GTSAM's [ω, v] (a file diag(100·I₃, 25·I₃) yields diag(25·I₃, 100·I₃));
``EDGE3`` information is taken as is.  Landmark ``j`` is the key
``gtsam.symbol('l', j)``, pose ``i`` the key ``i``.  Cartesian landmark
measurements become ``BearingRangeFactor`` s with the information mapped
exactly to first order, Λ_br = Jᵀ Λ_xyz J with J = [r·B, u] (B the bearing's
tangent basis, u = p/r) — what ``readG2o`` does for ``EDGE_SE3_TRACKXYZ``
(checked to 1e-13 on random information matrices), and what we do for
``LANDMARK2`` in 2-D (B = (−u_y, u_x)).

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
import re
import tempfile
from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np

import gtsam

from ..atomic import replace_atomically
from ..errors import PoseGraphError
from ..pose_graph import PoseGraph
from ..topology import components


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
        except (RuntimeError, OSError, ValueError):  # the wrapper raises FileNotFoundError
            pass
        raise PoseGraphError(
            f"{name}: no such file, and not a dataset shipped with GTSAM "
            f"(gtsam.findExampleDataFile)"
        )
    raise PoseGraphError(f"{name}: no such file")


# --------------------------------------------------------------------------- #
# The record table
# --------------------------------------------------------------------------- #

@dataclass
class Rows:
    """All lines of one tag: ``ids`` (n, k) int64, ``values`` (n, m) float64, ``lines`` (n,) 1-based."""

    tag: str
    ids: np.ndarray
    values: np.ndarray
    lines: np.ndarray
    fragile: np.ndarray | None = None  # rows GTSAM's 2-D second pass would stop at

    def __len__(self) -> int:
        return len(self.lines)


#: A row check gets the rows of one tag and yields (row index, message) for bad rows
#: (the first bad row of each kind of problem is enough).
RowCheck = Callable[[Rows], Iterator[tuple[int, str]]]


@dataclass(frozen=True)
class Record:
    """One g2o record type.

    ``kind``: ``pose`` / ``landmark`` (vertices), ``between`` (pose–pose
    edge), ``observation`` (pose → landmark), ``param``.  ``ids``/``values``
    name the integer and real fields in file order; ``info`` says how many of
    the values are a row-major upper-triangular information matrix.
    ``gtsam`` is False for records ``gtsam.readG2o`` skips (we build their
    factors); ``checks`` run on all rows of the tag at once.
    """

    tag: str
    dim: int
    kind: str
    ids: tuple[str, ...]
    values: tuple[str, ...]
    info: int = 0
    gtsam: bool = True
    checks: tuple[RowCheck, ...] = ()
    note: str = ""
    group: str = ""  # GTSAM pose type when the dimension alone does not say it

    @property
    def group_name(self) -> str:
        return self.group or ("Pose3" if self.dim == 3 else "Pose2")

    @property
    def nfields(self) -> int:
        return len(self.ids) + len(self.values) + self.info

    @property
    def field_text(self) -> str:
        text = " ".join(self.ids + self.values)
        if self.info:
            n = int(round((math.sqrt(8 * self.info + 1) - 1) / 2))
            text += f" + {self.info} information ({n}×{n} upper triangle)"
        return text


def _first(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def _upper_to_symmetric(values: np.ndarray, n: int) -> np.ndarray:
    """Row-major upper triangles, shape (..., n(n+1)/2) → symmetric (..., n, n)."""
    values = np.asarray(values, dtype=float)
    M = np.zeros(values.shape[:-1] + (n, n))
    iu = np.triu_indices(n)
    M[..., iu[0], iu[1]] = values
    M[..., iu[1], iu[0]] = values
    return M


#: Relative eigenvalue floor for an information matrix: below it the matrix is
#: singular to working precision and its square root (the whitening) meaningless.
INFO_REL_EIG = 1e-12


def _check_info(first: int, n: int, what: str = "information matrix") -> RowCheck:
    """Information values[first : first + n(n+1)/2] must be positive definite."""
    m = n * (n + 1) // 2

    def check(rows: Rows):
        M = _upper_to_symmetric(rows.values[:, first:first + m], n)
        eig_min = np.linalg.eigvalsh(M)[:, 0]
        scale = np.abs(M).reshape(len(M), -1).max(axis=1)
        bad = _first(~(eig_min > INFO_REL_EIG * scale))
        if bad is not None:
            yield bad, (f"{what} is not positive definite "
                        f"(smallest eigenvalue {eig_min[bad]:.3g})")

    return check


#: float64 x²+y²+z²+w² of a usable quaternion: GTSAM divides by its square root
#: (a subnormal or overflowing sum gives NaN or a zero rotation).
_QN2_MIN = float(np.finfo(float).tiny)


def _check_quaternion(first: int) -> RowCheck:
    def check(rows: Rows):
        q = rows.values[:, first:first + 4]
        n2 = np.einsum("ij,ij->i", q, q)
        bad = _first(~((n2 >= _QN2_MIN) & np.isfinite(n2)))
        if bad is not None:
            yield bad, (f"quaternion qx qy qz qw has norm {math.sqrt(n2[bad]):.3g}: GTSAM "
                        f"divides by it, which gives NaN or garbage (any other norm is normalized)")

    return check


def _check_range(first: int, k: int) -> RowCheck:
    """A Cartesian landmark measurement must have a positive finite range (GTSAM's rule for 3-D)."""
    def check(rows: Rows):
        p = rows.values[:, first:first + k]
        r2 = np.einsum("ij,ij->i", p, p)  # naive, as GTSAM computes it
        bad = _first(~((r2 > 0) & np.isfinite(r2)))
        if bad is not None:
            yield bad, ("landmark measurement has zero (or overflowing) range: "
                        "its bearing is undefined")

    return check


def _check_br(rows: Rows):
    v = rows.values
    bad = _first(~(v[:, 1] > 0))
    if bad is not None:
        yield bad, f"range {v[bad, 1]:.6g} is not positive"
    bad = _first(~((v[:, 2] > 0) & (v[:, 3] > 0)))
    if bad is not None:
        yield bad, (f"standard deviations ({v[bad, 2]:.6g}, {v[bad, 3]:.6g}) must be positive")


#: GTSAM's LANDMARK rule (dataset.cpp): |v1 − v3| < 1e-4 → σ_bearing = √(v1/10),
#: σ_range = √v1; otherwise it silently uses σ = (1, 1).
LANDMARK_ISO_TOL = 1e-4


def _check_landmark_cov(rows: Rows):
    v1, v3 = rows.values[:, 2], rows.values[:, 4]
    bad = _first(~(np.abs(v1 - v3) < LANDMARK_ISO_TOL))
    if bad is not None:
        yield bad, (f"LANDMARK covariance v1 = {v1[bad]:.6g}, v3 = {v3[bad]:.6g} is not isotropic: "
                    f"GTSAM's reader would ignore it and use unit standard deviations")
    bad = _first(~(v1 > 0))
    if bad is not None:
        yield bad, f"LANDMARK variance v1 = {v1[bad]:.6g} must be positive"


_QUAT = ("qx", "qy", "qz", "qw")

RECORDS: dict[str, Record] = {}


def register(record: Record) -> Record:
    """Add ``record`` to :data:`RECORDS` (one entry per tag)."""
    RECORDS[record.tag] = record
    return record


for _tag in ("VERTEX_SE2", "VERTEX2", "VERTEX"):
    register(Record(_tag, 2, "pose", ("id",), ("x", "y", "θ")))
register(Record("VERTEX_XY", 2, "landmark", ("id",), ("x", "y")))
def _check_info_se2(rows: Rows):
    """g2o-ordered 3×3 information; say so when the row reads as TORO-ordered instead."""
    for bad, msg in _check_info(3, 3)(rows):
        v = rows.values[bad, 3:9]
        # TORO: inf_ff inf_fs inf_ss inf_rr inf_fr inf_sr
        toro = np.array([[v[0], v[1], v[4]], [v[1], v[2], v[5]], [v[4], v[5], v[3]]])
        if np.linalg.eigvalsh(toro)[0] > 0:
            msg += (" in g2o order (I11 I12 I13 I22 I23 I33); it is positive definite in TORO order "
                    "(ff fs ss rr fr sr), which gtsam.readG2o does not read either")
        yield bad, msg


for _tag in ("EDGE_SE2", "EDGE2", "EDGE", "ODOMETRY"):
    register(Record(_tag, 2, "between", ("id1", "id2"), ("x", "y", "θ"), info=6,
                    checks=(_check_info_se2,)))
register(Record("BR", 2, "observation", ("pose", "landmark"),
                ("bearing", "range", "σ_bearing", "σ_range"), checks=(_check_br,)))
register(Record("LANDMARK", 2, "observation", ("pose", "landmark"), ("x", "y", "v1", "v2", "v3"),
                checks=(_check_range(0, 2), _check_landmark_cov),
                note="GTSAM: bearing-range with σ_bearing = √(v1/10), σ_range = √v1"))
register(Record("LANDMARK2", 2, "observation", ("pose", "landmark"), ("x", "y"), info=3,
                gtsam=False, checks=(_check_range(0, 2), _check_info(2, 2)),
                note="read by lie_factors (gtsam.readG2o skips it)"))
register(Record("VERTEX3", 3, "pose", ("id",), ("x", "y", "z", "roll", "pitch", "yaw")))
register(Record("VERTEX_SE3:QUAT", 3, "pose", ("id",), ("x", "y", "z") + _QUAT,
                checks=(_check_quaternion(3),)))
register(Record("VERTEX_TRACKXYZ", 3, "landmark", ("id",), ("x", "y", "z")))
register(Record("EDGE3", 3, "between", ("id1", "id2"), ("x", "y", "z", "roll", "pitch", "yaw"),
                info=21, checks=(_check_info(6, 6),)))
register(Record("EDGE_SE3:QUAT", 3, "between", ("id1", "id2"), ("x", "y", "z") + _QUAT, info=21,
                checks=(_check_quaternion(3), _check_info(7, 6))))
register(Record("EDGE_SE3_TRACKXYZ", 3, "observation", ("pose", "landmark", "offset"),
                ("x", "y", "z"), info=6, checks=(_check_range(0, 3), _check_info(3, 3))))
register(Record("PARAMS_SE3OFFSET", 3, "param", ("id",), ("x", "y", "z") + _QUAT,
                checks=(_check_quaternion(3),)))

#: Largest accepted |λ| of a Sim(3) record: e^±700 is still a normal double.
SIM3_MAX_LOG_SCALE = 700.0


def _check_log_scale(rows: Rows):
    lam = rows.values[:, 6]
    bad = _first(~(np.abs(lam) < SIM3_MAX_LOG_SCALE))
    if bad is not None:
        yield bad, (f"log-scale λ = {lam[bad]:.6g} is out of range (|λ| < {SIM3_MAX_LOG_SCALE:g}, "
                    f"the scale e^λ must be a finite, non-zero double)")


_SIM3 = ("ω1", "ω2", "ω3", "υ1", "υ2", "υ3", "σ")
register(Record("VERTEX_SIM3:EXPMAP", 3, "pose", ("id",), _SIM3 + ("fx", "fy", "cx", "cy"),
                gtsam=False, group="Similarity3", checks=(_check_log_scale,),
                note="read by lie_factors; the camera values are checked and dropped"))
register(Record("EDGE_SIM3:EXPMAP", 3, "between", ("id1", "id2"), _SIM3, info=28, gtsam=False,
                group="Similarity3", checks=(_check_log_scale, _check_info(7, 7)),
                note="read by lie_factors"))
SIM3_TAGS = ("VERTEX_SIM3:EXPMAP", "EDGE_SIM3:EXPMAP")
del _tag

#: Ids are GTSAM keys; a landmark key packs the character 'l' into the top 8
#: bits (gtsam.symbol), so larger ids cannot be landmarks and, as poses, could
#: collide with landmark keys.
MAX_ID = 2**56 - 1

#: Rows of one tag; vertex maps id → line.
@dataclass
class G2oSummary:
    """What :func:`check_g2o` learned about a file (all records parsed, all checks passed).

    ``rows``: tag → :class:`Rows`; ``is3d``: which of GTSAM's readers the file
    is for; ``comment_lines``: lines starting with ``#``; ``fragile_lines``:
    2-D lines whose 2nd/3rd field GTSAM's second pass cannot read as an
    integer (it stops reading there, see :func:`read_g2o`).
    """

    path: str
    is3d: bool
    rows: dict[str, Rows]
    comment_lines: list[int] = field(default_factory=list)
    fragile_lines: list[int] = field(default_factory=list)

    def _of_kind(self, kind: str, gtsam_only: bool = False) -> list[Rows]:
        return [r for tag, r in self.rows.items()
                if RECORDS[tag].kind == kind and (RECORDS[tag].gtsam or not gtsam_only)]

    def _ids(self, kind: str, col: int = 0) -> np.ndarray:
        parts = [r.ids[:, col] for r in self._of_kind(kind)]
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)

    @property
    def has_comments(self) -> bool:
        return bool(self.comment_lines)

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
        for r in self._of_kind("pose"):
            out.update(zip(r.ids[:, 0].tolist(), r.lines.tolist()))
        return out

    @property
    def edges(self) -> list[tuple[int, int, int]]:
        """Pose–pose edges (id1, id2, line), in tag order."""
        out = []
        for r in self._of_kind("between"):
            out.extend(zip(r.ids[:, 0].tolist(), r.ids[:, 1].tolist(), r.lines.tolist()))
        return out

    @property
    def between_count(self) -> int:
        return sum(len(r) for r in self._of_kind("between"))

    @property
    def observation_count(self) -> int:
        return sum(len(r) for r in self._of_kind("observation"))

    @property
    def gtsam_factor_count(self) -> int:
        """Factors ``gtsam.readG2o`` builds from this file."""
        return self.between_count + sum(len(r) for r in self._of_kind("observation", True))

    @property
    def pose_ids(self) -> list[int]:
        """Every pose id: vertices, pose–pose edges, observing poses (sorted)."""
        parts = [self.pose_vertex_ids]
        for r in self._of_kind("between"):
            parts.append(r.ids[:, :2].ravel())
        for r in self._of_kind("observation"):
            parts.append(r.ids[:, 0])
        return np.unique(np.concatenate(parts)).tolist()

    @property
    def landmark_ids(self) -> list[int]:
        parts = [self.landmark_vertex_ids] + [r.ids[:, 1] for r in self._of_kind("observation")]
        return np.unique(np.concatenate(parts)).tolist()


# --------------------------------------------------------------------------- #
# Checking
# --------------------------------------------------------------------------- #

_NUMBER_CHARS = b"0123456789+-.eE"
_WHITESPACE = b" \t\r\v\f\n"
_INT_RE = re.compile(rb"[+-]?[0-9]+\Z")
# What C++ `is >> double` reads as one whole token (no inf/nan/hex, no '_').
_FLOAT_RE = re.compile(rb"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z")
# GTSAM's 2-D second pass reads the 2nd and 3rd field of every line as size_t.
_SIZE_T_PREFIX = re.compile(rb"[+-]?([0-9]+)")


def _size_t_readable(tok: bytes) -> bool:
    """Does C++ `is >> size_t` succeed on this token (a digit prefix that fits 64 bits)?"""
    m = _SIZE_T_PREFIX.match(tok)
    return m is not None and int(m.group(1)) <= 2**64 - 1


def _show(token: bytes, limit: int = 40) -> str:
    text = token.decode("ascii", "backslashreplace")
    return repr(text if len(text) <= limit else text[:limit] + "...")


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def _expects(rec: Record) -> str:
    return f"{rec.tag} expects {rec.nfields} fields ({rec.field_text})"


def _read_bytes(path: str) -> bytes:
    try:
        with open(path, "rb") as fh:
            return fh.read()
    except IsADirectoryError:
        raise PoseGraphError(f"{path}: is a directory, expected a g2o file") from None
    except OSError as exc:
        raise PoseGraphError(f"{path}: cannot read ({exc.strerror or exc})") from None


def _family(rec: Record) -> tuple[int, str]:
    """Records that may share a file: same dimension and pose type."""
    return rec.dim, rec.group_name


class _LineError(PoseGraphError):
    """A malformed line; ``lineno`` lets the earliest of several be reported."""

    def __init__(self, lineno: int, message: str):
        super().__init__(message)
        self.lineno = lineno


def _parse_line(name: str, lineno: int, tokens: list[bytes], dim_of: list):
    """Check one line the slow, exact way: (record, ids, values), or raise the precise error.

    ``dim_of`` is a one-element list holding (dim, line) of the first record.
    """
    where = f"{name}:{lineno}"
    tag = tokens[0]
    rec = RECORDS.get(tag.decode("ascii")) if tag.isascii() else None
    if rec is None:
        known = ", ".join(RECORDS)
        raise _LineError(lineno, f"{where}: unknown tag {_show(tag)} "
                             f"(gtsam.readG2o would skip the line; expected one of {known})")
    if dim_of[0] is None:
        dim_of[0] = (rec, lineno)
    elif _family(rec) != _family(dim_of[0][0]):
        first_rec, first = dim_of[0]
        if rec.dim != first_rec.dim:
            raise _LineError(lineno, f"{where}: {rec.tag} is a {rec.dim}-D record but line {first} made "
                                     f"this a {first_rec.dim}-D file (gtsam.readG2o reads one or the other)")
        raise _LineError(lineno, f"{where}: {rec.tag} is a {rec.group_name} record but line {first} "
                                 f"made this a {first_rec.group_name} file")
    fields = tokens[1:]
    if len(fields) != rec.nfields:
        raise _LineError(lineno, f"{where}: {_expects(rec)}, got {len(fields)}")
    nids = len(rec.ids)
    ids = []
    for k, tok in enumerate(fields[:nids]):
        if not _INT_RE.match(tok):
            raise _LineError(lineno, f"{where}: field {k + 2} ({_show(tok)}) should be an integer id")
        value = int(tok)
        if value < 0:
            raise _LineError(lineno, f"{where}: field {k + 2}: negative id {value}")
        if value > MAX_ID:
            raise _LineError(lineno, f"{where}: field {k + 2}: id {value} is larger than 2^56 - 1 "
                                 f"(GTSAM landmark keys keep 56 bits for the id)")
        ids.append(value)
    values = []
    for k, tok in enumerate(fields[nids:], start=nids):
        value = _as_float(tok)
        if value is None:
            raise _LineError(lineno, f"{where}: field {k + 2} ({_show(tok)}) is not a number")
        if not math.isfinite(value):
            raise _LineError(lineno, f"{where}: field {k + 2} ({_show(tok)}) is not finite")
        values.append(value)
    return rec, ids, values


def _as_float(tok: bytes) -> float | None:
    """The number C++ reads from the whole token, ±inf/nan for those words, else None."""
    if _FLOAT_RE.match(tok):
        return float(tok)
    if tok.isascii() and tok.lower().lstrip(b"+-") in (b"inf", b"infinity", b"nan"):
        return float(tok)
    return None


def _slow_parse(name: str, data: bytes) -> tuple[dict[str, Rows], list[int], list[int]]:
    """Reference parse, line by line in file order: (rows, comment lines, fragile 2-D lines).

    Raises at the first malformed line.  The fast path below must agree with it
    on every file it accepts (tests/test_g2o_fuzz.py checks that).
    """
    dim_of = [None]
    acc: dict[str, tuple[Record, list, list, list]] = {}
    comments, fragile = [], []
    for lineno, line in enumerate(data.split(b"\n"), start=1):
        tokens = line.split()
        if not tokens:
            continue
        if tokens[0][:1] == b"#":
            comments.append(lineno)
            continue
        rec, ids, values = _parse_line(name, lineno, tokens, dim_of)
        if rec.tag not in acc:
            acc[rec.tag] = (rec, [], [], [])
        _, a_ids, a_values, a_lines = acc[rec.tag]
        a_ids.append(ids)
        a_values.append(values)
        a_lines.append(lineno)
        if _may_stop_gtsam(rec) and not all(_size_t_readable(t) for t in tokens[1:3]):
            fragile.append(lineno)
    rows = {tag: Rows(tag, np.array(i, dtype=np.int64).reshape(len(ln), len(rec.ids)),
                      np.array(v, dtype=np.float64).reshape(len(ln), len(rec.values) + rec.info),
                      np.array(ln, dtype=np.int64))
            for tag, (rec, i, v, ln) in acc.items()}
    return rows, comments, fragile


def _may_stop_gtsam(rec: Record) -> bool:
    """Is this a 2-D line whose fields GTSAM's second pass reads as ``id1 id2`` (see read_g2o)?"""
    return rec.dim == 2 and not (rec.gtsam and rec.kind in ("between", "observation"))


_WS_CODES = np.frombuffer(_WHITESPACE, dtype=np.uint8)


def _tag_width() -> int:
    return max(len(t) for t in RECORDS) + 1


def _fast_groups(data: bytes):
    """Lines grouped by tag without a Python loop over lines, or None to use the slow path.

    Returns (tag → line indices (0-based, sorted), line starts, line ends,
    comment line indices).  Tags are told apart by the first W bytes of each
    line, cut at the first whitespace; a line starting with whitespace makes
    us give up (the slow path handles it).
    """
    buf = np.frombuffer(data, dtype=np.uint8)
    nl = np.flatnonzero(buf == 10)
    starts = np.concatenate(([0], nl + 1))
    ends = np.concatenate((nl, [len(buf)]))
    used = np.flatnonzero(ends > starts)
    if used.size == 0:
        return {}, starts, ends, np.zeros(0, dtype=np.int64)
    W = _tag_width()
    padded = np.concatenate((buf, np.zeros(W, dtype=np.uint8)))
    idx = starts[used, None] + np.arange(W)
    win = padded[idx]
    if np.isin(win[:, 0], _WS_CODES).any():
        return None
    win[idx >= ends[used, None]] = 32
    cut = np.cumsum(np.isin(win, _WS_CODES), axis=1) > 0
    win[cut] = 0
    codes, inverse = np.unique(np.ascontiguousarray(win).view(f"S{W}").ravel(), return_inverse=True)
    inverse = inverse.ravel()
    order = np.argsort(inverse, kind="stable")
    bounds = np.concatenate(([0], np.cumsum(np.bincount(inverse, minlength=len(codes)))))
    groups, comments = {}, []
    for c, code in enumerate(codes.tolist()):
        lines = used[order[bounds[c]:bounds[c + 1]]]
        if code[:1] == b"#":
            comments.append(lines)
        else:
            groups[code] = lines
    comments = np.sort(np.concatenate(comments)) if comments else np.zeros(0, dtype=np.int64)
    return groups, starts, ends, comments


def _parse_group(rec: Record, data: bytes, lines: np.ndarray, starts, ends) -> Rows | None:
    """All lines of one tag (0-based indices) → Rows, or None if anything looks off."""
    n = len(lines)
    breaks = np.flatnonzero(np.diff(lines) != 1)
    run_first = np.concatenate(([0], breaks + 1))
    run_last = np.concatenate((breaks, [n - 1]))
    blob = b"\n".join([data[starts[lines[f]]:ends[lines[l]]]
                       for f, l in zip(run_first.tolist(), run_last.tolist())])
    nf = rec.nfields + 1
    tokens = blob.split()
    if len(tokens) != n * nf:
        return None
    table = np.array(tokens, dtype="S").reshape(n, nf)[:, 1:]
    if np.ascontiguousarray(table).tobytes().translate(None, _NUMBER_CHARS + b"\0"):
        return None
    nids = len(rec.ids)
    if not np.char.isdigit(table[:, :nids]).all():
        return None  # '+5', '1.0', '-3', ... : the slow path says which are ids
    try:
        # Restricted to [0-9+-.eE], float conversion of whole tokens accepts what
        # C++ `>>` reads as one number (forms like '1e' or '1.2.3' fail here).
        values = table[:, nids:].astype(np.float64)
        ids_f = table[:, :nids].astype(np.float64)
    except ValueError:
        return None
    if not np.isfinite(values).all() or (ids_f > MAX_ID).any():
        return None
    if (ids_f >= 2.0**53).any():  # beyond exact floats: integers from the text
        ids = np.array([[int(t) for t in row] for row in table[:, :nids].tolist()], dtype=np.int64)
    else:
        ids = ids_f.astype(np.int64)
    rows = Rows(rec.tag, ids.reshape(n, nids), np.ascontiguousarray(values), lines + 1)
    if _may_stop_gtsam(rec):
        rows.fragile = _fragile_rows(table[:, :2])
    return rows


def _fragile_rows(first_two: np.ndarray) -> np.ndarray:
    """Rows whose 2nd or 3rd field C++ cannot read as size_t (0-based row indices)."""
    bad = np.zeros(len(first_two), dtype=bool)
    for col in np.ascontiguousarray(first_two).T:
        col = np.ascontiguousarray(col)
        b = np.frombuffer(col.tobytes(), dtype=np.uint8).reshape(len(col), -1)
        c0 = b[:, 0]
        c1 = b[:, 1] if b.shape[1] > 1 else np.zeros_like(c0)
        digit0 = (c0 >= 48) & (c0 <= 57)
        digit1 = (c1 >= 48) & (c1 <= 57)
        sign = (c0 == 43) | (c0 == 45)
        # 20+ characters may hold a digit run that overflows 64 bits: the exact test decides.
        long = np.char.str_len(col) >= 20
        bad |= ~(digit0 | (sign & digit1)) | long
    rows = np.flatnonzero(bad)
    exact = [r for r in rows.tolist() if not all(_size_t_readable(t) for t in first_two[r].tolist())]
    return np.asarray(exact, dtype=np.int64)


def _fast_parse(name: str, data: bytes):
    """Vectorized parse: (rows, comment lines, fragile lines), or None if the slow path must run.

    A tag group that does not parse cleanly is re-parsed line by line (exact);
    unknown tags and a second dimension are located from the groups.  The
    earliest problem line of all is the one reported.
    """
    grouped = _fast_groups(data)
    if grouped is None:
        return None
    groups, starts, ends, comments = grouped
    if not groups:
        return {}, (comments + 1).tolist(), []
    first_line = {tag: int(lines[0]) for tag, lines in groups.items()}
    first_tag = min(first_line, key=first_line.get)
    first_rec = RECORDS.get(first_tag.decode("ascii")) if first_tag.isascii() else None
    problems: list[tuple[int, str]] = []
    rows: dict[str, Rows] = {}
    alien = []  # first lines of unknown tags and of the other dimension's records
    for tag_b, lines in groups.items():
        rec = RECORDS.get(tag_b.decode("ascii")) if tag_b.isascii() else None
        if rec is None or (first_rec is not None and _family(rec) != _family(first_rec)):
            alien.append(int(lines[0]))
            continue
        parsed = _parse_group(rec, data, lines, starts, ends)
        if parsed is None:
            try:
                parsed = _slow_group(name, rec, data, lines, starts, ends)
            except _LineError as exc:
                problems.append((exc.lineno, str(exc)))
                continue
        rows[rec.tag] = parsed
    if alien:  # only the earliest matters (a CSV file has thousands of "tags")
        i = min(alien)
        first = (first_rec, first_line[first_tag] + 1) if first_rec is not None else None
        try:
            _parse_line(name, i + 1, data[starts[i]:ends[i]].split(), [first])
        except _LineError as exc:
            problems.append((exc.lineno, str(exc)))
    if problems:
        raise PoseGraphError(min(problems)[1])
    fragile = []
    for r in rows.values():
        if r.fragile is not None and len(r.fragile):
            fragile.extend(r.lines[r.fragile].tolist())
    return rows, (comments + 1).tolist(), sorted(fragile)


def _slow_group(name: str, rec: Record, data: bytes, lines, starts, ends) -> Rows:
    """Line-by-line parse of one tag's lines (0-based indices); raises at its first bad line."""
    dim_of = [(rec, int(lines[0]) + 1)]
    ids, values, fragile = [], [], []
    for row, i in enumerate(lines.tolist()):
        tokens = data[starts[i]:ends[i]].split()
        _, row_ids, row_values = _parse_line(name, i + 1, tokens, dim_of)
        ids.append(row_ids)
        values.append(row_values)
        if _may_stop_gtsam(rec) and not all(_size_t_readable(t) for t in tokens[1:3]):
            fragile.append(row)
    n = len(lines)
    rows = Rows(rec.tag, np.array(ids, dtype=np.int64).reshape(n, len(rec.ids)),
                np.array(values, dtype=np.float64).reshape(n, len(rec.values) + rec.info),
                lines + 1)
    if _may_stop_gtsam(rec):
        rows.fragile = np.asarray(fragile, dtype=np.int64)
    return rows


def check_g2o(path: str) -> G2oSummary:
    """Validate a g2o file; raise :class:`PoseGraphError` naming the first bad line.

    Per line: known tag (see :data:`RECORDS`), one dimension per file, field
    count, integer ids in [0, 2^56), numbers C++ reads (no inf/nan/hex) and
    finite; per record: normalizable quaternions, positive-definite
    information, positive ranges and standard deviations.  Per file: no
    duplicate vertex, no self-loop, at least one measurement, landmark
    measurements in 3-D refer to existing vertices and an identity
    ``PARAMS_SE3OFFSET`` (GTSAM's rules), and one connected graph (a second
    component would have no prior: its gauge is free and the system singular).

    Parsing is vectorized (lines grouped by tag, all numbers of a tag converted
    by numpy at once); if anything looks off, the exact line-by-line parse
    (:func:`_slow_parse`) runs instead and names the first bad line.
    """
    name = os.path.basename(path)
    data = _read_bytes(path)
    parsed = _fast_parse(name, data)
    if parsed is None:
        parsed = _slow_parse(name, data)
    rows, comments, fragile = parsed
    if not rows:
        raise PoseGraphError(f"{name}: empty graph (no vertices and no edges)")
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
            bad = _first(r.ids[:, 0] == r.ids[:, 1])
            if bad is not None:
                problems.append((int(r.lines[bad]),
                                 f"edge connects vertex {r.ids[bad, 0]} to itself"))
        for check in rec.checks:
            for row, msg in check(r):
                problems.append((int(r.lines[row]), msg))
                break
    if problems:
        lineno, msg = min(problems)
        raise PoseGraphError(f"{name}:{lineno}: {msg}")


def _duplicates(ids: np.ndarray, lines: np.ndarray):
    """First duplicated id (by line of its second definition): (id, first line, second line)."""
    if len(ids) < 2:
        return None
    order = np.lexsort((lines, ids))
    s_ids, s_lines = ids[order], lines[order]
    dup = np.flatnonzero(s_ids[1:] == s_ids[:-1])
    if dup.size == 0:
        return None
    k = dup[np.argmin(s_lines[dup + 1])]
    return int(s_ids[k]), int(s_lines[k]), int(s_lines[k + 1])


def _stack(parts: list[Rows], what) -> tuple[np.ndarray, np.ndarray]:
    if not parts:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return (np.concatenate([what(r) for r in parts]), np.concatenate([r.lines for r in parts]))


def _check_graph(name: str, s: G2oSummary) -> None:
    for kind, label in (("pose", "vertex"), ("landmark", "landmark vertex"), ("param", "PARAMS_SE3OFFSET")):
        ids, lines = _stack(s._of_kind(kind), lambda r: r.ids[:, 0])
        dup = _duplicates(ids, lines)
        if dup is not None:
            vid, first, second = dup
            tail = " (GTSAM would keep the first)" if kind == "param" else ""
            raise PoseGraphError(f"{name}:{second}: {label} {vid} already defined on line {first}{tail}")

    if s.between_count + s.observation_count == 0:
        raise PoseGraphError(f"{name}: empty graph (no edges, nothing to optimize)")

    if s.is3d:
        _check_3d_references(name, s)

    # Pose–pose edges to poses without a vertex: in 2-D GTSAM's reader chains
    # them from the edge; in 3-D it leaves them without a value (refuse).
    pose_vertices = s.pose_vertex_ids
    if s.is3d and len(pose_vertices):
        known = np.isin  # vectorized membership
        for r in s._of_kind("between"):
            for col in (0, 1):
                bad = _first(~known(r.ids[:, col], pose_vertices))
                if bad is not None:
                    i, j = r.ids[bad]
                    raise PoseGraphError(
                        f"{name}:{r.lines[bad]}: edge {i}-{j} refers to pose {r.ids[bad, col]}, "
                        f"which has no vertex (gtsam.readG2o gives it no initial value in 3-D)")
    _check_connected(name, s)


def _check_3d_references(name: str, s: G2oSummary) -> None:
    """GTSAM's EDGE_SE3_TRACKXYZ rules: existing pose and landmark vertices, identity offset."""
    track = s.rows.get("EDGE_SE3_TRACKXYZ")
    if track is None:
        return
    poses, lms = s.pose_vertex_ids, s.landmark_vertex_ids
    bad = _first(~np.isin(track.ids[:, 0], poses) | ~np.isin(track.ids[:, 1], lms))
    if bad is not None:
        p, l = track.ids[bad, :2]
        raise PoseGraphError(f"{name}:{track.lines[bad]}: EDGE_SE3_TRACKXYZ refers to pose {p} and "
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
            raise PoseGraphError(f"{name}:{track.lines[row]}: EDGE_SE3_TRACKXYZ uses sensor offset "
                                 f"{pid}, but no PARAMS_SE3OFFSET {pid} line defines it")
        if not identity[pid]:
            raise PoseGraphError(f"{name}:{track.lines[row]}: EDGE_SE3_TRACKXYZ uses sensor offset "
                                 f"{pid}, which is not the identity (gtsam.readG2o supports only "
                                 f"identity offsets)")


def _check_connected(name: str, s: G2oSummary) -> None:
    poses = np.asarray(s.pose_ids, dtype=np.int64)
    lms = np.asarray(s.landmark_ids, dtype=np.int64)
    P = len(poses)
    us, vs = [], []
    for r in s._of_kind("between"):
        us.append(np.searchsorted(poses, r.ids[:, 0]))
        vs.append(np.searchsorted(poses, r.ids[:, 1]))
    for r in s._of_kind("observation"):
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
        raise PoseGraphError(
            f"{name}: graph is not connected: {what} cannot be reached from pose {poses[0]} "
            f"({lost.size} of {len(labels)} variables unreachable; only pose {poses[0]} gets a prior)")


# --------------------------------------------------------------------------- #
# Reading
# --------------------------------------------------------------------------- #

def landmark_key(j: int) -> int:
    """GTSAM's key of landmark ``j`` (``readG2o`` uses ``symbol('l', j)``)."""
    return gtsam.symbol("l", int(j))


def bearing_range_information_2d(p: np.ndarray, info: np.ndarray) -> np.ndarray:
    """Information of (bearing, range) from that of a 2-D point ``p`` (2,), ``info`` (2, 2).

    Λ_br = Jᵀ Λ J with J = ∂p/∂(θ, r) = [r·(−u_y, u_x), u], u = p/r: the 2-D
    form of what ``readG2o`` does for ``EDGE_SE3_TRACKXYZ``.
    """
    r = float(np.hypot(p[0], p[1]))
    u = np.asarray(p, dtype=float) / r
    J = np.array([[-r * u[1], u[0]], [r * u[0], u[1]]])
    return J.T @ info @ J


def point_information_2d(bearing: float, range_: float, info_br: np.ndarray) -> np.ndarray:
    """Inverse of :func:`bearing_range_information_2d`: Λ_xy = J⁻ᵀ Λ_br J⁻¹."""
    u = np.array([math.cos(bearing), math.sin(bearing)])
    J = np.array([[-range_ * u[1], u[0]], [range_ * u[0], u[1]]])
    Jinv = np.linalg.inv(J)
    return Jinv.T @ info_br @ Jinv


def landmark2_factors(rows: Rows) -> list:
    """``BearingRangeFactor2D`` s for ``LANDMARK2`` rows: pose key, landmark key ``l``."""
    out = []
    for (i, j), v in zip(rows.ids.tolist(), rows.values):
        p = v[:2]
        info = _upper_to_symmetric(v[2:5], 2)
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


def read_g2o(path: str, summary: G2oSummary):
    """Read a checked file: (graph, initial) as ``gtsam.readG2o`` builds them, plus LANDMARK2 factors.

    Verifies that GTSAM read as many factors and vertices as the check found
    (a disagreement is refused rather than half a file optimized).
    """
    if summary.group == "Similarity3":
        return _read_sim3(summary)
    tmp = _gtsam_copy(path, summary)
    try:
        try:
            graph, initial = gtsam.readG2o(tmp or path, summary.is3d)
        except (RuntimeError, ValueError) as exc:
            msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise PoseGraphError(f"{os.path.basename(path)}: gtsam.readG2o refused it: {msg}") from None
    finally:
        if tmp is not None:
            os.unlink(tmp)
    expected = summary.gtsam_factor_count
    if graph.size() != expected:
        raise PoseGraphError(f"{os.path.basename(path)}: gtsam.readG2o read {graph.size()} factors, "
                             f"the file has {expected}")
    for tag, rows in summary.rows.items():
        if not RECORDS[tag].gtsam and tag == "LANDMARK2":
            for f in landmark2_factors(rows):
                graph.add(f)
    return graph, initial


# --------------------------------------------------------------------------- #
# Reading into arrays (no GTSAM objects)
# --------------------------------------------------------------------------- #

#: g2o writes SE(3) information as [t, R]; GTSAM's Pose3 tangent is [ω, v].
_SE3_INFO_ORDER = np.array([3, 4, 5, 0, 1, 2])


def arrays_supported(summary: G2oSummary) -> bool:
    """Can :func:`read_arrays` represent this file?  Pose–pose files whose poses all have a
    vertex, or none has one (landmark records and 2-D files whose edges introduce
    poses GTSAM chains from odometry are read by GTSAM, :func:`read_g2o`)."""
    if any(RECORDS[t].kind not in ("pose", "between") for t in summary.rows):
        return False
    vertices = summary.pose_vertex_ids
    return len(vertices) == 0 or len(vertices) == len(summary.pose_ids)


def _rot2(theta: np.ndarray) -> np.ndarray:
    """Rot2::fromAngle(θ) as (N, 2, 2) matrices."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack((np.stack((c, -s), -1), np.stack((s, c), -1)), -2)


def _rot3_quaternion(q: np.ndarray) -> np.ndarray:
    """Rot3::Quaternion(qw, qx, qy, qz) of rows ``q`` = (qx, qy, qz, qw), shape (N, 3, 3).

    Eigen's ``normalized().toRotationMatrix()``: q / ‖q‖, then the
    products 2x·w, 2x·x, ... (checked against ``readG2o`` in the tests).
    """
    q = q / np.sqrt(np.einsum("ij,ij->i", q, q))[:, None]
    x, y, z, w = q.T
    tx, ty, tz = 2 * x, 2 * y, 2 * z
    twx, twy, twz = tx * w, ty * w, tz * w
    txx, txy, txz = tx * x, ty * x, tz * x
    tyy, tyz, tzz = ty * y, tz * y, tz * z
    R = np.empty((len(q), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 0, 2] = 1 - (tyy + tzz), txy - twz, txz + twy
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = txy + twz, 1 - (txx + tzz), tyz - twx
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = txz - twy, tyz + twx, 1 - (txx + tyy)
    return R


def _rot3_ypr(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Rot3::Ypr(yaw, pitch, roll) = Rz(yaw)·Ry(pitch)·Rx(roll), shape (N, 3, 3)."""
    cx, sx, cy, sy, cz, sz = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))
    R = np.empty((len(yaw), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 0, 2] = cy * cz, sx * sy * cz - cx * sz, cx * sy * cz + sx * sz
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = cy * sz, sx * sy * sz + cx * cz, cx * sy * sz - sx * cz
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = -sy, sx * cy, cx * cy
    return R


def _elements(rows: Rows) -> np.ndarray:
    """The group element of every row of a pose or edge record, shape (N, m, m)."""
    rec = RECORDS[rows.tag]
    v = rows.values
    N = len(v)
    if rec.group_name == "Similarity3":
        from .. import sim3  # Sim(3) records are converted by our exact exp (numba)

        return sim3.exp(np.ascontiguousarray(v[:, :7]))
    if rec.dim == 2:
        X = np.zeros((N, 3, 3))
        X[:, :2, :2] = _rot2(v[:, 2])
        X[:, 0, 2], X[:, 1, 2], X[:, 2, 2] = v[:, 0], v[:, 1], 1.0
        return X
    X = np.zeros((N, 4, 4))
    if "qw" in rec.values:
        X[:, :3, :3] = _rot3_quaternion(v[:, 3:7])
    else:  # VERTEX3 / EDGE3: x y z roll pitch yaw
        X[:, :3, :3] = _rot3_ypr(v[:, 5], v[:, 4], v[:, 3])
    X[:, :3, 3] = v[:, :3]
    X[:, 3, 3] = 1.0
    return X


def _edge_information(rows: Rows) -> np.ndarray:
    """Information matrices of an edge record's rows in GTSAM's tangent order, (N, n, n)."""
    rec = RECORDS[rows.tag]
    n = int(round((math.sqrt(8 * rec.info + 1) - 1) / 2))
    info = _upper_to_symmetric(rows.values[:, len(rec.values):], n)
    if rec.tag == "EDGE_SE3:QUAT":  # readG2o's permutation [t, R] → [ω, v]
        info = info[:, _SE3_INFO_ORDER][:, :, _SE3_INFO_ORDER]
    return info


def read_arrays(summary: G2oSummary) -> PoseGraph:
    """The checked file's poses and edges as :class:`PoseGraph`, with no GTSAM object.

    The same numbers as ``gtsam.readG2o`` (quaternions normalized, SE(3)
    information permuted to [ω, v]; Sim(3) records as :func:`read_g2o`),
    computed per record type on the arrays :func:`check_g2o` parsed.
    Raises ``ValueError`` for files :func:`arrays_supported` refuses.
    """
    if not arrays_supported(summary):
        raise ValueError(f"{summary.path}: landmark records or poses without a vertex line: "
                         "use read_g2o")
    keys = np.asarray(summary.pose_ids, dtype=np.int64)
    edges = summary._of_kind("between")
    lines = np.concatenate([r.lines for r in edges])
    order = np.argsort(lines, kind="stable")  # GTSAM's factor order is the file's line order
    edge_keys = np.concatenate([r.ids[:, :2] for r in edges])[order]
    measured = np.concatenate([_elements(r) for r in edges])[order]
    information = np.concatenate([_edge_information(r) for r in edges])[order]
    vertices = None
    poses = summary._of_kind("pose")
    if poses:
        ids = np.concatenate([r.ids[:, 0] for r in poses])
        X = np.concatenate([_elements(r) for r in poses])
        vertices = X[np.argsort(ids)]  # every pose has exactly one vertex (arrays_supported, check_g2o)
    return PoseGraph(summary.group, keys, np.ascontiguousarray(edge_keys), measured, information,
                           vertices, lines[order])


# --------------------------------------------------------------------------- #
# Writing
# --------------------------------------------------------------------------- #

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
        lines.append(f"LANDMARK2 {gtsam.Symbol(i).index()} {gtsam.Symbol(l).index()} "
                     + " ".join(repr(float(v)) for v in vals))
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
        lines.append(f"{tag} {sym.index()} " + " ".join(repr(float(x)) for x in p))
    return lines


def write_g2o(path: str, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
    """``gtsam.writeG2o`` + the landmark records it drops, via a temporary file.

    GTSAM writes poses, pose–pose edges and 3-D landmark measurements
    (``EDGE_SE3_TRACKXYZ`` with an identity ``PARAMS_SE3OFFSET``); we add
    the landmark vertices and the 2-D landmark measurements as ``LANDMARK2``
    (pose-frame x y + information, exact inverse of how we read them).
    ``graph`` must hold GTSAM's own factors: writeG2o recognises only
    BetweenFactorPose2/3 and BearingRangeFactor3D, so custom factors would
    silently lose the edges.
    """
    if _is_sim3_graph(graph):
        write_sim3_g2o(path, graph, values)
        return

    def write(tmp: str) -> None:
        gtsam.writeG2o(graph, values, tmp)
        with open(tmp, "rb") as fh:
            written = {int(line.split()[1]) for line in fh
                       if line.startswith((b"VERTEX_XY ", b"VERTEX_TRACKXYZ "))}
        extra = _landmark_vertex_lines(values, written) + _landmark2_lines(graph)
        if extra:
            with open(tmp, "a") as fh:
                fh.write("\n".join(extra) + "\n")

    replace_atomically(path, write, suffix=".g2o")


# --------------------------------------------------------------------------- #
# Sim(3) records (the conversion is derived in the module docstring)
# --------------------------------------------------------------------------- #

def similarity3_from_g2o(v) -> gtsam.Similarity3:
    """The GTSAM element of a g2o Sim(3) record's 7 numbers [ω, υ, σ]: ``Expmap`` of them.

    Shapes: ``v`` (7,).  Exact (``lie_factors.sim3.exp``).
    """
    from .. import sim3

    return gtsam.Similarity3(sim3.exp(np.asarray(v, dtype=np.float64)))


def similarity3_to_g2o(X: gtsam.Similarity3) -> np.ndarray:
    """The 7 numbers g2o writes for GTSAM element ``X``: its ``Logmap`` [ω, u, λ], shape (7,)."""
    from .. import sim3

    return sim3.log(np.asarray(X.matrix(), dtype=np.float64))


def _is_sim3_graph(graph: gtsam.NonlinearFactorGraph) -> bool:
    return graph.size() > 0 and isinstance(graph.at(0), gtsam.BetweenFactorSimilarity3)


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
        for (i, j), v in zip(edges.ids.tolist(), edges.values):
            info = _upper_to_symmetric(v[7:], 7)
            graph.add(gtsam.BetweenFactorSimilarity3(i, j, similarity3_from_g2o(v[:7]),
                                                     gtsam.noiseModel.Gaussian.Information(info)))
    return graph, initial


def read_sim3_g2o(path: str):
    """:func:`check_g2o` + the Sim(3) reading of a file: (graph, initial)."""
    return _read_sim3(check_g2o(path))


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
