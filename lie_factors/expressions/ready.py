"""Ready factors, each a few lines of the vocabulary, named and constructed as GTSAM's own.

Each is a factor kind (:func:`~lie_factors.expressions.kind.factor`) whose residual is GTSAM's
error of the factor of the same name; the class takes GTSAM's constructor arguments:

=================================  ==============================================  =========================
class (GTSAM's constructor)        residual                                        GTSAM's factor
=================================  ==============================================  =========================
``GPSFactor(key, gpsIn, model)``   translation(x) − z                              ``gtsam.GPSFactor``
``PoseTranslationPrior2D/3D``      translation(x) − z                              ``PoseTranslationPrior2D/3D``
``PoseToPointFactor2D/3D``         transformTo(x, l) − z                           C++ ``PoseToPointFactor``
``RangeFactor2D/3D``               ‖transformTo(x, l)‖ − r                         ``RangeFactor2D/3D``
``RangeFactorPose2/Pose3``         ‖transformTo(x1, t(x2))‖ − r                    ``RangeFactorPose2/3``
``BearingRangeFactor2D``           [Log(b⁻¹·bearing(x, l)), range(x, l) − r]       ``BearingRangeFactor2D``
``BearingRangeFactor3D``           [−bearing(x, l).localCoordinates(b), range − r] ``BearingRangeFactor3D``
``GenericProjectionFactorCal3_S2`` project(x, l, K) − z                            the same
``BundlerProjectionFactor``        project(x, l, K) − z, K = [f, k1, k2] a         ``GeneralSFMFactorCal3Bundler``
                                   variable                                        (camera = pose and K)
=================================  ==============================================  =========================
"""

from __future__ import annotations

import numpy as np

from . import ops
from .kind import factor

__all__ = ["GPSFactor", "PoseTranslationPrior2D", "PoseTranslationPrior3D", "PoseToPointFactor2D",
           "PoseToPointFactor3D", "RangeFactor2D", "RangeFactor3D", "RangeFactorPose2", "RangeFactorPose3",
           "BearingRangeFactor2D", "BearingRangeFactor3D", "GenericProjectionFactorCal3_S2",
           "BundlerProjectionFactor", "from_gtsam"]


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

    return type(name, (kind,), {"__init__": __init__, "measured": measured, "__module__": __name__, "__doc__":
                                f"‖transformTo(x, l)‖ − r: GTSAM's ``{gtsam_name}(key1, key2, measured, noiseModel)``."})


RangeFactor2D = _range_class(_range2, "RangeFactor2D", "RangeFactor2D")
RangeFactor3D = _range_class(_range3, "RangeFactor3D", "RangeFactor3D")
RangeFactorPose2 = _range_class(_range_pose2, "RangeFactorPose2", "RangeFactorPose2")
RangeFactorPose3 = _range_class(_range_pose3, "RangeFactorPose3", "RangeFactorPose3")


@factor("Pose2", "Point2", bearing="Rot2", range="Vector1")
def _bearing_range2(x, l, bearing, range):
    return ops.stack(bearing.localCoordinates(x.bearing(l)), x.range(l) - range)


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


@factor("Pose3", "Point3", bearing="Unit3", range="Vector1")
def _bearing_range3(x, l, bearing, range):
    # GTSAM's error of a bearing: −Local(predicted, measured), in the predicted direction's basis
    return ops.stack(-x.bearing(l).localCoordinates(bearing), x.range(l) - range)


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


@factor("Pose3", "Point3", measured="Point2", K="Cal3_S2")
def _projection(x, l, z, K):
    return ops.project(x, l, K) - z


class GenericProjectionFactorCal3_S2(_projection):
    """project(x, l, K) − z (a pinhole camera at x, z forward): GTSAM's
    ``GenericProjectionFactorCal3_S2(measured, noiseModel, poseKey, pointKey, k)``."""

    def __init__(self, measured, noiseModel, poseKey, pointKey, k):
        super().__init__(poseKey, pointKey, measured, noiseModel, K=k)


@factor("Pose3", "Cal3Bundler", "Point3", measured="Point2")
def BundlerProjectionFactor(x, K, l, z):
    """project(x, l, K) − z with K = [f, k1, k2] a variable: BAL's camera as a Pose3 and its
    Cal3Bundler, GTSAM's ``GeneralSFMFactorCal3Bundler`` on a ``PinholeCameraCal3Bundler``."""
    return ops.project(x, l, K) - z


def from_gtsam(f):
    """The ready factor equal to GTSAM's factor ``f`` (same keys, measurement and noise model
    object): ``BearingRangeFactor2D``/``3D``, ``RangeFactor2D``/``3D``/``Pose2``/``Pose3``,
    ``GPSFactor``; ``f`` itself for any other."""
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
