"""GTSAM's factors with a twin kind in the smoother: linearized by the kind's kernel, not by GTSAM.

A visual SLAM run as GTSAM's VisualISAM2Example writes it (GTSAM's projection factors, with and
without a body pose, its priors), updated pose by pose, relinearizing often: every estimate
equals ``gtsam.ISAM2``'s, and GTSAM's linearization is called for no factor that has a twin;
a factor whose noise model the kernels do not take (a robust one) is still GTSAM's to linearize.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import C, L, X

from lie_factors.incremental import Smoother, gtsam_objects


class _Counted:
    def __init__(self, fn):
        self.fn, self.calls = fn, []

    def __call__(self, f, theta):
        self.calls.append(type(f).__name__)
        return self.fn(f, theta)


def _steps(seed: int, robust: bool):
    """(factors, values) per update: 8 poses around a cube of 8 landmarks, the first two in one."""
    rng = np.random.default_rng(seed)
    K = gtsam.Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    pixel = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    if robust:
        pixel = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345), pixel)
    body = gtsam.Pose3(gtsam.Rot3.Rz(0.05), np.array([0.1, 0.0, 0.02]))
    points = [np.array(p, dtype=float) for p in
              [(10, 10, 10), (-10, 10, 10), (-10, -10, 10), (10, -10, 10), (10, 10, -10), (-10, 10, -10),
               (-10, -10, -10), (10, -10, -10)]]
    up, target = np.array([0.0, 0.0, 1.0]), gtsam.Point3(0, 0, 0)
    poses = [gtsam.PinholeCameraCal3_S2.Lookat(np.array([40 * np.cos(t), 40 * np.sin(t), 10.0]), target, up,
                                              K).pose() for t in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    steps = []
    for i, pose in enumerate(poses):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for j, p in enumerate(points):
            with_body = j % 3 == 0
            camera = gtsam.PinholeCameraCal3_S2(pose.compose(body) if with_body else pose, K)
            z = camera.project(p) + rng.normal(scale=0.5, size=2)
            if with_body:
                graph.add(gtsam.GenericProjectionFactorCal3_S2(z, pixel, X(i), L(j), K, body))
            else:
                graph.add(gtsam.GenericProjectionFactorCal3_S2(z, pixel, X(i), L(j), K))
        if i == 0:
            graph.add(gtsam.PriorFactorPose3(X(0), pose, gtsam.noiseModel.Diagonal.Sigmas([0.3] * 3 + [0.1] * 3)))
            graph.add(gtsam.PriorFactorPoint3(L(0), points[0], gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
            for j, p in enumerate(points):
                values.insert(L(j), p + rng.normal(scale=0.3, size=3))
        values.insert(X(i), pose.compose(gtsam.Pose3(gtsam.Rot3.Rodrigues(*rng.normal(scale=0.05, size=3)),
                                                     rng.normal(scale=0.2, size=3))))
        steps.append((graph, values))
    graph, values = steps.pop(0)  # one camera leaves the landmarks' depths open: the first update has two
    graph.push_back(steps[0][0])
    values.insert(steps[0][1])
    steps[0] = (graph, values)
    return steps


def _params():
    p = gtsam.ISAM2Params()
    p.setRelinearizeThreshold(0.01)
    p.relinearizeSkip = 1
    return p


def _deviation(a: gtsam.Values, b: gtsam.Values) -> float:
    d = a.localCoordinates(b)
    return max(float(np.max(np.abs(d.at(k)))) for k in a.keys())


@pytest.mark.parametrize("robust", [False, True])
def test_projection_factors_run_in_the_kernels_and_match_isam2(monkeypatch, robust):
    counted = _Counted(gtsam_objects.native_jacobian)
    monkeypatch.setattr(gtsam_objects, "native_jacobian", counted)
    isam, ours = gtsam.ISAM2(_params()), Smoother(_params())
    for graph, values in _steps(3, robust):
        isam.update(graph, values)
        ours.update(graph, values)
        assert _deviation(isam.calculateEstimate(), ours.calculateEstimate()) < 1e-9
    names = set(counted.calls)
    if robust:  # the robust projection factors: GTSAM's linearization, at each relinearization too
        assert names == {"GenericProjectionFactorCal3_S2"} and len(counted.calls) > 64
    else:
        assert not counted.calls


def _bundler_steps(seed: int):
    """(factors, values) per update of GeneralSFMFactor2Cal3Bundler, whose keys (pose, point,
    calibration) are in another order than its twin kind's (pose, calibration, point)."""
    rng = np.random.default_rng(seed)
    K = gtsam.Cal3Bundler(50.0, 1e-3, 1e-5, 0.0, 0.0)
    cameras = [gtsam.PinholeCameraCal3Bundler(gtsam.PinholeCameraCal3_S2.Lookat(
        np.array([40 * np.cos(t), 40 * np.sin(t), 10.0]), gtsam.Point3(0, 0, 0), np.array([0.0, 0.0, 1.0]),
        gtsam.Cal3_S2()).pose(), K) for t in np.linspace(0, np.pi, 6)]
    points = [rng.uniform(-8, 8, size=3) for _ in range(8)]
    pixel = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    steps = []
    for i, camera in enumerate(cameras):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for j, p in enumerate(points):
            z = camera.project(p) + rng.normal(scale=0.3, size=2)
            graph.add(gtsam.GeneralSFMFactor2Cal3Bundler(z, pixel, X(i), L(j), C(0)))
        if i == 0:
            graph.add(gtsam.PriorFactorPose3(X(0), camera.pose(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
            graph.add(gtsam.PriorFactorPoint3(L(0), points[0], gtsam.noiseModel.Isotropic.Sigma(3, 0.01)))
            graph.add(gtsam.PriorFactorCal3Bundler(C(0), K, gtsam.noiseModel.Diagonal.Sigmas([1.0, 1e-3, 1e-5])))
            values.insert(C(0), gtsam.Cal3Bundler(50.5, 0.0, 0.0, 0.0, 0.0))
            for j, p in enumerate(points):
                values.insert(L(j), p + rng.normal(scale=0.1, size=3))
        values.insert(X(i), camera.pose().compose(gtsam.Pose3(gtsam.Rot3.Rodrigues(*rng.normal(scale=0.01, size=3)),
                                                              rng.normal(scale=0.05, size=3))))
        steps.append((graph, values))
    graph, values = steps.pop(0)
    graph.push_back(steps[0][0])
    values.insert(steps[0][1])
    steps[0] = (graph, values)
    return steps


def test_a_twin_whose_keys_gtsam_orders_otherwise_matches_isam2(monkeypatch):
    """The block factor holds a twin's rows with its variables in the kind's order, not in the
    order of GTSAM's keys (GeneralSFMFactor2's point and calibration, both of dimension 3)."""
    counted = _Counted(gtsam_objects.native_jacobian)
    monkeypatch.setattr(gtsam_objects, "native_jacobian", counted)
    isam, ours = gtsam.ISAM2(_params()), Smoother(_params())
    for graph, values in _bundler_steps(5):
        isam.update(graph, values)
        ours.update(graph, values)
        assert _deviation(isam.calculateEstimate(), ours.calculateEstimate()) < 1e-9
    assert set(counted.calls) == {"PriorFactorCal3Bundler"}  # a class without a twin: GTSAM's linearization
