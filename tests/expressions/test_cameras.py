"""Projections: every calibration (Cal3_S2, Cal3Bundler with its principal point, Cal3DS2,
Cal3Fisheye) and GTSAM's stereo camera (Cal3_S2Stereo), their values and Jacobians against GTSAM's
own (PinholeCamera, uncalibrate with its Jacobians, StereoCamera) and Richardson differences,
near the optical axis and across Cal3Fisheye's series threshold; a point not in front of the
camera raising GTSAM's CheiralityException from a user's kind, in GTSAM and in lf.optimize."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

import lie_factors as lf
from lie_factors.errors import CheiralityException, LieFactorsError
from lie_factors.expressions import camera, ops
from lie_factors.expressions.types import calibration_array
from support.kinds import evaluate, relative_error, richardson

K_S2 = gtsam.Cal3_S2(500.0, 480.0, 0.1, 320.0, 240.0)
K_BUNDLER = gtsam.Cal3Bundler(520.0, 0.08, -0.015, 310.0, 235.0)
K_DS2 = gtsam.Cal3DS2(500.0, 480.0, 0.1, 320.0, 240.0, -0.2, 0.05, 1e-3, -2e-3)
K_FISHEYE = gtsam.Cal3Fisheye(400.0, 410.0, 0.2, 330.0, 250.0, -0.01, 0.003, -4e-4, 1e-5)
K_STEREO = gtsam.Cal3_S2Stereo(500.0, 480.0, 0.1, 320.0, 240.0, 0.3)
CALIBRATIONS = (K_S2, K_BUNDLER, K_DS2, K_FISHEYE, K_STEREO)


@lf.factor("Pose3", "Point3", "Cal3_S2", "Cal3Bundler", "Cal3DS2", "Cal3Fisheye", "Cal3_S2Stereo")
def cameras(x, p, a, b, c, d, s):
    return ops.stack(*(ops.project(x, p, K) for K in (a, b, c, d, s)))


def gtsam_projections(x, p):
    pose = gtsam.Pose3(x)
    return np.concatenate([gtsam.PinholeCameraCal3_S2(pose, K_S2).project(p),
                           gtsam.PinholeCameraCal3Bundler(pose, K_BUNDLER).project(p),
                           gtsam.PinholeCameraCal3DS2(pose, K_DS2).project(p),
                           gtsam.PinholeCameraCal3Fisheye(pose, K_FISHEYE).project(p),
                           gtsam.StereoCamera(pose, K_STEREO).project(p).vector()])


def _values(x, p):
    return [x, p] + [calibration_array(type(K).__name__, K) for K in CALIBRATIONS]


def _pose(rng):
    return gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.5, 3)), rng.normal(0, 1, 3)).matrix()


def test_every_calibration_and_the_stereo_camera_against_gtsams_and_differences():
    rng = np.random.default_rng(10)
    for angle_of_view in (0.0, 1e-6, 0.3, 0.9):  # the point on the optical axis, near it, and off it
        x = _pose(rng)
        direction = np.array([np.cos(rng.uniform(0, 2 * np.pi)), np.sin(rng.uniform(0, 2 * np.pi)), 0.0])
        local = np.tan(angle_of_view) * direction + np.array([0.0, 0.0, 1.0])
        p = x[:3, :3] @ (rng.uniform(2, 5) * local) + x[:3, 3]
        values = _values(x, p)
        e, H = evaluate(cameras.kind, values, [])
        np.testing.assert_allclose(e, gtsam_projections(x, p), rtol=0, atol=1e-9)
        for j, (a, n) in enumerate(zip(H, richardson(cameras.kind, values, []))):
            assert relative_error(a, n) <= 1e-8, (angle_of_view, j, relative_error(a, n))


@pytest.mark.parametrize("K", [K_S2, K_BUNDLER, K_DS2, K_FISHEYE], ids=lambda K: type(K).__name__)
def test_projection_against_gtsams_jacobians_at_and_near_the_optical_axis(K):
    """A camera at the identity seeing (pn, 1), pn at radii 0, 1e-12, just below and above
    Cal3Fisheye's series threshold (1e-8), 1e-3 and 0.6: the pixels and the three Jacobians of
    GTSAM's ``PinholeCamera<K>.project(point, Dpose, Dpoint, Dcal)`` (the wheel's
    ``Cal3Bundler.uncalibrate`` is bound to Cal3f's, which leaves out the distortion: the camera's
    is the reference), and Richardson differences across the axis."""
    name = type(K).__name__
    kind = lf.factor("Pose3", "Point3", name)(lambda x, q, c: ops.project(x, q, c)).kind
    cam = getattr(gtsam, f"PinholeCamera{name}")(gtsam.Pose3(), K)
    for r in (0.0, 1e-12, 0.99 * camera.FISHEYE_SERIES, 1.01 * camera.FISHEYE_SERIES, 1e-3, 0.6):
        q = np.array([0.6 * r, -0.8 * r, 1.0])
        Dpose, Dpoint, Dcal = (np.zeros((2, n), order="F") for n in (6, 3, K.dim()))
        uv = cam.project(q, Dpose, Dpoint, Dcal)
        values = [np.eye(4), q, calibration_array(name, K)]
        e, H = evaluate(kind, values, [])
        np.testing.assert_allclose(e, uv, rtol=0, atol=1e-12 * np.abs(uv).max())
        for ours, theirs in zip(H, (Dpose, Dpoint, Dcal)):
            np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-9 * max(1.0, np.abs(theirs).max()))
        for ours, numeric in zip(H, richardson(kind, values, [])):  # smooth through the axis: steps of 1e-3
            assert relative_error(ours, numeric) <= 1e-8, (r, relative_error(ours, numeric))


def test_a_cal3bundlers_principal_point_is_honoured_in_gtsam_and_in_lf_optimize():
    """BundlerProjectionFactor with u0, v0 ≠ 0 equals GTSAM's GeneralSFMFactorCal3Bundler on the
    same camera (error and Jacobians), and a small bundle adjustment reaches GTSAM's optimum both
    in GTSAM's LM and in lf.optimize, the principal points unmoved."""
    from lie_factors.expressions import ready
    from lie_factors.expressions.bal import CalibrationPrior

    rng = np.random.default_rng(11)
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    poses = [gtsam.Pose3(gtsam.Rot3.Ypr(0.1 * i, 0.05, -0.02 * i), np.array([0.5 * i, 0.1, -6.0])) for i in range(3)]
    points = [rng.uniform(-1.5, 1.5, 3) for _ in range(8)]
    calibrations = [gtsam.Cal3Bundler(500.0 + 10 * i, 0.05, -0.01, 300.0 + i, 200.0 - i) for i in range(3)]
    ours, theirs = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    start, start_theirs = gtsam.Values(), gtsam.Values()
    X, Kk, P, C = (gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.K, gtsam.symbol_shorthand.P,
                   gtsam.symbol_shorthand.C)
    for i, (pose, K) in enumerate(zip(poses, calibrations)):
        cam = gtsam.PinholeCameraCal3Bundler(pose, K)
        for j, p in enumerate(points):
            z = cam.project(p) + rng.normal(0, 0.5, 2)
            ours.add(ready.BundlerProjectionFactor(X(i), Kk(i), P(j), z, noise))
            theirs.add(gtsam.GeneralSFMFactorCal3Bundler(z, noise, C(i), P(j)))
        moved = gtsam.Pose3(pose.rotation(), pose.translation() + rng.normal(0, 0.05, 3))
        start.insert(X(i), moved)
        start.insert(Kk(i), K)
        start_theirs.insert(C(i), gtsam.PinholeCameraCal3Bundler(moved, K))
    for j, p in enumerate(points):
        start.insert(P(j), p + rng.normal(0, 0.05, 3))
        start_theirs.insert(P(j), start.atPoint3(P(j)))
    for i in range(ours.size()):
        a, b = ours.at(i), theirs.at(i)
        np.testing.assert_allclose(a.unwhitenedError(start), b.unwhitenedError(start_theirs), atol=1e-9)
        A, B = a.linearize(start).jacobian()[0], b.linearize(start_theirs).jacobian()[0]
        np.testing.assert_allclose(A, B, atol=1e-9 * np.abs(B).max())  # [pose, f k1 k2 | point] both
    prior = gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)
    ours.add(gtsam.PriorFactorPose3(X(0), start.atPose3(X(0)), prior))
    ours.add(gtsam.PriorFactorPose3(X(1), start.atPose3(X(1)), prior))
    for i in range(3):
        ours.add(ready.PoseTranslationPrior3D(X(i), start.atPose3(X(i)).translation(),
                                              gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
        ours.add(CalibrationPrior(Kk(i), calibrations[i], gtsam.noiseModel.Diagonal.Sigmas(np.array([5.0, 0.01, 0.01]))))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-12)
    reference = gtsam.LevenbergMarquardtOptimizer(ours, start, params).optimize()
    result = lf.optimize(ours, start)
    assert result.error == pytest.approx(ours.error(reference), rel=1e-7)
    for i, K in enumerate(calibrations):
        got = result.values.atCal3Bundler(Kk(i))
        assert (got.px(), got.py()) == (K.px(), K.py())
        assert (reference.atCal3Bundler(Kk(i)).px(), reference.atCal3Bundler(Kk(i)).py()) == (K.px(), K.py())
        np.testing.assert_allclose(calibration_array("Cal3Bundler", got),
                                   calibration_array("Cal3Bundler", reference.atCal3Bundler(Kk(i))), rtol=1e-6)


@lf.factor("Pose3", "Point3", measured="Point2", K="Cal3_S2")
def reprojection(x, p, z, K):
    return ops.project(x, p, K) - z


@pytest.mark.parametrize("depth", [0.0, -1.0, -1e-300])
def test_a_point_not_in_front_of_the_camera_raises_gtsams_cheirality_exception(depth):
    """GTSAM's PinholeCamera.project raises its CheiralityException (a RuntimeError) for a point
    on or behind the camera plane; so does a kind's ops.project, naming the line and the keys,
    evaluated by GTSAM, by lf.optimize, and as the residual's single evaluation."""
    x, p = gtsam.Pose3(), np.array([0.1, 0.2, depth])
    with pytest.raises(RuntimeError, match="CheiralityException"):
        gtsam.PinholeCameraCal3_S2(x, K_S2).project(p)
    f = reprojection(gtsam.symbol("x", 1), gtsam.symbol("l", 4), np.array([300.0, 200.0]),
                     gtsam.noiseModel.Isotropic.Sigma(2, 1.0), K=K_S2)
    values = gtsam.Values()
    values.insert(gtsam.symbol("x", 1), x)
    values.insert(gtsam.symbol("l", 4), p)
    for call in (f.error, f.linearize):
        with pytest.raises(CheiralityException, match=r"reprojection on x1, l4: reprojection, line \d+: project: "
                                                      r"the point is not in front of the camera") as err:
            call(values)
        assert isinstance(err.value, RuntimeError) and isinstance(err.value, LieFactorsError)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(f)
    graph.add(gtsam.PriorFactorPose3(gtsam.symbol("x", 1), x, gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
    graph.add(gtsam.PriorFactorPoint3(gtsam.symbol("l", 4), p, gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    with pytest.raises(CheiralityException):
        lf.optimize(graph, values)  # never a silent NaN result
    with pytest.raises(CheiralityException):
        gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()


def test_a_residual_that_is_not_finite_is_an_error_not_a_nan_result():
    from lie_factors.errors import EvaluationError

    kind = lf.factor("Point3")(lambda p: p / p.norm() - 1.0)  # 0/0 at the origin, where GTSAM's would be NaN
    f = kind(gtsam.symbol("p", 0), gtsam.noiseModel.Unit.Create(3))
    values = gtsam.Values()
    values.insert(gtsam.symbol("p", 0), np.zeros(3))
    with pytest.raises(EvaluationError, match="division by zero"):
        f.error(values)
    unit = lf.factor("Point3", bearing="Unit3")(lambda p, b: b.localCoordinates(ops.bearing(p)))
    g = unit(gtsam.symbol("p", 0), gtsam.noiseModel.Unit.Create(2), bearing=gtsam.Unit3(np.array([0.0, 0.0, 1.0])))
    with pytest.raises(EvaluationError, match="p0: .*the residual is not finite at these values"):
        g.error(values)
