"""GTSAM's factors with a twin kind in the smoother: linearized by the kind's kernel, not by GTSAM.

A visual SLAM run as GTSAM's VisualISAM2Example writes it (GTSAM's projection factors, with and
without a body pose, its priors), updated pose by pose, relinearizing often: every estimate
equals ``gtsam.ISAM2``'s, and GTSAM's linearization is called for no factor that has a twin;
a factor whose noise model the kernels do not take (a robust one) is still GTSAM's to linearize.
The rows the smoother stores keep their variables in the kind's order, which for GeneralSFMFactor2
is not GTSAM's key order.
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


def test_native_rows_give_columns_in_the_order_of_their_keys():
    """What the smoother stores (``NativeRows``): each factor's [A | b] with A's column blocks
    in the order :meth:`NativeRows.keys` gives, equal to GTSAM's linearization of the factor
    reordered that way, for twins whose kind orders the keys as GTSAM does and one that does not."""
    rng = np.random.default_rng(11)
    pose = gtsam.PinholeCameraCal3_S2.Lookat(np.array([10.0, 2.0, 3.0]), gtsam.Point3(0, 0, 0),
                                             np.array([0.0, 0.0, 1.0]), gtsam.Cal3_S2()).pose()
    point = rng.normal(0, 1, 3)
    bundler = gtsam.Cal3Bundler(400.0, 0.01, -1e-3, 0.0, 0.0)
    theta = gtsam.Values()
    theta.insert(X(0), pose)
    theta.insert(L(0), point)
    theta.insert(C(0), bundler)
    theta.insert(X(1), gtsam.Pose2(0.3, -0.2, 0.4))
    theta.insert(L(1), np.array([2.0, 1.5]))
    pixel, two = gtsam.noiseModel.Isotropic.Sigma(2, 0.7), gtsam.noiseModel.Diagonal.Sigmas([0.1, 0.3])
    z = gtsam.PinholeCameraCal3Bundler(pose, bundler).project(point) + rng.normal(0, 1, 2)
    factors = [
        gtsam.GeneralSFMFactor2Cal3Bundler(z, pixel, X(0), L(0), C(0)),
        gtsam.GenericProjectionFactorCal3_S2(np.array([300.0, 200.0]), pixel, X(0), L(0),
                                             gtsam.Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)),
        gtsam.BearingRangeFactor2D(X(1), L(1), gtsam.Rot2(0.2), 2.0, two),
        gtsam.BetweenFactorPoint3(L(0), L(0) + 7, rng.normal(0, 1, 3), gtsam.noiseModel.Isotropic.Sigma(3, 0.2)),
    ]
    theta.insert(L(0) + 7, rng.normal(0, 1, 3))
    rows = gtsam_objects.NativeRows()
    dims = {int(k): len(theta.zeroVectors().at(k)) for k in theta.keys()}
    for f in factors:
        ((positions, J),) = rows([f], theta)
        keys = rows.keys(f)
        assert sorted(keys) == sorted(int(k) for k in f.keys())
        A, b = f.linearize(theta).jacobian()
        offsets = np.cumsum([0] + [dims[int(k)] for k in f.keys()])
        block = {int(k): A[:, offsets[i]:offsets[i + 1]] for i, k in enumerate(f.keys())}
        expected = np.concatenate([block[k] for k in keys] + [b[:, None]], axis=1)
        scale = max(1.0, float(np.max(np.abs(expected))))
        np.testing.assert_allclose(J[0], expected, rtol=0, atol=1e-9 * scale, err_msg=type(f).__name__)
    assert rows.keys(factors[0]) == [X(0), C(0), L(0)]  # the kind's order: pose, calibration, point


def test_equal_noise_models_share_one_whitening():
    """Factors each given its own, equal, noise model object (a loop that makes one per factor)
    share one stored whitening: the table does not grow with the factors (each addition would
    copy it), and the rows still equal GTSAM's linearization."""
    K = gtsam.Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)
    theta = gtsam.Values()
    theta.insert(X(0), gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.0, -10.0])))
    factors = []
    for j in range(40):
        theta.insert(L(j), np.array([0.1 * j - 2.0, 0.05 * j, 1.0]))
        sigma = 1.0 if j % 2 else 2.0
        factors.append(gtsam.GenericProjectionFactorCal3_S2(np.array([320.0 + j, 240.0 - j]),
                                                            gtsam.noiseModel.Isotropic.Sigma(2, sigma), X(0), L(j), K))
    rows = gtsam_objects.NativeRows()
    ((positions, J),) = rows(factors, theta)
    (kind_rows,) = rows._kinds.values()
    assert kind_rows.whitenings == 2
    for q, f in zip(positions.tolist(), factors):
        A, b = f.linearize(theta).jacobian()
        np.testing.assert_allclose(J[q], np.concatenate([A, b[:, None]], axis=1), rtol=0,
                                   atol=1e-9 * max(1.0, np.abs(A).max()))
