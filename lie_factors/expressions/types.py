"""The types a factor's residual is written in: GTSAM's groups, points, vectors and calibrations.

Each :class:`ValueType` says how a value is stored in the compiled kernels and how it perturbs,
in GTSAM's conventions (``docs/conventions.md``):

- a **group** (Rot2, Rot3, Pose2, Pose3, Similarity2, Similarity3) is its (m, m) matrix, and a
  variable of it moves as X·Exp(δ), δ in GTSAM's tangent order (Pose3 [ω, v], Pose2 [x, y, θ],
  Similarity3 [ω, u, λ], …); Rot2 is the 2×2 rotation matrix, tangent [θ];
- a **vector** (Point2, Point3, StereoPoint2 [uL, uR, v], VectorN, and the calibrations
  :data:`CALIBRATIONS`: Cal3_S2 [fx, fy, s, u0, v0], Cal3Bundler [f, k1, k2, u0, v0],
  Cal3DS2 [fx, fy, s, u0, v0, k1, k2, p1, p2], Cal3Fisheye [fx, fy, s, u0, v0, k1, k2, k3, k4],
  Cal3_S2Stereo [fx, fy, s, u0, v0, b]) is a 1-D array, and moves as p + δ on its first ``dim``
  entries (all but a Cal3Bundler's principal point, which GTSAM does not optimize either);
- a **camera** (PinholeCameraCal3Bundler, PinholeCameraCal3_S2: GTSAM's PinholeCamera, a pose
  and its calibration as one value) is one 1-D array: the pose's 4×4 matrix row by row, then the
  calibration's stored entries; its tangent is GTSAM's [pose ω, v, then the calibration's]
  (9 and 11), and it moves as (P·Exp(δ[:6]), K + δ[6:]) (:data:`CAMERAS`);
- a **matrix** (what ``matrix()`` and ``AdjointMap()`` give; ``MatrixRxC``) is held row by
  row in a 1-D array, and is an intermediate value only: never a variable or a constant.

:func:`value_type` reads a type by name (``"Pose3"``, ``"Point2"``, ``"Vector4"``) or by GTSAM class.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import InputError
from ..kernels import registry


@dataclass(frozen=True)
class ValueType:
    """A type of the vocabulary.  ``dim``: tangent dimension; ``shape``: the stored array's shape;
    ``group``: the registry's :class:`~lie_factors.kernels.registry.GroupInfo` of a matrix group
    (None for Rot2 and for vectors); ``rot``: the rotation's dimension of a group (2 or 3);
    ``cols``: a matrix's number of columns (its rows: ``dim // cols``)."""

    name: str
    kind: str  # "group", "vector", "unit" (a Unit3), "camera" or "matrix"
    dim: int
    shape: tuple
    group: registry.GroupInfo | None = None
    rot: int = 0
    cols: int = 0

    @property
    def is_group(self) -> bool:
        return self.kind == "group"

    @property
    def is_matrix(self) -> bool:
        return self.kind == "matrix"

    @property
    def rows(self) -> int:
        """A matrix's rows (a vector's entries: a column)."""
        return self.dim // self.cols if self.cols else self.dim

    @property
    def plain(self) -> bool:
        """Whether the stored array is the value's coordinates, one entry each (not a group, a
        Unit3, or a Cal3Bundler with its principal point beside them)."""
        return self.kind in ("vector", "matrix") and self.shape == (self.dim,)

    @cached_property
    def accessor(self) -> str:
        """The ``gtsam.Values`` method that reads a variable of this type (:func:`accessor`)."""
        return accessor(self)

    def __str__(self) -> str:
        return self.name


def _group_type(info: registry.GroupInfo) -> ValueType:
    return ValueType(info.gtsam, "group", info.dim, (info.mat, info.mat), info, info.rot_dim)


ROT2 = ValueType("Rot2", "group", 1, (2, 2), None, 2)
GROUPS = {"Rot2": ROT2, **{info.gtsam: _group_type(info) for info in registry.GROUPS.values()}}
POINT2 = ValueType("Point2", "vector", 2, (2,))
POINT3 = ValueType("Point3", "vector", 3, (3,))
STEREO_POINT2 = ValueType("StereoPoint2", "vector", 3, (3,))
#: GTSAM's calibrations: their stored entries, each read by the GTSAM accessor named (and the
#: order of GTSAM's constructor).  A Cal3Bundler's tangent is [f, k1, k2] (GTSAM's dim 3): its
#: principal point is held, used, and never moved.
CALIBRATIONS = {
    "Cal3_S2": ("fx", "fy", "skew", "px", "py"),
    "Cal3Bundler": ("fx", "k1", "k2", "px", "py"),
    "Cal3DS2": ("fx", "fy", "skew", "px", "py", "k1", "k2", "p1", "p2"),
    "Cal3Fisheye": ("fx", "fy", "skew", "px", "py", "k1", "k2", "k3", "k4"),
    "Cal3_S2Stereo": ("fx", "fy", "skew", "px", "py", "baseline"),
}
_CALIBRATION_TYPES = {name: ValueType(name, "vector", 3 if name == "Cal3Bundler" else len(fields), (len(fields),))
                      for name, fields in CALIBRATIONS.items()}
CAL3_S2 = _CALIBRATION_TYPES["Cal3_S2"]
CAL3_BUNDLER = _CALIBRATION_TYPES["Cal3Bundler"]
NAMED_VECTORS = {t.name: t for t in (POINT2, POINT3, STEREO_POINT2, *_CALIBRATION_TYPES.values())}
#: GTSAM's cameras: each one's calibration.  Stored as :func:`camera_array`: the pose's matrix
#: row by row (16 entries), then the calibration's stored entries (:data:`CALIBRATIONS`).
CAMERAS = {"PinholeCameraCal3Bundler": "Cal3Bundler", "PinholeCameraCal3_S2": "Cal3_S2"}
CAMERA_TYPES = {name: ValueType(name, "camera", 6 + _CALIBRATION_TYPES[cal].dim, (16 + len(CALIBRATIONS[cal]),))
                for name, cal in CAMERAS.items()}
#: A direction in 3-D (GTSAM's Unit3), held as its unit vector; its Jacobians in the chain rule
#: are those of the unit vector (3 rows).  A measurement, or a bearing computed from a point: not
#: a variable.
UNIT3 = ValueType("Unit3", "unit", 3, (3,))


def vector(n: int) -> ValueType:
    """The plain vector type of dimension ``n`` ≥ 1 (Point2 and Point3 are vectors of 2 and 3
    that print as points)."""
    if int(n) < 1:
        raise InputError(f"a vector needs a dimension of at least 1, got {n}")
    return ValueType(f"Vector{int(n)}", "vector", int(n), (int(n),))


def matrix(rows: int, cols: int) -> ValueType:
    """The matrix type of ``rows`` × ``cols`` entries (held row by row)."""
    return ValueType(f"Matrix{rows}x{cols}", "matrix", rows * cols, (rows * cols,), cols=cols)


def calibration_array(name: str, value) -> np.ndarray:
    """The stored entries of a GTSAM calibration object of class ``name`` (:data:`CALIBRATIONS`)."""
    return np.array([getattr(value, field)() for field in CALIBRATIONS[name]], dtype=np.float64)


def camera_array(name: str, value) -> np.ndarray:
    """The stored array of a GTSAM camera object of class ``name`` (:data:`CAMERAS`): its pose's
    matrix row by row, then its calibration's stored entries."""
    return np.concatenate([value.pose().matrix().reshape(16), calibration_array(CAMERAS[name], value.calibration())])


def camera_pose(a: np.ndarray) -> np.ndarray:
    """The pose's 4×4 matrix of a camera's stored array ``a`` (a view)."""
    return a[:16].reshape(4, 4)


def camera_calibration(a: np.ndarray) -> np.ndarray:
    """The calibration's stored entries of a camera's stored array ``a`` (a view)."""
    return a[16:]


def value_type(spec) -> ValueType:
    """The :class:`ValueType` named by ``spec``: a ValueType, a name (``"Pose3"``, ``"Point2"``,
    ``"Vector4"``, ``"Cal3_S2"``), or a GTSAM class (``gtsam.Pose3``, ``gtsam.Cal3_S2``)."""
    if isinstance(spec, ValueType):
        return spec
    name = getattr(spec, "__name__", spec)
    if not isinstance(name, str):
        raise InputError(f"a factor's type must be a name such as 'Pose3' or a GTSAM class, got {spec!r}")
    if name in GROUPS:
        return GROUPS[name]
    if name in NAMED_VECTORS:
        return NAMED_VECTORS[name]
    if name in CAMERA_TYPES:
        return CAMERA_TYPES[name]
    if name == "Unit3":
        return UNIT3
    match = re.fullmatch(r"Vector(\d+)", name)
    if match:
        return vector(int(match.group(1)))
    known = ", ".join([*GROUPS, *NAMED_VECTORS, *CAMERA_TYPES, "VectorN", "Unit3"])
    raise InputError(f"unknown type {name!r}: expected one of {known}")


def as_array(t: ValueType, value, what: str) -> np.ndarray:
    """``value`` (a GTSAM object or an array) as ``t``'s stored array, checked: its shape, finite
    entries, and for a group an element of it (``InputError`` naming ``what``)."""
    if t.is_group:
        if hasattr(value, "matrix"):
            value = value.matrix()
        elif t.name == "Rot2" and hasattr(value, "theta"):
            c, s = value.c(), value.s()
            value = np.array([[c, -s], [s, c]])
    elif t.name == "Unit3" and hasattr(value, "point3"):
        value = value.point3()
    elif t.name in CALIBRATIONS and type(value).__name__ == t.name:
        value = calibration_array(t.name, value)
    elif t.kind == "camera" and type(value).__name__ == t.name:
        value = camera_array(t.name, value)
    elif hasattr(value, "vector"):  # a StereoPoint2
        value = value.vector()
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected a {t} ({' × '.join(map(str, t.shape))} array), "
                         f"got {type(value).__name__}") from None
    if t.name == "Cal3Bundler" and a.shape == (3,):  # [f, k1, k2]: the principal point at the origin
        a = np.concatenate([a, np.zeros(2)])
    if a.shape != t.shape:
        raise InputError(f"{what}: expected a {t} of shape {t.shape}, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise InputError(f"{what}: not finite")
    if t.is_group:
        _check_element(t, a, what)
    if t.kind == "camera":
        _check_element(GROUPS["Pose3"], camera_pose(a), f"{what}: its pose")
    if t.name == "Unit3" and abs(float(np.linalg.norm(a)) - 1.0) > 1e-9:
        raise InputError(f"{what}: a Unit3 is a unit vector, got one of norm {np.linalg.norm(a):.6g}")
    return np.ascontiguousarray(a)


def accessor(t: ValueType) -> str:
    """The ``gtsam.Values`` method that reads a variable of type ``t``."""
    if t.is_group or t.kind == "camera" or (t.name in NAMED_VECTORS and t is not STEREO_POINT2):
        return f"at{t.name}"
    return "atVector"


def _check_element(t: ValueType, a: np.ndarray, what: str) -> None:
    """The test of an element: the public functions' compiled fast path first
    (:func:`lie_factors.kernels.checks.element_ok`, which accepts nothing the numpy test
    refuses), then, for what it does not accept, the numpy test that words the defect
    (:mod:`lie_factors.kernels.validate`)."""
    from ..kernels import validate
    from ..kernels.checks import element_ok

    info = t.group
    corner = registry.NO_CORNER if info is None else info.corner
    if element_ok(a, t.rot, corner):
        return
    validate.rotation_block(a, what, t.rot)
    if corner != registry.NO_CORNER:
        validate.bottom_row(a, what, validate.last_row(info), corner == registry.POSITIVE)
