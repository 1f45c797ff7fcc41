"""The ready factors against GTSAM's C++ factors of the same name: the error to 1e-12, the Jacobians
to 1e-9 (relative to their scale), on drawn poses, points and measurements."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from lie_factors.errors import InputError
from lie_factors.expressions import ready

RNG_SEEDS = range(8)


def pose2(rng):
    return gtsam.Pose2(*rng.normal(0, 2, 2), rng.uniform(-3, 3))


def pose3(rng):
    return gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 1, 3)), rng.normal(0, 2, 3))


def _compare(ours, theirs, values):
    """Error and (whitened, concatenated) Jacobians of two factors on the same keys at ``values``."""
    e_ours, e_theirs = ours.unwhitenedError(values), theirs.unwhitenedError(values)
    np.testing.assert_allclose(e_ours, e_theirs, rtol=0, atol=1e-12 * max(1.0, np.max(np.abs(e_theirs))))
    A = ours.linearize(values)
    B = theirs.linearize(values)
    ja, jb = A.jacobian()[0], B.jacobian()[0]
    scale = max(1.0, float(np.max(np.abs(jb))))
    np.testing.assert_allclose(ja, jb, rtol=0, atol=1e-9 * scale)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_position_priors(seed):
    rng = np.random.default_rng(seed)
    v = gtsam.Values()
    x3, x2 = pose3(rng), pose2(rng)
    v.insert(1, x3)
    v.insert(2, x2)
    z3, z2 = rng.normal(size=3), rng.normal(size=2)
    n3, n2 = gtsam.noiseModel.Isotropic.Sigma(3, 0.5), gtsam.noiseModel.Isotropic.Sigma(2, 0.5)
    _compare(ready.GPSFactor(1, z3, n3), gtsam.GPSFactor(1, z3, n3), v)
    _compare(ready.PoseTranslationPrior3D(1, z3, n3), gtsam.PoseTranslationPrior3D(1, gtsam.Pose3(gtsam.Rot3(), z3), n3), v)
    _compare(ready.PoseTranslationPrior2D(2, z2, n2), gtsam.PoseTranslationPrior2D(2, gtsam.Pose2(z2[0], z2[1], 0.0), n2), v)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_ranges(seed):
    rng = np.random.default_rng(seed)
    v = gtsam.Values()
    v.insert(1, pose2(rng))
    v.insert(2, rng.normal(0, 3, 2))
    v.insert(3, pose3(rng))
    v.insert(4, rng.normal(0, 3, 3))
    v.insert(5, pose2(rng))
    v.insert(6, pose3(rng))
    r = rng.uniform(1, 5)
    n = gtsam.noiseModel.Isotropic.Sigma(1, 0.2)
    _compare(ready.RangeFactor2D(1, 2, r, n), gtsam.RangeFactor2D(1, 2, r, n), v)
    _compare(ready.RangeFactor3D(3, 4, r, n), gtsam.RangeFactor3D(3, 4, r, n), v)
    _compare(ready.RangeFactorPose2(1, 5, r, n), gtsam.RangeFactorPose2(1, 5, r, n), v)
    _compare(ready.RangeFactorPose3(3, 6, r, n), gtsam.RangeFactorPose3(3, 6, r, n), v)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_bearing_range_2d(seed):
    rng = np.random.default_rng(seed)
    v = gtsam.Values()
    x = pose2(rng)
    p = rng.normal(0, 4, 2)
    v.insert(1, x)
    v.insert(2, p)
    b = gtsam.Rot2(x.bearing(p).theta() + rng.normal(0, 0.3))
    r = x.range(p) + rng.normal(0, 0.2)
    n = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.1]))
    _compare(ready.BearingRangeFactor2D(1, 2, b, r, n), gtsam.BearingRangeFactor2D(1, 2, b, r, n), v)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_bearing_range_3d(seed):
    """GTSAM's error to 1e-12; its Jacobians are those of the predicted bearing in its own chart
    (an ExpressionFactor leaves out the derivative of Unit3's local coordinates), equal to the
    error's derivative where the error is zero: compared there, ours everywhere against differences."""
    rng = np.random.default_rng(seed)
    v = gtsam.Values()
    x = pose3(rng)
    p = rng.normal(0, 4, 3)
    v.insert(1, x)
    v.insert(2, p)
    n = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.05, 0.1]))
    seen = x.transformTo(p) + rng.normal(0, 0.3, 3)
    b, r = gtsam.Unit3(seen / np.linalg.norm(seen)), x.range(p) + rng.normal(0, 0.2)
    ours, theirs = ready.BearingRangeFactor3D(1, 2, b, r, n), gtsam.BearingRangeFactor3D(1, 2, b, r, n)
    e = theirs.unwhitenedError(v)
    np.testing.assert_allclose(ours.unwhitenedError(v), e, rtol=0, atol=1e-12 * max(1.0, np.max(np.abs(e))))
    exact = gtsam.Unit3(x.transformTo(p))
    _compare(ready.BearingRangeFactor3D(1, 2, exact, x.range(p), n),
             gtsam.BearingRangeFactor3D(1, 2, exact, x.range(p), n), v)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_pose_to_point(seed):
    rng = np.random.default_rng(seed)
    v = gtsam.Values()
    x3, x2 = pose3(rng), pose2(rng)
    p3, p2 = rng.normal(0, 3, 3), rng.normal(0, 3, 2)
    v.insert(1, x3)
    v.insert(2, p3)
    v.insert(3, x2)
    v.insert(4, p2)
    f3 = ready.PoseToPointFactor3D(1, 2, x3.transformTo(p3) + rng.normal(0, 0.1, 3), gtsam.noiseModel.Unit.Create(3))
    f2 = ready.PoseToPointFactor2D(3, 4, x2.transformTo(p2) + rng.normal(0, 0.1, 2), gtsam.noiseModel.Unit.Create(2))
    for f, x, p in ((f3, x3, p3), (f2, x2, p2)):
        H1 = np.zeros((len(p), 6 if len(p) == 3 else 3), order="F")
        H2 = np.zeros((len(p), len(p)), order="F")
        e = x.transformTo(p, H1, H2) - f.measured()
        lin = f.linearize(v)
        np.testing.assert_allclose(f.unwhitenedError(v), e, atol=1e-12)
        np.testing.assert_allclose(lin.jacobian()[0], np.hstack([H1, H2]), atol=1e-12)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_projection_cal3_s2(seed):
    rng = np.random.default_rng(seed)
    x = pose3(rng)
    p = x.transformFrom(np.array([rng.normal(), rng.normal(), rng.uniform(2, 6)]))
    K = gtsam.Cal3_S2(500.0, 480.0, 0.1, 320.0, 240.0)
    z = gtsam.PinholeCameraCal3_S2(x, K).project(p) + rng.normal(0, 2, 2)
    n = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    v = gtsam.Values()
    v.insert(1, x)
    v.insert(2, p)
    _compare(ready.GenericProjectionFactorCal3_S2(z, n, 1, 2, K), gtsam.GenericProjectionFactorCal3_S2(z, n, 1, 2, K), v)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_bundler_projection_equals_gtsams_camera_factor(seed):
    rng = np.random.default_rng(seed)
    x = pose3(rng)
    p = x.transformFrom(np.array([rng.normal(), rng.normal(), rng.uniform(2, 6)]))
    f, k1, k2 = 600.0 + rng.normal(0, 50), rng.normal(0, 0.1), rng.normal(0, 0.01)
    cam = gtsam.PinholeCameraCal3Bundler(x, gtsam.Cal3Bundler(f, k1, k2, 0.0, 0.0))
    z = cam.project(p) + rng.normal(0, 2, 2)
    n = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    ours = ready.BundlerProjectionFactor(1, 2, 3, z, n)
    v = gtsam.Values()
    v.insert(1, x)
    v.insert(2, gtsam.Cal3Bundler(f, k1, k2, 0.0, 0.0))
    v.insert(3, p)
    theirs = gtsam.GeneralSFMFactorCal3Bundler(z, n, 10, 3)
    w = gtsam.Values()
    w.insert(10, cam)
    w.insert(3, p)
    np.testing.assert_allclose(ours.unwhitenedError(v), theirs.unwhitenedError(w), atol=1e-10)
    A, B = ours.linearize(v).jacobian()[0], theirs.linearize(w).jacobian()[0]
    scale = np.max(np.abs(B))
    np.testing.assert_allclose(A, B, atol=1e-9 * scale)  # [pose, calibration | point] both


def test_ready_factors_check_their_measurements():
    with pytest.raises(InputError, match="not finite"):
        ready.GPSFactor(1, np.array([0.0, np.nan, 1.0]), gtsam.noiseModel.Unit.Create(3))
    with pytest.raises(InputError, match="a number"):
        ready.RangeFactor2D(1, 2, np.array([1.0, 2.0]), gtsam.noiseModel.Unit.Create(1))
    with pytest.raises(InputError, match="unit vector"):
        ready.BearingRangeFactor3D(1, 2, np.array([1.0, 1.0, 0.0]), 1.0, gtsam.noiseModel.Unit.Create(3))


# ----------------------------------------------------------------------- cameras and cheirality

_Z2 = np.array([300.0, 200.0])
_CAMERAS = [
    ("GenericProjectionFactorCal3_S2", gtsam.Cal3_S2(500.0, 480.0, 0.1, 320.0, 240.0), _Z2),
    ("GenericProjectionFactorCal3DS2", gtsam.Cal3DS2(500.0, 480.0, 0.1, 320.0, 240.0, -0.2, 0.05, 1e-3, -2e-3), _Z2),
    ("GenericProjectionFactorCal3Fisheye", gtsam.Cal3Fisheye(400.0, 410.0, 0.2, 330.0, 250.0, -0.01, 0.003, -4e-4,
                                                             1e-5), _Z2),
    ("GenericStereoFactor3D", gtsam.Cal3_S2Stereo(500.0, 480.0, 0.1, 320.0, 240.0, 0.3),
     gtsam.StereoPoint2(300.0, 280.0, 200.0)),
]
_BODY = gtsam.Pose3(gtsam.Rot3.Ypr(0.05, -0.1, 0.02), np.array([0.1, -0.05, 0.2]))
_OPTIONAL = [(), (_BODY,), (False, False), (False, False, _BODY)]
#: a body pose and camera whose frames are exact in binary: a point at depth exactly 0
_SHIFT = gtsam.Pose3(gtsam.Rot3(), np.array([0.5, -0.25, 0.125]))


def _outcome(f, values):
    try:
        return f.unwhitenedError(values), f.linearize(values).jacobian()
    except RuntimeError as exc:
        return type(exc), str(exc)


@pytest.mark.parametrize("name,K,z", _CAMERAS, ids=[c[0] for c in _CAMERAS])
def test_camera_factors_equal_gtsams_in_front_on_and_behind_the_camera(name, K, z):
    """GTSAM's constructor, each of its four signatures; the error and Jacobians of GTSAM's C++
    factor at points in front of the camera, on its plane (depth 0, exactly and through the body
    pose) and behind it: GTSAM's constant 2·fx with zero Jacobians where not in front."""
    rng = np.random.default_rng(20)
    x = pose3(rng)
    n = gtsam.noiseModel.Isotropic.Sigma(3 if "Stereo" in name else 2, 1.5)
    ours_cls, theirs_cls = getattr(ready, name), getattr(gtsam, name)
    for optional in _OPTIONAL + [(_SHIFT,), (False, False, _SHIFT)]:
        body = optional[-1] if optional and isinstance(optional[-1], gtsam.Pose3) else gtsam.Pose3()
        exact = body is _SHIFT or not optional or optional == (False, False)
        camera = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 2.0, -3.0])) if exact else x
        sensor = camera.compose(body)
        for depth in (3.0, 0.375, 0.0, -2.0 ** -30, -2.0) if exact else (3.0, 0.4, -1e-9, -2.0):
            local = np.array([0.375, -0.625, depth]) if exact else np.array([*rng.normal(0, 0.3, 2), depth])
            p = sensor.transformFrom(local)
            assert not exact or sensor.transformTo(p)[2] == depth
            v = gtsam.Values()
            v.insert(1, camera)
            v.insert(2, p)
            ours, theirs = ours_cls(z, n, 1, 2, K, *optional), theirs_cls(z, n, 1, 2, K, *optional)
            e_ours, (A, b) = _outcome(ours, v)
            e_theirs, (B, c) = _outcome(theirs, v)
            scale = max(1.0, float(np.max(np.abs(e_theirs))))
            np.testing.assert_allclose(e_ours, e_theirs, rtol=0, atol=1e-9 * scale)
            np.testing.assert_allclose(A, B, rtol=0, atol=1e-9 * max(1.0, float(np.max(np.abs(B)))))
            np.testing.assert_allclose(b, c, rtol=0, atol=1e-9 * scale)
            if depth <= 0.0:
                assert np.all(e_ours == 2.0 * K.fx()) and not A.any()
        assert ours.body_P_sensor() is (body if optional and isinstance(optional[-1], gtsam.Pose3) else None)
        assert ours.calibration().equals(K, 1e-15) and not ours.throwCheirality() and not ours.verboseCheirality()


@pytest.mark.parametrize("name,K,z", _CAMERAS, ids=[c[0] for c in _CAMERAS])
def test_throw_and_verbose_cheirality_as_gtsams(name, K, z, capfd):
    from lie_factors.errors import CheiralityException

    n = gtsam.noiseModel.Isotropic.Sigma(3 if "Stereo" in name else 2, 1.0)
    v = gtsam.Values()
    camera, landmark = gtsam.symbol("x", 1), gtsam.symbol("l", 2)
    v.insert(camera, gtsam.Pose3())
    v.insert(landmark, np.array([0.1, 0.2, -1.0]))
    what = "Stereo Cheirality Exception" if "Stereo" in name else "CheiralityException"
    for ours, theirs in ((getattr(ready, name)(z, n, camera, landmark, K, True, False),
                          getattr(gtsam, name)(z, n, camera, landmark, K, True, False)),
                         (getattr(ready, name)(z, n, camera, landmark, K, throwCheirality=True, verboseCheirality=False,
                                               body_P_sensor=_BODY),
                          getattr(gtsam, name)(z, n, camera, landmark, K, True, False, _BODY))):
        with pytest.raises(RuntimeError, match=what):
            theirs.error(v)
        with pytest.raises(CheiralityException, match=f"{name}: {what}: landmark l2 is behind camera x1") as err:
            ours.error(v)
        assert isinstance(err.value, RuntimeError) and ours.throwCheirality()
    verbose = getattr(ready, name)(z, n, camera, landmark, K, False, True)
    assert verbose.verboseCheirality()
    np.testing.assert_allclose(verbose.unwhitenedError(v), getattr(gtsam, name)(z, n, camera, landmark, K, False,
                                                                              True).unwhitenedError(v))
    out = capfd.readouterr().out.splitlines()
    line = f"{what}: Landmark l2 moved behind camera x1"
    assert out.count(line) == 2, out  # GTSAM's, then ours


def test_camera_factors_refuse_what_gtsams_wrapper_refuses():
    from lie_factors.errors import ArgumentTypeError

    K, n = _CAMERAS[0][1], gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    for args, named in (((True,), {}), ((), {"throwCheirality": True}), ((_BODY, True, False), {}),
                        ((True, False), {"body_P_sensor": np.eye(4)}), (("yes", False), {})):
        with pytest.raises(TypeError, match="incompatible constructor arguments"):
            gtsam.GenericProjectionFactorCal3_S2(_Z2, n, 1, 2, K, *args, **named)
        with pytest.raises(ArgumentTypeError, match="incompatible constructor arguments; GTSAM's are"):
            ready.GenericProjectionFactorCal3_S2(_Z2, n, 1, 2, K, *args, **named)
    # pybind11's converting bool caster takes numbers: so do we
    for flags in ((1, 0), (np.True_, 0.0)):
        theirs = gtsam.GenericProjectionFactorCal3_S2(_Z2, n, 1, 2, K, *flags)
        ours = ready.GenericProjectionFactorCal3_S2(_Z2, n, 1, 2, K, *flags)
        assert (ours.throwCheirality(), ours.verboseCheirality()) == (theirs.throwCheirality(),
                                                                       theirs.verboseCheirality())


def test_bundler_projection_behind_the_camera_is_gtsams_zero():
    K = gtsam.Cal3Bundler(500.0, 0.1, -0.02, 12.0, -7.0)
    n = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    for depth in (2.0, 0.0, -1.0):
        p = np.array([0.2, -0.1, depth])
        v, w = gtsam.Values(), gtsam.Values()
        v.insert(1, gtsam.Pose3())
        v.insert(2, K)
        v.insert(3, p)
        w.insert(10, gtsam.PinholeCameraCal3Bundler(gtsam.Pose3(), K))
        w.insert(3, p)
        ours, theirs = ready.BundlerProjectionFactor(1, 2, 3, _Z2, n), gtsam.GeneralSFMFactorCal3Bundler(_Z2, n, 10, 3)
        np.testing.assert_allclose(ours.unwhitenedError(v), theirs.unwhitenedError(w), atol=1e-10)
        A, B = ours.linearize(v).jacobian()[0], theirs.linearize(w).jacobian()[0]
        np.testing.assert_allclose(A, B, atol=1e-9 * max(1.0, np.abs(B).max()))


# ----------------------------------------------------------------------- at zero distance


@pytest.mark.parametrize("distance", [0.0, 1e-11, 1e-9, 1e-6, 3e-6, 2e-5])
def test_ranges_and_bearings_at_and_near_zero_distance_equal_gtsams(distance):
    """GTSAM's norm2/norm3 Jacobian [1, …, 1] at distance ≤ 1e-10 (RangeFactor's ±1), and
    Rot2::relativeBearing's identity with zero Jacobian within 1e-5: ours are GTSAM's, both sides
    of each threshold."""
    rng = np.random.default_rng(30)
    x2, x3 = pose2(rng), pose3(rng)
    d2 = distance * np.array([0.6, -0.8])
    d3 = distance * np.array([0.48, -0.64, 0.6])
    l2 = x2.translation() + d2
    l3 = x3.transformFrom(x3.rotation().unrotate(d3))  # the translation plus d3 in the world frame
    y2 = gtsam.Pose2(gtsam.Rot2(0.7), l2)
    y3 = gtsam.Pose3(gtsam.Rot3.Ypr(0.1, 0.2, 0.3), l3)
    v = gtsam.Values()
    for k, value in enumerate((x2, l2, x3, l3, y2, y3)):
        v.insert(k + 1, value)
    r, n = 0.5, gtsam.noiseModel.Isotropic.Sigma(1, 0.2)
    _compare(ready.RangeFactor2D(1, 2, r, n), gtsam.RangeFactor2D(1, 2, r, n), v)
    _compare(ready.RangeFactor3D(3, 4, r, n), gtsam.RangeFactor3D(3, 4, r, n), v)
    _compare(ready.RangeFactorPose2(1, 5, r, n), gtsam.RangeFactorPose2(1, 5, r, n), v)
    _compare(ready.RangeFactorPose3(3, 6, r, n), gtsam.RangeFactorPose3(3, 6, r, n), v)
    nb = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.1]))
    b = gtsam.Rot2(0.4)
    _compare(ready.BearingRangeFactor2D(1, 2, b, r, nb), gtsam.BearingRangeFactor2D(1, 2, b, r, nb), v)
    if distance <= 1e-10:
        A = ready.RangeFactor3D(3, 4, r, gtsam.noiseModel.Unit.Create(1)).linearize(v).jacobian()[0]
        assert np.all(np.abs(A[0, 3:]) > 0)  # not the zero Jacobian


def test_bearing_range_3d_jacobians_exact_where_gtsams_are_not():
    """GTSAM's BearingRangeFactor3D Jacobians against central differences of GTSAM's own error
    (its ExpressionFactor leaves out the derivative of Unit3's local coordinates) are off by
    more than 1e-3 away from zero error; ours are within 1e-8 of Richardson differences of
    ours, and both errors agree (docs/factors.md)."""
    rng = np.random.default_rng(40)
    worst = 0.0
    for _ in range(6):
        x, p = pose3(rng), rng.normal(0, 4, 3)
        seen = x.transformTo(p) + rng.normal(0, 0.3, 3)
        b, r = gtsam.Unit3(seen / np.linalg.norm(seen)), x.range(p) + rng.normal(0, 0.2)
        n = gtsam.noiseModel.Unit.Create(3)
        ours, theirs = ready.BearingRangeFactor3D(1, 2, b, r, n), gtsam.BearingRangeFactor3D(1, 2, b, r, n)

        def error(f, dx, dp):
            v = gtsam.Values()
            v.insert(1, x.retract(dx))
            v.insert(2, p + dp)
            return f.unwhitenedError(v)

        def central(f, h=1e-5):
            cols = []
            for i in range(9):
                d = np.zeros(9)
                d[i] = h
                cols.append((error(f, d[:6], d[6:]) - error(f, -d[:6], -d[6:])) / (2 * h))
            return np.stack(cols, axis=1)

        v = gtsam.Values()
        v.insert(1, x)
        v.insert(2, p)
        A, B = ours.linearize(v).jacobian()[0], theirs.linearize(v).jacobian()[0]
        assert np.max(np.abs(A - central(ours))) <= 1e-6 * max(1.0, np.abs(A).max())
        worst = max(worst, float(np.max(np.abs(B - central(theirs)))))
    assert worst > 1e-3
