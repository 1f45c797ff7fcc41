"""Bundle adjustment in the large (BAL files, ``gtsam.SfmData``) with the ready projection factor.

:func:`graph_of` builds, from a scene GTSAM has read (``gtsam.SfmData.FromBalFile``), the problem
GTSAM's ``SFMExample_bal.py`` builds with ``GeneralSFMFactorCal3Bundler`` on
``PinholeCameraCal3Bundler`` variables, in our variables: each camera i as its pose (key
``x_i``, a Pose3) and its calibration [f, k1, k2] (key ``k_i``, a Cal3Bundler, its principal point held),
each point j as ``p_j``; one :class:`~lie_factors.expressions.ready.BundlerProjectionFactor` per
observation, and the same priors as the example (camera 0 with σ = 0.1 in each of its 9
coordinates, point 0 with σ = 0.1).  A camera's 9 coordinates are its pose's 6 then its
calibration's 3, retracted apart (GTSAM's ``PinholeCamera::retract``), so both problems have the
same cost function and optimum.
"""

from __future__ import annotations

import gtsam

from . import factor
from .ready import BundlerProjectionFactor

__all__ = ["graph_of", "gtsam_graph_of", "CalibrationPrior", "PointPrior", "pose_key", "calibration_key",
           "point_key"]


def pose_key(i: int) -> int:
    return gtsam.symbol("x", i)


def calibration_key(i: int) -> int:
    return gtsam.symbol("k", i)


def point_key(j: int) -> int:
    return gtsam.symbol("p", j)


@factor("Cal3Bundler", measured="Cal3Bundler")
def CalibrationPrior(K, z):
    """K − z: a prior on a calibration's [f, k1, k2] (GTSAM's local coordinates of a Cal3Bundler)."""
    return K - z


@factor("Point3", measured="Point3")
def PointPrior(p, z):
    """p − z: GTSAM's ``PriorFactorPoint3``."""
    return p - z


def graph_of(scene: "gtsam.SfmData", sigma_pixel: float = 1.0, sigma_prior: float = 0.1):
    """(graph, initial Values) of ``scene`` in our variables (module docstring)."""
    from ..factors import PriorFactorPose3

    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Isotropic.Sigma(2, sigma_pixel)
    for j in range(scene.numberTracks()):
        track = scene.track(j)
        for m in range(track.numberMeasurements()):
            i, uv = track.measurement(m)
            graph.add(BundlerProjectionFactor(pose_key(i), calibration_key(i), point_key(j), uv, noise))
    camera0 = scene.camera(0)
    graph.add(PriorFactorPose3(pose_key(0), camera0.pose(), gtsam.noiseModel.Isotropic.Sigma(6, sigma_prior)))
    graph.add(CalibrationPrior(calibration_key(0), camera0.calibration(), gtsam.noiseModel.Isotropic.Sigma(3, sigma_prior)))
    graph.add(PointPrior(point_key(0), scene.track(0).point3(), gtsam.noiseModel.Isotropic.Sigma(3, sigma_prior)))
    initial = gtsam.Values()
    for i in range(scene.numberCameras()):
        camera = scene.camera(i)
        initial.insert(pose_key(i), camera.pose())
        initial.insert(calibration_key(i), camera.calibration())
    for j in range(scene.numberTracks()):
        initial.insert(point_key(j), scene.track(j).point3())
    return graph, initial


def gtsam_graph_of(scene: "gtsam.SfmData", sigma_pixel: float = 1.0, sigma_prior: float = 0.1):
    """(graph, initial Values) of ``scene`` as GTSAM's ``SFMExample_bal.py`` builds them: cameras
    at keys i (``PinholeCameraCal3Bundler``), points at ``p_j``."""
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Isotropic.Sigma(2, sigma_pixel)
    for j in range(scene.numberTracks()):
        track = scene.track(j)
        for m in range(track.numberMeasurements()):
            i, uv = track.measurement(m)
            graph.add(gtsam.GeneralSFMFactorCal3Bundler(uv, noise, i, point_key(j)))
    graph.push_back(gtsam.PriorFactorPinholeCameraCal3Bundler(0, scene.camera(0),
                                                             gtsam.noiseModel.Isotropic.Sigma(9, sigma_prior)))
    graph.push_back(gtsam.PriorFactorPoint3(point_key(0), scene.track(0).point3(),
                                            gtsam.noiseModel.Isotropic.Sigma(3, sigma_prior)))
    initial = gtsam.Values()
    for i in range(scene.numberCameras()):
        initial.insert(i, scene.camera(i))
    for j in range(scene.numberTracks()):
        initial.insert(point_key(j), scene.track(j).point3())
    return graph, initial
