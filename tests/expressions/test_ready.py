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
