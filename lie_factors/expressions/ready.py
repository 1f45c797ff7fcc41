"""Ready factors, each a few lines of the vocabulary, named and constructed as GTSAM's own.

Each is a factor kind (:func:`~lie_factors.expressions.kind.factor`) whose residual is GTSAM's
error of the factor of the same name; the class takes GTSAM's constructor arguments:

- ``GPSFactor(key, gpsIn, model)``: translation(x) − z (GTSAM's ``GPSFactor``);
- ``PoseTranslationPrior2D/3D``: translation(x) − z;
- ``PoseToPointFactor2D/3D``: transformTo(x, l) − z (C++ ``PoseToPointFactor``);
- ``RangeFactor2D/3D``, ``RangeFactorPose2/Pose3``: range(x, l) − r, GTSAM's ‖l − t‖ (of another
  pose: its translation);
- ``BearingRangeFactor2D``: [Log(b⁻¹·bearing(x, l)), range(x, l) − r];
- ``BearingRangeFactor3D``: [−bearing(x, l).localCoordinates(b), range(x, l) − r];
- ``GenericProjectionFactorCal3_S2``, ``…Cal3DS2``, ``…Cal3Fisheye``: project(x·B, l, K) − z,
  B the ``body_P_sensor`` (or I);
- ``GenericStereoFactor3D``: the same with GTSAM's StereoCamera, [uL, uR, v];
- ``BundlerProjectionFactor``: project(x, l, K) − z with K = [f, k1, k2] a variable (u0, v0
  held with it), GTSAM's ``GeneralSFMFactorCal3Bundler`` with the camera as a pose and its
  calibration.

And the kinds of GTSAM's generic factors, one per type, made on first use (each the kind's
factor class, constructed ``kind(key_1, …, measured, noise_model)`` as GTSAM's):

- :func:`between_kind`: ``BetweenFactor<T>``, Log(z⁻¹·x1⁻¹·x2) of a group (Rot2, Rot3, Pose2,
  Pose3, Similarity2, Similarity3), (x2 − x1) − z of a point;
- :func:`prior_kind`: ``PriorFactor<T>``, Log(z⁻¹·x) of a group, x − z of a point, a camera's
  GTSAM ``localCoordinates`` from z to x;
- :func:`pose_rotation_prior_kind`: ``PoseRotationPrior2D/3D``, Log(z⁻¹·rotation(x));
- :func:`bearing_kind`: ``BearingFactor2D/3D``, the bearing part of ``BearingRangeFactor2D/3D``;
- :func:`camera_projection_kind`: ``GeneralSFMFactor`` on a camera variable (PinholeCameraCal3Bundler,
  PinholeCameraCal3_S2): camera.project(l) − z, 0 with zero Jacobians where the point is not
  in front of the camera.

A point not in front of a camera (depth ≤ 0) gives GTSAM's projection factors' error: the
constant 2·fx with zero Jacobians (0 for BundlerProjectionFactor, as GeneralSFMFactor), and
with ``verboseCheirality`` GTSAM's line on standard output, with ``throwCheirality``
:class:`~lie_factors.errors.CheiralityException` (a ``RuntimeError``, as GTSAM's).
"""

from __future__ import annotations

from functools import cache

import numpy as np

from . import ops
from .kind import factor

__all__ = ["GPSFactor", "PoseTranslationPrior2D", "PoseTranslationPrior3D", "PoseToPointFactor2D",
           "PoseToPointFactor3D", "RangeFactor2D", "RangeFactor3D", "RangeFactorPose2", "RangeFactorPose3",
           "BearingRangeFactor2D", "BearingRangeFactor3D", "GenericProjectionFactorCal3_S2",
           "GenericProjectionFactorCal3DS2", "GenericProjectionFactorCal3Fisheye", "GenericStereoFactor3D",
           "BundlerProjectionFactor", "from_gtsam", "between_kind", "prior_kind", "pose_rotation_prior_kind",
           "bearing_kind", "camera_projection_kind"]


def _scalar(value) -> np.ndarray:
    """A measured number as the (1,) vector the kind holds."""
    a = np.asarray(value, dtype=np.float64)
    if a.size != 1:
        from ..errors import InputError

        raise InputError(f"expected a number, got an array of shape {a.shape}")
    return a.reshape(1)


@factor("Pose3", measured="Point3")
def PoseTranslationPrior3D(x, z):
    """translation(x) − z: GTSAM's ``PoseTranslationPrior3D(key, measured, model)``."""
    return x.translation() - z


@factor("Pose2", measured="Point2")
def PoseTranslationPrior2D(x, z):
    """translation(x) − z: GTSAM's ``PoseTranslationPrior2D(key, measured, model)``."""
    return x.translation() - z


class GPSFactor(PoseTranslationPrior3D):
    """A GPS position of a Pose3, translation(x) − z: GTSAM's ``GPSFactor(key, gpsIn, model)``."""

    def measurementIn(self) -> np.ndarray:
        """The measured position (GTSAM's ``measurementIn()``)."""
        return self.constants()["measured"].copy()

    def as_gtsam(self):
        """GTSAM's own ``GPSFactor``: the same key, measurement and noise model object."""
        import gtsam

        return gtsam.GPSFactor(self.keys()[0], self.measurementIn(), self.noiseModel())


@factor("Pose3", "Point3", measured="Point3")
def PoseToPointFactor3D(x, l, z):
    """transformTo(x, l) − z: the point l seen from the pose x (g2o's ``EDGE_SE3_TRACKXYZ``)."""
    return x.transformTo(l) - z


@factor("Pose2", "Point2", measured="Point2")
def PoseToPointFactor2D(x, l, z):
    """transformTo(x, l) − z: the point l seen from the pose x (g2o's ``EDGE_SE2_XY``)."""
    return x.transformTo(l) - z


@factor("Pose2", "Point2", measured="Vector1")
def _range2(x, l, r):
    return x.range(l) - r


@factor("Pose3", "Point3", measured="Vector1")
def _range3(x, l, r):
    return x.range(l) - r


@factor("Pose2", "Pose2", measured="Vector1")
def _range_pose2(x1, x2, r):
    return x1.range(x2) - r


@factor("Pose3", "Pose3", measured="Vector1")
def _range_pose3(x1, x2, r):
    return x1.range(x2) - r


def _range_class(kind, name: str, gtsam_name: str):
    def __init__(self, key1, key2, measured, noiseModel):
        kind.__init__(self, key1, key2, _scalar(measured), noiseModel)

    def measured(self) -> float:
        """The measured range (GTSAM's ``measured()``)."""
        return float(self.constants()["measured"][0])

    def as_gtsam(self):
        """GTSAM's own factor of this name: the same keys, measured range and noise model object."""
        import gtsam

        key1, key2 = self.keys()
        return getattr(gtsam, gtsam_name)(key1, key2, self.measured(), self.noiseModel())

    return type(name, (kind,), {"__init__": __init__, "measured": measured, "as_gtsam": as_gtsam,
                                "__module__": __name__, "__doc__":
                                f"range(x, l) − r: GTSAM's ``{gtsam_name}(key1, key2, measured, noiseModel)``."})


RangeFactor2D = _range_class(_range2, "RangeFactor2D", "RangeFactor2D")
RangeFactor3D = _range_class(_range3, "RangeFactor3D", "RangeFactor3D")
RangeFactorPose2 = _range_class(_range_pose2, "RangeFactorPose2", "RangeFactorPose2")
RangeFactorPose3 = _range_class(_range_pose3, "RangeFactorPose3", "RangeFactorPose3")


def _bearing_error(x, l, measured):
    """GTSAM's error of a measured bearing of l from x (an ExpressionFactor's −Local(predicted,
    measured)): Log(b⁻¹·bearing(x, l)) of a Rot2; of a Unit3, −bearing(x, l).localCoordinates(b),
    in the predicted direction's basis."""
    predicted = x.bearing(l)
    if measured.type.kind == "unit":
        return -predicted.localCoordinates(measured)
    return measured.localCoordinates(predicted)


@factor("Pose2", "Point2", bearing="Rot2", range="Vector1")
def _bearing_range2(x, l, bearing, range):
    return ops.stack(_bearing_error(x, l, bearing), x.range(l) - range)


class BearingRangeFactor2D(_bearing_range2):
    """[Log(b⁻¹·bearing(x, l)), ‖transformTo(x, l)‖ − r]: GTSAM's
    ``BearingRangeFactor2D(poseKey, pointKey, measuredBearing, measuredRange, noiseModel)``."""

    def __init__(self, poseKey, pointKey, measuredBearing, measuredRange, noiseModel):
        super().__init__(poseKey, pointKey, noiseModel, bearing=measuredBearing, range=_scalar(measuredRange))

    def measured(self):
        """The measurement as GTSAM's ``BearingRange2D`` (GTSAM's ``measured()``)."""
        import gtsam

        c = self.constants()
        return gtsam.BearingRange2D(gtsam.Rot2.atan2(c["bearing"][1, 0], c["bearing"][0, 0]), float(c["range"][0]))

    def as_gtsam(self):
        """GTSAM's own ``BearingRangeFactor2D``: the same keys, measurement and noise model object."""
        import gtsam

        br = self.measured()
        pose, point = self.keys()
        return gtsam.BearingRangeFactor2D(pose, point, br.bearing(), br.range(), self.noiseModel())


@factor("Pose3", "Point3", bearing="Unit3", range="Vector1")
def _bearing_range3(x, l, bearing, range):
    return ops.stack(_bearing_error(x, l, bearing), x.range(l) - range)


class BearingRangeFactor3D(_bearing_range3):
    """[−bearing(x, l).localCoordinates(b) (GTSAM's Unit3 coordinates, in the predicted
    direction's basis), ‖transformTo(x, l)‖ − r]: GTSAM's
    ``BearingRangeFactor3D(poseKey, pointKey, measuredBearing, measuredRange, noiseModel)``."""

    def __init__(self, poseKey, pointKey, measuredBearing, measuredRange, noiseModel):
        super().__init__(poseKey, pointKey, noiseModel, bearing=measuredBearing, range=_scalar(measuredRange))

    def measured(self):
        """The measurement as GTSAM's ``BearingRange3D`` (GTSAM's ``measured()``)."""
        import gtsam

        c = self.constants()
        return gtsam.BearingRange3D(gtsam.Unit3(c["bearing"]), float(c["range"][0]))

    def as_gtsam(self):
        """GTSAM's own ``BearingRangeFactor3D``: the same keys, measurement and noise model object
        (what GTSAM's writeG2o writes as EDGE_SE3_TRACKXYZ)."""
        import gtsam

        br = self.measured()
        pose, point = self.keys()
        return gtsam.BearingRangeFactor3D(pose, point, br.bearing(), br.range(), self.noiseModel())


def _camera_kind(name: str, calibration: str, measured: str, rows: int):
    """The kind of GTSAM's projection factors for ``calibration``: project(x·body_P_sensor, l, K)
    − z, and where the point is not in front of the camera the constant 2·fx in every entry with
    zero Jacobians (their ``catch (CheiralityException&)``)."""
    def residual(x, l, z, K, body_P_sensor):
        return ops.catch_cheirality(ops.project(x.compose(body_P_sensor), l, K) - z, 2.0 * K[0] * np.ones(rows))

    residual.__name__ = residual.__qualname__ = name
    return factor("Pose3", "Point3", measured=measured, K=calibration, body_P_sensor="Pose3")(residual)


_projection_s2 = _camera_kind("GenericProjectionFactorCal3_S2", "Cal3_S2", "Point2", 2)
_projection_ds2 = _camera_kind("GenericProjectionFactorCal3DS2", "Cal3DS2", "Point2", 2)
_projection_fisheye = _camera_kind("GenericProjectionFactorCal3Fisheye", "Cal3Fisheye", "Point2", 2)
_stereo = _camera_kind("GenericStereoFactor3D", "Cal3_S2Stereo", "StereoPoint2", 3)


#: GTSAM's constructor signatures after (measured, noiseModel, poseKey, pointKey, k).
_SIGNATURES = ((), ("body_P_sensor",), ("throwCheirality", "verboseCheirality"),
               ("throwCheirality", "verboseCheirality", "body_P_sensor"))


def _fits(name: str, value) -> bool:
    """Whether pybind11 would take ``value`` for GTSAM's argument ``name``: a gtsam.Pose3 for the
    body pose; for a bool, what its converting bool caster takes (None, a number)."""
    if name == "body_P_sensor":
        import gtsam

        return isinstance(value, gtsam.Pose3)
    return value is None or isinstance(value, (bool, int, float, np.bool_, np.number))


def _camera_arguments(factor_name: str, head: str, args: tuple, named: dict) -> dict:
    """The optional arguments of a GTSAM projection factor, bound to the one of GTSAM's four
    signatures they fit (as pybind11 chooses among overloads), or an ArgumentTypeError listing them."""
    for signature in _SIGNATURES:
        if len(args) > len(signature) or set(named) != set(signature[len(args):]):
            continue
        bound = dict(zip(signature, args), **named)
        if all(_fits(k, v) for k, v in bound.items()):
            return bound
    from ..errors import ArgumentTypeError

    listed = "; ".join(f"({head}{''.join(', ' + a for a in sig)})" for sig in _SIGNATURES)
    raise ArgumentTypeError(f"{factor_name}: incompatible constructor arguments; GTSAM's are {listed}, with "
                            "throwCheirality and verboseCheirality bools and body_P_sensor a gtsam.Pose3")


class _CameraFactor:
    """What GTSAM's GenericProjectionFactor and GenericStereoFactor share: the constructor
    ``(measured, noiseModel, poseKey, pointKey, k[, throwCheirality, verboseCheirality]
    [, body_P_sensor])``, its accessors, and what a point behind the camera does: the error
    2·fx in every entry with zero Jacobians, a line printed with ``verboseCheirality`` and
    :class:`~lie_factors.errors.CheiralityException` raised with ``throwCheirality``."""

    _what = "CheiralityException"  # GTSAM's exception's what()
    _calibration = "Cal3_S2"

    def __init__(self, measured, noiseModel, poseKey, pointKey, k, *args, **named):
        bound = _camera_arguments(type(self).__name__, "measured, noiseModel, poseKey, pointKey, k", args, named)
        self._throw = bool(bound.get("throwCheirality", False))
        self._verbose = bool(bound.get("verboseCheirality", False))
        self._body = bound.get("body_P_sensor")
        body = _IDENTITY if self._body is None else self._body
        super().__init__(poseKey, pointKey, measured, noiseModel, K=k, body_P_sensor=body)

    def calibration(self):
        """The calibration, as GTSAM's object (GTSAM's ``calibration()``)."""
        import gtsam

        return getattr(gtsam, self._calibration)(*(float(v) for v in self.constants()["K"]))

    def body_P_sensor(self):
        """The sensor's pose in the body frame, or None (GTSAM's ``body_P_sensor()``)."""
        return self._body

    def throwCheirality(self) -> bool:
        return self._throw

    def verboseCheirality(self) -> bool:
        return self._verbose

    def silent_fallback(self) -> bool:
        return not (self._throw or self._verbose)

    def on_cheirality(self) -> None:
        camera_cheirality(type(self).__name__, self._what, *self._keys_, self._throw, self._verbose)


def camera_cheirality(factor: str, what: str, camera: int, landmark: int, throw: bool, verbose: bool) -> None:
    """What GTSAM's GenericProjectionFactor and GenericStereoFactor (class ``factor``, exception
    text ``what``) do where their projection finds the landmark not in front of the camera:
    with ``verbose`` print GTSAM's line, with ``throw`` raise
    :class:`~lie_factors.errors.CheiralityException`."""
    import gtsam

    from ..errors import CheiralityException

    camera, landmark = gtsam.DefaultKeyFormatter(camera), gtsam.DefaultKeyFormatter(landmark)
    if verbose:
        print(f"{what}: Landmark {landmark} moved behind camera {camera}")
    if throw:
        raise CheiralityException(f"{factor}: {what}: landmark {landmark} is behind camera {camera} "
                                  "(throwCheirality)")


_IDENTITY = np.eye(4)


class GenericProjectionFactorCal3_S2(_CameraFactor, _projection_s2):
    """project(x·body_P_sensor, l, K) − z (a pinhole camera, z forward), GTSAM's error 2·fx where
    the point is not in front of it: GTSAM's ``GenericProjectionFactorCal3_S2(measured,
    noiseModel, poseKey, pointKey, k[, throwCheirality, verboseCheirality][, body_P_sensor])``."""


class GenericProjectionFactorCal3DS2(_CameraFactor, _projection_ds2):
    """GenericProjectionFactorCal3_S2's error with a Cal3DS2 (radial and tangential distortion):
    GTSAM's ``GenericProjectionFactorCal3DS2``, the same constructor."""

    _calibration = "Cal3DS2"


class GenericProjectionFactorCal3Fisheye(_CameraFactor, _projection_fisheye):
    """GenericProjectionFactorCal3_S2's error with a Cal3Fisheye (the equidistant model):
    GTSAM's ``GenericProjectionFactorCal3Fisheye``, the same constructor."""

    _calibration = "Cal3Fisheye"


class GenericStereoFactor3D(_CameraFactor, _stereo):
    """project(x·body_P_sensor, l, K) − z of GTSAM's StereoCamera ([uL, uR, v], a StereoPoint2),
    its error 2·fx where the point is not in front: GTSAM's ``GenericStereoFactor3D(measured,
    noiseModel, poseKey, landmarkKey, K[, throwCheirality, verboseCheirality][, body_P_sensor])``."""

    _what = "Stereo Cheirality Exception"
    _calibration = "Cal3_S2Stereo"


def _sfm_error(pose, l, K, z):
    """GTSAM's GeneralSFMFactor error: project(pose, l, K) − z, or 0 with zero Jacobians where
    the point is not in front of the camera (its ``catch (CheiralityException&)``)."""
    return ops.catch_cheirality(ops.project(pose, l, K) - z, np.zeros(2))


@factor("Pose3", "Cal3Bundler", "Point3", measured="Point2")
def BundlerProjectionFactor(x, K, l, z):
    """project(x, l, K) − z with K = [f, k1, k2] a variable (its principal point u0, v0 held
    with it): BAL's camera as a Pose3 and its Cal3Bundler, GTSAM's
    ``GeneralSFMFactorCal3Bundler`` on a ``PinholeCameraCal3Bundler``, whose error where the
    point is not in front of the camera is 0, with zero Jacobians."""
    return _sfm_error(x, l, K, z)


def _named(residual, name: str):
    residual.__name__ = residual.__qualname__ = name
    return residual


def _points(t: str) -> bool:
    return t in ("Point2", "Point3")


@cache
def between_kind(t: str):
    """The kind of GTSAM's ``BetweenFactor<t>`` (``t`` a group or a point's name): Log(z⁻¹·x1⁻¹·x2)
    (GTSAM's Local(z, between(x1, x2))), of points (x2 − x1) − z."""
    def residual(x1, x2, z):
        if _points(t):
            return (x2 - x1) - z
        return z.localCoordinates(x1.between(x2))

    cls = factor(t, t, measured=t)(_named(residual, f"BetweenFactor{t}"))
    cls.kind.relative = True
    return cls


@cache
def prior_kind(t: str):
    """The kind of GTSAM's ``PriorFactor<t>`` (``t`` a group, a point or a camera's name): Log(z⁻¹·x)
    (GTSAM's −Local(x, z)), of a point x − z, of a camera z.localCoordinates(x)."""
    def residual(x, z):
        if _points(t):
            return x - z
        return z.localCoordinates(x)

    return factor(t, measured=t)(_named(residual, f"PriorFactor{t}"))


@cache
def pose_rotation_prior_kind(pose: str):
    """The kind of GTSAM's ``PoseRotationPrior2D/3D`` (``pose`` "Pose2" or "Pose3"): Log(z⁻¹·R(x))."""
    rotation = "Rot2" if pose == "Pose2" else "Rot3"

    def residual(x, z):
        return z.localCoordinates(x.rotation())

    return factor(pose, measured=rotation)(_named(residual, f"PoseRotationPrior{pose[-1]}D"))


@cache
def bearing_kind(pose: str):
    """The kind of GTSAM's ``BearingFactor2D/3D`` (``pose`` "Pose2" or "Pose3"): the bearing part
    of the bearing-range factors' error."""
    point, bearing = ("Point2", "Rot2") if pose == "Pose2" else ("Point3", "Unit3")

    def residual(x, l, z):
        return _bearing_error(x, l, z)

    return factor(pose, point, measured=bearing)(_named(residual, f"BearingFactor{pose[-1]}D"))


@cache
def camera_projection_kind(camera: str):
    """The kind of GTSAM's ``GeneralSFMFactor`` on a camera variable (``camera``
    "PinholeCameraCal3Bundler" or "PinholeCameraCal3_S2"): camera.project(l) − z, 0 where the
    point is not in front of the camera."""
    def residual(c, l, z):
        return _sfm_error(c.pose(), l, c.calibration(), z)

    return factor(camera, "Point3", measured="Point2")(
        _named(residual, "GeneralSFMFactor" + camera[len("PinholeCamera"):]))


def from_gtsam(f):
    """The ready factor equal to GTSAM's factor ``f`` (same keys, measurement and noise model
    object): ``BearingRangeFactor2D``/``3D``, ``RangeFactor2D``/``3D``/``Pose2``/``Pose3``,
    ``GPSFactor``; ``f`` itself for any other.  Each of those ready factors' ``as_gtsam()`` is
    the inverse."""
    import gtsam

    name = type(f).__name__
    keys = [int(k) for k in f.keys()]
    noise = f.noiseModel()
    if name in ("BearingRangeFactor2D", "BearingRangeFactor3D"):
        br = f.measured()
        cls = BearingRangeFactor2D if name.endswith("2D") else BearingRangeFactor3D
        return cls(keys[0], keys[1], br.bearing(), br.range(), noise)
    if name in ("RangeFactor2D", "RangeFactor3D", "RangeFactorPose2", "RangeFactorPose3"):
        return globals()[name](keys[0], keys[1], f.measured(), noise)
    if isinstance(f, gtsam.GPSFactor):
        return GPSFactor(keys[0], f.measurementIn(), noise)
    return f
