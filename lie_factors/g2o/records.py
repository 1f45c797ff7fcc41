"""The g2o record table: one :class:`Record` per tag, its fields and the checks of its rows.

A new record type is one :func:`register` call here (plus, if GTSAM's reader
does not build its factor, a branch in :func:`lie_factors.g2o.read.read_with_gtsam`).

What GTSAM 4.3's ``readG2o`` accepts (its ``dataset.cpp``, checked against the
wheel): in 2-D (``load2D``) ``VERTEX_SE2``/``VERTEX2``/``VERTEX``,
``VERTEX_XY``, ``EDGE_SE2``/``EDGE2``/``EDGE``/``ODOMETRY``, ``BR`` and
``LANDMARK``; in 3-D (``load3D``) ``VERTEX3``, ``VERTEX_SE3:QUAT``,
``VERTEX_TRACKXYZ``, ``EDGE3``, ``EDGE_SE3:QUAT``, ``EDGE_SE3_TRACKXYZ`` and
``PARAMS_SE3OFFSET``.  Every other tag is skipped without a word; we refuse it
(a skipped line is a lost measurement), except ``LANDMARK2`` (pose id,
landmark id, x y in the pose frame, 2×2 information — the SE-Sync landmark
format of the shipped ``cityTrees``/``victoriaPark`` files) and the Sim(3)
records ``VERTEX_SIM3:EXPMAP``/``EDGE_SIM3:EXPMAP``, which we read ourselves.

Row checks run on all rows of one tag at once (numpy) and yield
(row index, message) for the first bad row of each kind of problem.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np


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
    def family(self) -> tuple[int, str]:
        """Records that may share a file: same dimension and pose type."""
        return self.dim, self.group_name

    @property
    def nfields(self) -> int:
        return len(self.ids) + len(self.values) + self.info

    @property
    def info_dim(self) -> int:
        """n of the n×n information matrix whose upper triangle is the last ``info`` values."""
        return int(round((math.sqrt(8 * self.info + 1) - 1) / 2))

    @property
    def field_text(self) -> str:
        text = " ".join(self.ids + self.values)
        if self.info:
            n = self.info_dim
            text += f" + {self.info} information ({n}×{n} upper triangle)"
        return text


def first_true(mask: np.ndarray) -> int | None:
    """Index of the first True in ``mask``, or None."""
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def same_rows(values: np.ndarray) -> bool:
    """Whether every row of ``values`` (N, k) holds the bits of the first (N ≥ 1)."""
    words = values.view(np.uint64) if values.dtype == np.float64 else values
    return bool(np.all(words == words[:1]))


def upper_to_symmetric(values: np.ndarray, n: int, order: np.ndarray | None = None) -> np.ndarray:
    """Row-major upper triangles, shape (..., n(n+1)/2) → symmetric (..., n, n).

    ``order`` (n,): rows and columns taken in that order (M[order][:, order]).
    One gather of whole rows: writing the n² entries one strided pass each
    streams the (..., n, n) array through memory n² times.
    """
    index = np.zeros((n, n), dtype=np.intp)
    iu = np.triu_indices(n)
    index[iu] = np.arange(len(iu[0]))
    index[iu[1], iu[0]] = index[iu]
    if order is not None:
        index = index[np.ix_(order, order)]
    return np.take(np.asarray(values, dtype=float), index, axis=-1)


# --------------------------------------------------------------------------- #
# Row checks
# --------------------------------------------------------------------------- #

#: Relative eigenvalue floor for an information matrix: below it the matrix is
#: singular to working precision and its square root (the whitening) meaningless.
INFO_REL_EIG = 1e-12


def _check_info(first: int, n: int, what: str = "information matrix") -> RowCheck:
    """Information values[first : first + n(n+1)/2] must be positive definite."""
    m = n * (n + 1) // 2

    def check(rows: Rows):
        upper = rows.values[:, first:first + m]
        if len(upper) > 1 and same_rows(upper):
            upper = upper[:1]  # one matrix stated on every row: one check
        eig_min = np.linalg.eigvalsh(upper_to_symmetric(upper, n))[:, 0]
        scale = np.abs(upper).max(axis=1)  # the largest |entry| of M: its upper triangle holds them all
        bad = first_true(~(eig_min > INFO_REL_EIG * scale))
        if bad is not None:
            yield bad, (f"{what} is not positive definite "
                        f"(smallest eigenvalue {eig_min[bad]:.3g})")

    return check


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


#: float64 x²+y²+z²+w² of a usable quaternion: GTSAM divides by its square root
#: (a subnormal or overflowing sum gives NaN or a zero rotation).
_QN2_MIN = float(np.finfo(float).tiny)


def _check_quaternion(first: int) -> RowCheck:
    def check(rows: Rows):
        q = rows.values[:, first:first + 4]
        n2 = np.einsum("ij,ij->i", q, q)
        bad = first_true(~((n2 >= _QN2_MIN) & np.isfinite(n2)))
        if bad is not None:
            yield bad, (f"quaternion qx qy qz qw has norm {math.sqrt(n2[bad]):.3g}: GTSAM "
                        f"divides by it, which gives NaN or garbage (any other norm is normalized)")

    return check


def _check_range(first: int, k: int) -> RowCheck:
    """A Cartesian landmark measurement must have a positive finite range (GTSAM's rule for 3-D)."""
    def check(rows: Rows):
        p = rows.values[:, first:first + k]
        r2 = np.einsum("ij,ij->i", p, p)  # naive, as GTSAM computes it
        bad = first_true(~((r2 > 0) & np.isfinite(r2)))
        if bad is not None:
            yield bad, ("landmark measurement has zero (or overflowing) range: "
                        "its bearing is undefined")

    return check


def _check_br(rows: Rows):
    v = rows.values
    bad = first_true(~(v[:, 1] > 0))
    if bad is not None:
        yield bad, f"range {v[bad, 1]:.6g} is not positive"
    bad = first_true(~((v[:, 2] > 0) & (v[:, 3] > 0)))
    if bad is not None:
        yield bad, (f"standard deviations ({v[bad, 2]:.6g}, {v[bad, 3]:.6g}) must be positive")


#: GTSAM's LANDMARK rule (dataset.cpp): |v1 − v3| < 1e-4 → σ_bearing = √(v1/10),
#: σ_range = √v1; otherwise it silently uses σ = (1, 1).
LANDMARK_ISO_TOL = 1e-4


def _check_landmark_cov(rows: Rows):
    v1, v3 = rows.values[:, 2], rows.values[:, 4]
    bad = first_true(~(np.abs(v1 - v3) < LANDMARK_ISO_TOL))
    if bad is not None:
        yield bad, (f"LANDMARK covariance v1 = {v1[bad]:.6g}, v3 = {v3[bad]:.6g} is not isotropic: "
                    f"GTSAM's reader would ignore it and use unit standard deviations")
    bad = first_true(~(v1 > 0))
    if bad is not None:
        yield bad, f"LANDMARK variance v1 = {v1[bad]:.6g} must be positive"


#: Largest accepted |λ| of a Sim(3) record: e^±700 is still a normal double.
SIM3_MAX_LOG_SCALE = 700.0


def _check_log_scale(rows: Rows):
    lam = rows.values[:, 6]
    bad = first_true(~(np.abs(lam) < SIM3_MAX_LOG_SCALE))
    if bad is not None:
        yield bad, (f"log-scale λ = {lam[bad]:.6g} is out of range (|λ| < {SIM3_MAX_LOG_SCALE:g}, "
                    f"the scale e^λ must be a finite, non-zero double)")


# --------------------------------------------------------------------------- #
# The table
# --------------------------------------------------------------------------- #

#: Ids are GTSAM keys; a landmark key packs the character 'l' into the top 8
#: bits (gtsam.symbol), so larger ids cannot be landmarks and, as poses, could
#: collide with landmark keys.
MAX_ID = 2**56 - 1

RECORDS: dict[str, Record] = {}


def register(record: Record) -> Record:
    """Add ``record`` to :data:`RECORDS` (one entry per tag)."""
    RECORDS[record.tag] = record
    return record


_QUAT = ("qx", "qy", "qz", "qw")
_SIM3 = ("ω1", "ω2", "ω3", "υ1", "υ2", "υ3", "σ")

# The order of registration is the order the "unknown tag" message lists them in.
for _tag in ("VERTEX_SE2", "VERTEX2", "VERTEX"):
    register(Record(_tag, 2, "pose", ("id",), ("x", "y", "θ")))
register(Record("VERTEX_XY", 2, "landmark", ("id",), ("x", "y")))
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
register(Record("VERTEX_SIM3:EXPMAP", 3, "pose", ("id",), _SIM3 + ("fx", "fy", "cx", "cy"),
                gtsam=False, group="Similarity3", checks=(_check_log_scale,),
                note="read by lie_factors; the camera values are checked and dropped"))
register(Record("EDGE_SIM3:EXPMAP", 3, "between", ("id1", "id2"), _SIM3, info=28, gtsam=False,
                group="Similarity3", checks=(_check_log_scale, _check_info(7, 7)),
                note="read by lie_factors"))
del _tag
