"""GTSAM's own factors that have a twin among the kinds: the kind that computes the same residual,
and a reader of the GTSAM factor object into what a row of that kind needs.

The batch solver (:mod:`lie_factors.batch.graph`) evaluates a GTSAM factor whose class is in
:data:`TABLE` with its twin kind's kernel, beside every other factor of the kind, instead of
asking GTSAM to linearize it through Python at each iteration.  Each twin's residual is GTSAM's
error of that class, written in the vocabulary (:mod:`lie_factors.expressions.ready`):

- ``BetweenFactor`` and ``PriorFactor`` of Rot2, Rot3, Pose2, Pose3, Similarity2, Similarity3,
  Point2, Point3; ``PriorFactorPinholeCameraCal3Bundler``/``Cal3_S2``;
- ``PoseTranslationPrior2D/3D``, ``GPSFactor``, ``PoseRotationPrior2D/3D``;
- ``RangeFactor2D/3D/Pose2/Pose3``, ``BearingFactor2D/3D``, ``BearingRangeFactor2D/3D``;
- ``GenericProjectionFactorCal3_S2/Cal3DS2/Cal3Fisheye`` and ``GenericStereoFactor3D`` (with
  their ``body_P_sensor``, ``throwCheirality`` and ``verboseCheirality``);
- ``GeneralSFMFactor2Cal3Bundler`` (pose, point, calibration: the kind
  ``BundlerProjectionFactor``, whose keys are pose, calibration, point) and
  ``GeneralSFMFactorCal3Bundler``/``Cal3_S2`` (a camera and a point).

A reader, ``read(factor, cache)``, returns (the keys in the kind's variable order, the constants
as the kind stores them (:func:`~lie_factors.expressions.types.as_array`'s arrays) in its order,
the noise model object), or None where this factor has no twin after all (a GeneralSFMFactor on a
camera with a robust noise model: GTSAM's linearization of it whitens its Jacobians by the
Gaussian part only).  It calls as few of GTSAM's accessors as it can (each costs 0.3–1 µs), and
keeps its conversions of calibrations in ``cache`` by ``id()`` (GTSAM returns one Python
object for a shared C++ one; ``cache`` holds the object, so its id stays its own).  GTSAM's
Python wrapper has no ``body_P_sensor()`` and, for GenericStereoFactor3D, no
``throwCheirality()``/``verboseCheirality()``: a projection factor is compared with the factor
GTSAM makes from its other fields (``equals``, which compares ``body_P_sensor``), and only one
that differs, and every stereo factor, is read from GTSAM's serialization; a body pose read
there is checked the same way, and where the check fails the factor has no twin.

:class:`TwinRow` is the row: ``_keys_`` and ``_constants`` (what
:class:`~lie_factors.batch.kinds.KindGroup` reads), the GTSAM factor, and :meth:`TwinRow.evaluated`,
which does what GTSAM's factor does at a status of the kernel: a fault raises the kind's error
naming GTSAM's class and keys; a projection GTSAM's factor catches prints or raises as its
``verboseCheirality``/``throwCheirality`` say (GeneralSFMFactor2 always prints its line).
"""

from __future__ import annotations

import gtsam
import numpy as np

from .types import calibration_array, camera_array

__all__ = ["Twin", "TwinRow", "TABLE", "twin_row"]


class Twin:
    """A GTSAM factor class's twin: the kind (made on first use by ``make_kind``), the reader
    (module docstring) and what a caught cheirality does (``"flags"``: the factor's
    throw/verbose flags, held in its row; ``"print"``: GeneralSFMFactor2's line; ``""``:
    nothing)."""

    __slots__ = ("_make_kind", "_kind", "read", "cheirality", "what")

    def __init__(self, make_kind, read, cheirality: str = "", what: str = "CheiralityException"):
        self._make_kind = make_kind
        self._kind = None
        self.read = read
        self.cheirality = cheirality
        self.what = what

    @property
    def kind(self):
        """The :class:`~lie_factors.expressions.kind.Kind` computing the same residual."""
        if self._kind is None:
            self._kind = self._make_kind().kind
        return self._kind


class TwinRow:
    """One GTSAM factor as a row of its twin kind: ``_keys_`` (the kind's variable order),
    ``_constants`` (the kind's stored arrays), ``factor`` (GTSAM's, for messages), ``twin``,
    and ``flags`` (throwCheirality, verboseCheirality) of a projection factor."""

    __slots__ = ("_keys_", "_constants", "factor", "twin", "flags")

    def __init__(self, keys, constants, factor, twin, flags=(False, False)):
        self._keys_ = keys
        self._constants = constants
        self.factor = factor
        self.twin = twin
        self.flags = flags

    @property
    def kind(self):
        """The twin's kind, which evaluates this row."""
        return self.twin.kind

    def silent_fallback(self) -> bool:
        """Whether a caught cheirality changes nothing but the residual (GTSAM's factor neither
        prints nor raises): :meth:`lie_factors.expressions.kind.KindFactor.silent_fallback`."""
        how = self.twin.cheirality
        return how == "" or (how == "flags" and not any(self.flags))

    def evaluated(self, code: int) -> None:
        """What GTSAM's factor does where the kernel's status is ``code`` ≠ 0: a fault (> 0)
        raises the kind's error (:meth:`~lie_factors.expressions.kind.Kind.fault`) naming GTSAM's
        class and keys; a caught cheirality (< 0) prints or raises as GTSAM's factor does."""
        f = self.factor
        if code > 0:
            raise self.twin.kind.fault(code, [int(k) for k in f.keys()], type(f).__name__)
        how = self.twin.cheirality
        if how == "flags":
            from .ready import camera_cheirality

            camera, landmark = f.keys()
            camera_cheirality(type(f).__name__, self.twin.what, camera, landmark, *self.flags)
        elif how == "print":  # GeneralSFMFactor2: pose, landmark, calibration
            camera, landmark = (gtsam.DefaultKeyFormatter(k) for k in f.keys()[:2])
            print(f"{self.twin.what}: Landmark {landmark} behind Camera {camera}")


def evaluable(row, R) -> bool:
    """Whether the kind evaluates the twin ``row`` with whitening ``R`` (RᵀR its information):
    a noise model of the residual's dimension on distinct keys; else GTSAM's own evaluation of
    the factor says what is wrong."""
    m = row.kind.dim
    return R is not None and R.shape == (m, m) and len(set(row._keys_)) == len(row._keys_)


def twin_row(f, cache: dict) -> tuple[TwinRow, object] | None:
    """(the row, the noise model) of GTSAM's factor ``f`` if its class has a twin and ``f`` is
    one (module docstring), else None; ``cache``: the caller's dictionary of conversions, kept
    across the factors of one graph."""
    twin = TABLE.get(type(f))
    if twin is None:
        return None
    read = twin.read(f, cache)
    if read is None:
        return None
    return TwinRow(read[0], read[1], f, twin, *read[3:]), read[2]


# ----------------------------------------------------------------------------- readers


def _read_measured_group(f, cache):
    return f.keys(), [f.measured().matrix()], f.noiseModel()


def _read_measured_vector(f, cache):
    return f.keys(), [np.asarray(f.measured(), dtype=np.float64)], f.noiseModel()


def _read_prior_group(f, cache):
    return f.keys(), [f.prior().matrix()], f.noiseModel()


def _read_prior_point(f, cache):
    return f.keys(), [np.asarray(f.prior(), dtype=np.float64)], f.noiseModel()


def _read_prior_camera(f, cache):
    camera = f.prior()
    return f.keys(), [camera_array(type(camera).__name__, camera)], f.noiseModel()


def _read_gps(f, cache):
    return f.keys(), [np.asarray(f.measurementIn(), dtype=np.float64)], f.noiseModel()


def _read_range(f, cache):
    return f.keys(), [np.array([f.measured()], dtype=np.float64)], f.noiseModel()


def _bearing_value(b) -> np.ndarray:
    """A Rot2's matrix, or a Unit3's unit vector."""
    return b.matrix() if type(b) is gtsam.Rot2 else np.asarray(b.point3(), dtype=np.float64)


def _read_bearing(f, cache):
    return f.keys(), [_bearing_value(f.measured())], f.noiseModel()


def _read_bearing_range(f, cache):
    br = f.measured()
    return f.keys(), [_bearing_value(br.bearing()), np.array([br.range()], dtype=np.float64)], f.noiseModel()


def _calibration(K, cache: dict) -> np.ndarray:
    """The stored entries of GTSAM's calibration object ``K``, converted once per object."""
    entry = cache.get(id(K))
    if entry is None:
        entry = cache[id(K)] = (K, calibration_array(type(K).__name__, K))
    return entry[1]


_IDENTITY = np.eye(4)


def _serialized_options(f) -> tuple[np.ndarray | None, tuple[bool, bool]]:
    """(body_P_sensor's matrix or None, (throwCheirality, verboseCheirality)) of a projection
    or stereo factor, from GTSAM's serialization, which ends with the optional body pose (its
    rotation's nine entries row by row, two tags, its translation's three) and the two flags."""
    tokens = f.serialize().split()
    flags = (tokens[-2] == "1", tokens[-1] == "1")
    if "e" not in tokens[-3]:  # the optional's "absent" tag, where a translation would end
        return None, flags
    body = np.eye(4)
    body[:3, :3] = np.array([float(t) for t in tokens[-16:-7]]).reshape(3, 3)
    body[:3, 3] = [float(t) for t in tokens[-5:-2]]
    return body, flags


def _camera_reader(cls, flags_in_wrapper: bool):
    """The reader of GTSAM's projection factor class ``cls`` (keys pose, point; constants
    measured, K, body_P_sensor; and the flags)."""
    def read(f, cache):
        z, K, noise = f.measured(), f.calibration(), f.noiseModel()
        keys = f.keys()
        constants = [np.asarray(z.vector() if hasattr(z, "vector") else z, dtype=np.float64),
                     _calibration(K, cache), _IDENTITY]
        if flags_in_wrapper:
            flags = (f.throwCheirality(), f.verboseCheirality())
            if f.equals(cls(z, noise, keys[0], keys[1], K), 1e-9):
                return keys, constants, noise, flags
            body, _ = _serialized_options(f)
        else:
            body, flags = _serialized_options(f)
            if body is None:
                return keys, constants, noise, flags
        if body is None:
            return None  # unequal for another reason than a body pose: GTSAM's own evaluation
        pose = gtsam.Pose3(body)
        if not f.equals(cls(z, noise, keys[0], keys[1], K, flags[0], flags[1], pose), 1e-9):
            return None
        constants[2] = pose.matrix()
        return keys, constants, noise, flags

    return read


def _read_sfm2(f, cache):
    pose, point, calibration = f.keys()
    return [pose, calibration, point], [np.asarray(f.measured(), dtype=np.float64)], f.noiseModel()


def _read_sfm_camera(f, cache):
    noise = f.noiseModel()
    if isinstance(noise, gtsam.noiseModel.Robust):
        return None  # GTSAM's GeneralSFMFactor::linearize whitens H by the Gaussian part only
    return f.keys(), [np.asarray(f.measured(), dtype=np.float64)], noise


def _projection_twin(cls, ready_class: str, flags_in_wrapper: bool, what: str = "CheiralityException") -> Twin:
    return Twin(lambda: _ready(ready_class), _camera_reader(cls, flags_in_wrapper), "flags", what)


def _ready(name: str):
    from . import ready

    return getattr(ready, name)


def _kind(factory: str, *args):
    def make():
        from . import ready

        return getattr(ready, factory)(*args)
    return make


def _table() -> dict:
    table = {}
    for t in ("Rot2", "Rot3", "Pose2", "Pose3", "Similarity2", "Similarity3"):
        table[getattr(gtsam, f"BetweenFactor{t}")] = Twin(_kind("between_kind", t), _read_measured_group)
        table[getattr(gtsam, f"PriorFactor{t}")] = Twin(_kind("prior_kind", t), _read_prior_group)
    for t in ("Point2", "Point3"):
        table[getattr(gtsam, f"BetweenFactor{t}")] = Twin(_kind("between_kind", t), _read_measured_vector)
        table[getattr(gtsam, f"PriorFactor{t}")] = Twin(_kind("prior_kind", t), _read_prior_point)
    for camera in ("PinholeCameraCal3Bundler", "PinholeCameraCal3_S2"):
        table[getattr(gtsam, f"PriorFactor{camera}")] = Twin(_kind("prior_kind", camera), _read_prior_camera)
        table[getattr(gtsam, "GeneralSFMFactor" + camera[len("PinholeCamera"):])] = Twin(
            _kind("camera_projection_kind", camera), _read_sfm_camera)
    for d in ("2D", "3D"):
        pose = "Pose" + d[0]
        table[getattr(gtsam, f"PoseTranslationPrior{d}")] = Twin(lambda d=d: _ready(f"PoseTranslationPrior{d}"),
                                                                 _read_measured_vector)
        table[getattr(gtsam, f"PoseRotationPrior{d}")] = Twin(_kind("pose_rotation_prior_kind", pose),
                                                              _read_measured_group)
        table[getattr(gtsam, f"BearingFactor{d}")] = Twin(_kind("bearing_kind", pose), _read_bearing)
        table[getattr(gtsam, f"BearingRangeFactor{d}")] = Twin(lambda d=d: _ready(f"BearingRangeFactor{d}"),
                                                               _read_bearing_range)
    table[gtsam.GPSFactor] = Twin(lambda: _ready("GPSFactor"), _read_gps)
    for name in ("RangeFactor2D", "RangeFactor3D", "RangeFactorPose2", "RangeFactorPose3"):
        table[getattr(gtsam, name)] = Twin(lambda name=name: _ready(name), _read_range)
    for name in ("GenericProjectionFactorCal3_S2", "GenericProjectionFactorCal3DS2",
                 "GenericProjectionFactorCal3Fisheye"):
        table[getattr(gtsam, name)] = _projection_twin(getattr(gtsam, name), name, True)
    table[gtsam.GenericStereoFactor3D] = _projection_twin(gtsam.GenericStereoFactor3D, "GenericStereoFactor3D",
                                                          False, "Stereo Cheirality Exception")
    table[gtsam.GeneralSFMFactor2Cal3Bundler] = Twin(lambda: _ready("BundlerProjectionFactor"), _read_sfm2, "print")
    return table


#: GTSAM's factor classes with a twin → their :class:`Twin`.
TABLE: dict = _table()
