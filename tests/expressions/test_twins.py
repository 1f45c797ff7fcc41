"""GTSAM's own factors read into their twin kinds (lie_factors.expressions.twins): each converted
class's error (1e-12 relative) and whitened Jacobians (1e-9) against GTSAM's factor at the same
values, read by the batch solver as it reads a graph; where GTSAM's Jacobians leave out the
derivative of the error's local coordinates (the similarities' Between and Prior, the camera
priors, the 3-D bearings), they are compared where the error is zero, and ours against
Richardson differences of GTSAM's own error elsewhere."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

import lie_factors as lf
from lie_factors.batch.graph import Problem
from lie_factors.errors import CheiralityException, EvaluationError
from lie_factors.expressions.twins import TABLE, twin_row

SEEDS = range(4)
X, L, K_ = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L, gtsam.symbol_shorthand.K

CONVERTED = [
    "BearingFactor2D", "BearingFactor3D", "BearingRangeFactor2D", "BearingRangeFactor3D",
    "BetweenFactorPoint2", "BetweenFactorPoint3", "BetweenFactorPose2", "BetweenFactorPose3", "BetweenFactorRot2",
    "BetweenFactorRot3", "BetweenFactorSimilarity2", "BetweenFactorSimilarity3", "GPSFactor",
    "GeneralSFMFactor2Cal3Bundler", "GeneralSFMFactorCal3Bundler", "GeneralSFMFactorCal3_S2",
    "GenericProjectionFactorCal3DS2", "GenericProjectionFactorCal3Fisheye", "GenericProjectionFactorCal3_S2",
    "GenericStereoFactor3D", "PoseRotationPrior2D", "PoseRotationPrior3D", "PoseTranslationPrior2D",
    "PoseTranslationPrior3D", "PriorFactorPinholeCameraCal3Bundler", "PriorFactorPinholeCameraCal3_S2",
    "PriorFactorPoint2", "PriorFactorPoint3", "PriorFactorPose2", "PriorFactorPose3", "PriorFactorRot2",
    "PriorFactorRot3", "PriorFactorSimilarity2", "PriorFactorSimilarity3", "RangeFactor2D", "RangeFactor3D",
    "RangeFactorPose2", "RangeFactorPose3",
]


def test_the_converted_classes():
    assert sorted(cls.__name__ for cls in TABLE) == CONVERTED
    assert all(getattr(gtsam, name) in TABLE for name in CONVERTED)


# ----------------------------------------------------------------------------- values

def rot2(rng):
    return gtsam.Rot2(rng.uniform(-3, 3))


def rot3(rng):
    return gtsam.Rot3.Expmap(rng.normal(0, 1, 3))


def pose2(rng):
    return gtsam.Pose2(*rng.normal(0, 2, 2), rng.uniform(-3, 3))


def pose3(rng):
    return gtsam.Pose3(rot3(rng), rng.normal(0, 2, 3))


def sim2(rng):
    return gtsam.Similarity2(rot2(rng), rng.normal(0, 2, 2), rng.uniform(0.5, 2.0))


def sim3(rng):
    return gtsam.Similarity3(rot3(rng), rng.normal(0, 2, 3), rng.uniform(0.5, 2.0))


def point2(rng):
    return rng.normal(0, 3, 2)


def point3(rng):
    return rng.normal(0, 3, 3)


def noise(dim, rng):
    """A full Gaussian noise model (its whitening mixes the rows)."""
    A = rng.normal(0, 0.3, (dim, dim))
    return gtsam.noiseModel.Gaussian.Covariance(A @ A.T + 0.2 * np.eye(dim))


def values_of(**items):
    v = gtsam.Values()
    for key, value in items.values():
        v.insert(key, value)
    return v


# ----------------------------------------------------------------------------- comparisons

def _kind_group(f, values, robust=False):
    graph = gtsam.NonlinearFactorGraph()
    graph.add(f)
    P = Problem(graph, values, group_robust=robust)
    assert not P.native, f"{type(f).__name__} stayed native"
    P.linearize()
    (kg,) = P.kinds
    return kg


def _columns(kg, f) -> np.ndarray:
    """The kind's Jacobian columns in the order of GTSAM's keys."""
    keys = [int(k) for k in kg.keys[0]]
    return np.concatenate([np.arange(*kg.kind.blocks[keys.index(k)]) for k in f.keys()])


def _richardson(f, values, h=1e-3) -> np.ndarray:
    """Whitened Jacobian of GTSAM's own error of ``f`` at ``values`` (its keys' order), by
    Richardson's extrapolation of central differences."""
    nm = f.noiseModel()
    zero = values.zeroVectors()
    dims = [len(zero.at(k)) for k in f.keys()]

    def central(step):
        cols = []
        for key, d in zip(f.keys(), dims):
            for c in range(d):
                plus, minus = gtsam.VectorValues(), gtsam.VectorValues()
                for k in values.keys():
                    dk = np.zeros(len(zero.at(k)))
                    if k == key:
                        dk[c] = step
                    plus.insert(k, dk)
                    minus.insert(k, -dk)
                ep = nm.whiten(f.unwhitenedError(values.retract(plus)))
                em = nm.whiten(f.unwhitenedError(values.retract(minus)))
                cols.append((ep - em) / (2 * step))
        return np.stack(cols, axis=1)

    return (4 * central(h / 2) - central(h)) / 3


def compare(f, values, exact=True, residual=None):
    """The twin's residual, error, whitened Jacobians and b against GTSAM's ``f`` at ``values``
    (each to its tolerance relative to the larger of 1 and GTSAM's value's largest entry).
    ``exact=False``: GTSAM's Jacobians leave out the derivative of the error's chart, which is
    O(residual) (``residual``: the error's size): below 1e-3 they are compared within
    10·residual; above, ours are held to Richardson differences of GTSAM's error (at smaller
    residuals GTSAM's Logmaps lose digits to cancellation, so its differences would not do)."""
    kg = _kind_group(f, values)
    e = np.asarray(f.unwhitenedError(values))
    scale = max(1.0, float(np.max(np.abs(e))))
    np.testing.assert_allclose(kg.e[0], e, rtol=0, atol=1e-12 * scale)
    error = f.error(values)
    np.testing.assert_allclose(0.5 * kg.sq[0], error, rtol=0, atol=1e-12 * max(1.0, error))
    A = kg.A[0][:, _columns(kg, f)]
    if exact or residual < 1e-3:
        B, b = f.linearize(values).jacobian()
        tolerance = 1e-9 if exact else max(1e-9, 10.0 * residual)
        np.testing.assert_allclose(A, B, rtol=0, atol=tolerance * max(1.0, float(np.max(np.abs(B)))))
        np.testing.assert_allclose(kg.b[0], b, rtol=0, atol=1e-9 * scale)
    else:
        N = _richardson(f, values)
        np.testing.assert_allclose(A, N, rtol=0, atol=1e-7 * max(1.0, float(np.max(np.abs(N)))))


# ----------------------------------------------------------------------------- between and prior

GROUPS = {"Rot2": (rot2, 1), "Rot3": (rot3, 3), "Pose2": (pose2, 3), "Pose3": (pose3, 6),
          "Similarity2": (sim2, 4), "Similarity3": (sim3, 7)}
#: the residual's size: at zero, across the small-angle branches, and large
RESIDUALS = (0.0, 1e-9, 1e-4, 0.5, 3.0)


def _off(value, dim, size, rng):
    """``value`` moved by a tangent vector of norm ``size`` (its rotation angle about ``size``)."""
    d = rng.normal(0, 1, dim)
    return value.retract(size * d / np.linalg.norm(d)) if size else value


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("group", list(GROUPS))
def test_between_and_prior_of_groups(group, seed):
    rng = np.random.default_rng(seed)
    make, dim = GROUPS[group]
    a, b = make(rng), make(rng)
    values = values_of(a=(X(1), a), b=(X(2), b))
    for size in RESIDUALS:
        nm = noise(dim, rng)
        between = getattr(gtsam, f"BetweenFactor{group}")(X(1), X(2), _off(a.between(b), dim, size, rng), nm)
        prior = getattr(gtsam, f"PriorFactor{group}")(X(2), _off(b, dim, size, rng), nm)
        for f in (between, prior):
            compare(f, values, exact=size == 0.0 or _gtsam_exact(group, size), residual=size)


def _gtsam_exact(group: str, size: float) -> bool:
    """Whether GTSAM 4.3's Between and Prior Jacobians are exact at residuals of ``size``: of
    Rot2, Rot3 and Pose3 everywhere; of Pose2 away from small angles (its Logmap derivative loses
    digits there); of the similarities only at zero (they leave out the Logmap derivative)."""
    return group in ("Rot2", "Rot3", "Pose3") or (group == "Pose2" and size >= 1e-3)


@pytest.mark.parametrize("seed", SEEDS)
def test_between_and_prior_of_points_and_position_priors(seed):
    rng = np.random.default_rng(seed)
    p2, q2, p3, q3, x2, x3 = point2(rng), point2(rng), point3(rng), point3(rng), pose2(rng), pose3(rng)
    values = values_of(p2=(L(1), p2), q2=(L(2), q2), p3=(L(3), p3), q3=(L(4), q3), x2=(X(1), x2), x3=(X(2), x3))
    n2, n3 = noise(2, rng), noise(3, rng)
    for f in (gtsam.BetweenFactorPoint2(L(1), L(2), point2(rng), n2), gtsam.PriorFactorPoint2(L(1), point2(rng), n2),
              gtsam.BetweenFactorPoint3(L(3), L(4), point3(rng), n3), gtsam.PriorFactorPoint3(L(3), point3(rng), n3),
              gtsam.PoseTranslationPrior2D(X(1), pose2(rng), n2), gtsam.PoseTranslationPrior3D(X(2), pose3(rng), n3),
              gtsam.GPSFactor(X(2), point3(rng), n3),
              gtsam.PoseRotationPrior2D(X(1), rot2(rng), noise(1, rng))):
        compare(f, values)
    for size in RESIDUALS:
        compare(gtsam.PoseRotationPrior3D(X(2), _off(x3.rotation(), 3, size, rng), n3), values)


# ----------------------------------------------------------------------------- ranges and bearings

@pytest.mark.parametrize("distance", [0.0, 1e-11, 1e-9, 1e-6, 3e-6, 2e-5, 1.7])
def test_ranges_and_bearings_across_their_thresholds(distance):
    """GTSAM's norm Jacobian at distance ≤ 1e-10, Rot2::relativeBearing's within 1e-5: both sides."""
    rng = np.random.default_rng(30)
    x2, x3 = pose2(rng), pose3(rng)
    l2 = x2.translation() + distance * np.array([0.6, -0.8])
    l3 = x3.translation() + distance * np.array([0.48, -0.64, 0.6])
    y2, y3 = gtsam.Pose2(gtsam.Rot2(0.7), l2), gtsam.Pose3(rot3(rng), l3)
    values = values_of(x2=(X(1), x2), l2=(L(1), l2), x3=(X(2), x3), l3=(L(2), l3), y2=(X(3), y2), y3=(X(4), y3))
    r = 0.5
    for f in (gtsam.RangeFactor2D(X(1), L(1), r, noise(1, rng)), gtsam.RangeFactor3D(X(2), L(2), r, noise(1, rng)),
              gtsam.RangeFactorPose2(X(1), X(3), r, noise(1, rng)),
              gtsam.RangeFactorPose3(X(2), X(4), r, noise(1, rng)),
              gtsam.BearingFactor2D(X(1), L(1), rot2(rng), noise(1, rng)),
              gtsam.BearingRangeFactor2D(X(1), L(1), rot2(rng), r, noise(2, rng))):
        compare(f, values)
    if distance > 1e-9:  # a Unit3 bearing of a point at the pose's origin is not defined
        seen = x3.transformTo(l3)
        exact = gtsam.Unit3(seen)
        off = gtsam.Unit3(seen / np.linalg.norm(seen) + rng.normal(0, 0.2, 3))
        # differences of steps far larger than the distance say nothing: the zero error only there
        for b, zero in ((exact, True), (off, False))[: 2 if distance > 1.0 else 1]:
            compare(gtsam.BearingFactor3D(X(2), L(2), b, noise(2, rng)), values, exact=zero, residual=0.2)
            compare(gtsam.BearingRangeFactor3D(X(2), L(2), b, np.linalg.norm(seen) if zero else r, noise(3, rng)),
                    values, exact=zero, residual=0.2)


# ----------------------------------------------------------------------------- cameras

_CALIBRATIONS = [
    ("GenericProjectionFactorCal3_S2", gtsam.Cal3_S2(500.0, 480.0, 0.1, 320.0, 240.0)),
    ("GenericProjectionFactorCal3DS2", gtsam.Cal3DS2(500.0, 480.0, 0.1, 320.0, 240.0, -0.2, 0.05, 1e-3, -2e-3)),
    ("GenericProjectionFactorCal3Fisheye", gtsam.Cal3Fisheye(400.0, 410.0, 0.2, 330.0, 250.0, -0.01, 0.003, -4e-4,
                                                             1e-5)),
    ("GenericStereoFactor3D", gtsam.Cal3_S2Stereo(500.0, 480.0, 0.1, 320.0, 240.0, 0.3)),
]
_BODY = gtsam.Pose3(gtsam.Rot3.Ypr(0.05, -0.1, 0.02), np.array([0.1, -0.05, 0.2]))
#: a body pose whose frame is exact in binary: a point at depth exactly 0 through it
_SHIFT = gtsam.Pose3(gtsam.Rot3(), np.array([0.5, -0.25, 0.125]))
_OPTIONAL = [(), (_BODY,), (False, False), (False, False, _BODY), (_SHIFT,), (False, False, _SHIFT)]


@pytest.mark.parametrize("name,K", _CALIBRATIONS, ids=[c[0] for c in _CALIBRATIONS])
def test_projection_factors_in_front_on_and_behind_the_camera(name, K):
    rng = np.random.default_rng(20)
    stereo = "Stereo" in name
    z = gtsam.StereoPoint2(300.0, 280.0, 200.0) if stereo else np.array([300.0, 200.0])
    cls = getattr(gtsam, name)
    for optional in _OPTIONAL:
        body = optional[-1] if optional and isinstance(optional[-1], gtsam.Pose3) else gtsam.Pose3()
        exact = body is _SHIFT or not optional or optional == (False, False)
        camera = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 2.0, -3.0])) if exact else pose3(rng)
        sensor = camera.compose(body)
        for depth in (3.0, 0.375, 0.0, -2.0 ** -30, -2.0) if exact else (3.0, 0.4, -1e-9, -2.0):
            local = np.array([0.375, -0.625, depth]) if exact else np.array([*rng.normal(0, 0.3, 2), depth])
            p = sensor.transformFrom(local)
            values = values_of(x=(X(1), camera), l=(L(2), p))
            f = cls(z, noise(3 if stereo else 2, rng), X(1), L(2), K, *optional)
            compare(f, values)
        row, _ = twin_row(f, {})
        assert np.array_equal(row._constants[2], body.matrix())


def test_twin_rows_read_each_calibration_once():
    K = _CALIBRATIONS[0][1]
    n = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    cache: dict = {}
    rows = [twin_row(gtsam.GenericProjectionFactorCal3_S2(np.array([1.0, 2.0]), n, X(1), L(j), K), cache)[0]
            for j in range(3)]
    assert list(cache) == [id(K)] and all(r._constants[1] is rows[0]._constants[1] for r in rows)


@pytest.mark.parametrize("name", ["GenericProjectionFactorCal3_S2", "GenericStereoFactor3D"])
def test_throw_and_verbose_cheirality_as_gtsams(name, capfd):
    K = dict(_CALIBRATIONS)[name]
    stereo = "Stereo" in name
    z = gtsam.StereoPoint2(300.0, 280.0, 200.0) if stereo else np.array([300.0, 200.0])
    n = gtsam.noiseModel.Isotropic.Sigma(3 if stereo else 2, 1.0)
    values = values_of(x=(X(1), gtsam.Pose3()), l=(L(2), np.array([0.1, 0.2, 0.0])))  # depth 0
    what = "Stereo Cheirality Exception" if stereo else "CheiralityException"
    for optional in ((True, False), (True, True, _BODY)):
        theirs = getattr(gtsam, name)(z, n, X(1), L(2), K, *optional)
        graph = gtsam.NonlinearFactorGraph()
        graph.add(theirs)
        with pytest.raises(RuntimeError, match=what):
            theirs.error(values)
        P = Problem(graph, values)
        assert not P.native
        with pytest.raises(CheiralityException, match=f"{name}: {what}: landmark l2 is behind camera x1") as err:
            P.linearize()
        assert isinstance(err.value, RuntimeError)
    capfd.readouterr()
    verbose = getattr(gtsam, name)(z, n, X(1), L(2), K, False, True)
    verbose.error(values)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(verbose)
    Problem(graph, values).linearize()
    out = capfd.readouterr().out.splitlines()
    assert out.count(f"{what}: Landmark l2 moved behind camera x1") == 2, out  # GTSAM's, then ours


@pytest.mark.parametrize("seed", SEEDS)
def test_camera_factors_and_camera_priors(seed, capfd):
    """GeneralSFMFactor on a camera (9 and 11 tangent dims), GeneralSFMFactor2 (pose, point,
    calibration) and the camera priors, in front of, on the plane of (exactly: a camera frame
    exact in binary) and behind the camera (0 there; GeneralSFMFactor2 prints GTSAM's line at
    each evaluation: GTSAM's three here, then ours)."""
    rng = np.random.default_rng(seed)
    bundler = gtsam.Cal3Bundler(500.0 + rng.normal(0, 20), rng.normal(0, 0.1), rng.normal(0, 0.01), 12.0, -7.0)
    s2 = gtsam.Cal3_S2(500.0, 480.0, 0.1, 320.0, 240.0)
    exact = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 2.0, -3.0]))
    behind = 0
    for x, depth in ((pose3(rng), 3.0), (exact, 0.0), (pose3(rng), -1.0), (exact, -2.0 ** -30)):
        p = x.transformFrom(np.array([0.375, -0.625, depth]))
        for cal, camera in (("Cal3Bundler", gtsam.PinholeCameraCal3Bundler(x, bundler)),
                            ("Cal3_S2", gtsam.PinholeCameraCal3_S2(x, s2))):
            z = rng.normal(0, 1, 2) + (camera.project(p) if depth > 0 else 0.0)
            values = values_of(c=(X(1), camera), l=(L(2), p))
            compare(getattr(gtsam, f"GeneralSFMFactor{cal}")(z, noise(2, rng), X(1), L(2)), values)
        values = values_of(x=(X(1), x), l=(L(2), p), k=(K_(3), bundler))
        compare(gtsam.GeneralSFMFactor2Cal3Bundler(rng.normal(0, 1, 2), noise(2, rng), X(1), L(2), K_(3)), values)
        behind += depth <= 0.0
    printed = capfd.readouterr().out.splitlines()
    assert printed == ["CheiralityException: Landmark l2 behind Camera x1"] * (4 * behind)
    x = pose3(rng)
    cameras = {"Cal3Bundler": gtsam.PinholeCameraCal3Bundler(x, bundler), "Cal3_S2": gtsam.PinholeCameraCal3_S2(x, s2)}
    for cal, camera in cameras.items():
        dim = 6 + (3 if cal == "Cal3Bundler" else 5)
        values = values_of(c=(X(1), camera))
        prior = getattr(gtsam, f"PriorFactorPinholeCamera{cal}")
        compare(prior(X(1), camera, noise(dim, rng)), values)  # zero error: GTSAM's identity Jacobian exact
        moved = camera.retract(rng.normal(0, 0.2, dim) * np.r_[np.ones(6), 0.01 * np.ones(dim - 6)])
        compare(prior(X(1), moved, noise(dim, rng)), values, exact=False, residual=0.2)


# ----------------------------------------------------------------------------- what stays native

def test_what_stays_native():
    n = gtsam.noiseModel
    huber = n.Robust.Create(n.mEstimator.Huber.Create(1.345), n.Isotropic.Sigma(6, 0.1))
    fair = n.Robust.Create(n.mEstimator.Fair.Create(1.3998), n.Isotropic.Sigma(6, 0.1))
    x, y = gtsam.Pose3(), gtsam.Pose3(gtsam.Rot3.Ypr(0.1, 0.2, 0.3), np.array([1.0, 2.0, 3.0]))
    values = values_of(x=(X(1), x), y=(X(2), y), c=(X(3), gtsam.PinholeCameraCal3_S2(x, gtsam.Cal3_S2())),
                       l=(L(1), np.array([0.0, 0.0, 5.0])))
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.BetweenFactorPose3(X(1), X(2), x.between(y), huber))                       # 0: robust
    graph.add(gtsam.BetweenFactorPose3(X(1), X(2), x.between(y), fair))                        # 1: robust
    graph.add(gtsam.PriorFactorPose3(X(1), x, n.Constrained.All(6)))                           # 2: constrained
    graph.add(gtsam.GeneralSFMFactorCal3_S2(np.zeros(2), n.Robust.Create(n.mEstimator.Huber.Create(1.0),
                                                                         n.Unit.Create(2)), X(3), L(1)))  # 3
    graph.add(gtsam.PriorFactorVector(X(4), np.zeros(2), n.Unit.Create(2)))                    # 4: no twin
    graph.add(gtsam.BetweenFactorPose3(X(1), X(1), gtsam.Pose3(), n.Unit.Create(6)))           # 5: one key twice
    values.insert(X(4), np.zeros(2))
    plain = Problem(graph, values)
    assert [i for i, _, _ in plain.native] == [0, 1, 2, 3, 4, 5]
    grouped = Problem(graph, values, group_robust=True)
    assert [i for i, _, _ in grouped.native] == [2, 3, 4, 5]
    assert [str(grouped.robust[i]) for i in (0, 1)] == ["huber:1.345", "fair:1.3998"]


def test_a_fault_names_gtsams_class_and_keys():
    f = gtsam.BetweenFactorPoint3(L(1), L(2), np.array([np.nan, 0.0, 0.0]), gtsam.noiseModel.Unit.Create(3))
    graph = gtsam.NonlinearFactorGraph()
    graph.add(f)
    P = Problem(graph, values_of(a=(L(1), np.zeros(3)), b=(L(2), np.ones(3))))
    with pytest.raises(EvaluationError, match="BetweenFactorPoint3 on l1, l2: .*not finite"):
        P.linearize()


# ----------------------------------------------------------------------------- optimization

def test_a_graph_of_twins_and_native_factors_reaches_gtsams_optimum():
    """Cameras (a 9-dimensional variable in its own block, read back into GTSAM's Values for the
    native factor on it), projections, priors and betweens as twins, beside native factors."""
    rng = np.random.default_rng(5)
    n = gtsam.noiseModel
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    K = gtsam.Cal3Bundler(500.0, 0.05, -0.01, 0.0, 0.0)
    points = [rng.normal(0, 2, 3) for _ in range(12)]
    poses = [gtsam.Pose3(gtsam.Rot3.Ypr(0.1 * i, 0.0, 0.0), np.array([1.0 * i, 0.0, -8.0])) for i in range(4)]
    for i, pose in enumerate(poses):
        camera = gtsam.PinholeCameraCal3Bundler(pose, K)
        for j, p in enumerate(points):
            graph.add(gtsam.GeneralSFMFactorCal3Bundler(camera.project(p) + rng.normal(0, 1, 2),
                                                        n.Isotropic.Sigma(2, 1.0), X(i), L(j)))
        values.insert(X(i), camera.retract(np.r_[rng.normal(0, 0.02, 6), rng.normal(0, [5, 0.01, 0.001])]))
    for j, p in enumerate(points):
        values.insert(L(j), p + rng.normal(0, 0.1, 3))
    graph.add(gtsam.PriorFactorPinholeCameraCal3Bundler(X(0), gtsam.PinholeCameraCal3Bundler(poses[0], K),
                                                        n.Isotropic.Sigma(9, 0.01)))
    graph.add(gtsam.PriorFactorPoint3(L(0), points[0], n.Isotropic.Sigma(3, 0.01)))
    graph.add(gtsam.BetweenFactorPoint3(L(1), L(2), points[2] - points[1], n.Isotropic.Sigma(3, 0.01)))
    # native: a robust projection on a camera (GTSAM linearizes it), a vector prior
    graph.add(gtsam.GeneralSFMFactorCal3Bundler(
        gtsam.PinholeCameraCal3Bundler(poses[1], K).project(points[3]),
        n.Robust.Create(n.mEstimator.Huber.Create(1.0), n.Isotropic.Sigma(2, 1.0)), X(1), L(3)))
    graph.add(gtsam.PriorFactorPoint3(L(4), points[4], n.Robust.Create(n.mEstimator.Cauchy.Create(1.0),
                                                                          n.Isotropic.Sigma(3, 0.1))))
    problem = Problem(graph, values)
    assert [i for i, _, _ in problem.native] == [graph.size() - 2, graph.size() - 1]
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-12)
    theirs = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    ours = lf.optimize(graph, values, params).values
    assert graph.error(ours) == pytest.approx(graph.error(theirs), rel=1e-8)
    for i in range(4):
        a, b = ours.atPinholeCameraCal3Bundler(X(i)), theirs.atPinholeCameraCal3Bundler(X(i))
        assert a.equals(b, 1e-5), (a, b)
    for j in range(12):
        np.testing.assert_allclose(ours.atPoint3(L(j)), theirs.atPoint3(L(j)), atol=1e-5)


def test_robust_twins_reach_gtsams_optimum_where_the_solver_groups_robust_losses():
    """With ``group_robust`` (WeightedLevenbergMarquardt) a twin with a robust noise model is a
    row of its kind, its loss the solver's; its kind's factors count in the objective."""
    from lie_factors.expressions import ready
    from lie_factors.robust.weighted import WeightedLevenbergMarquardt

    n = gtsam.noiseModel
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(X(1), gtsam.Pose2(), n.Isotropic.Sigma(3, 0.1)))
    graph.add(ready.RangeFactor2D(X(1), L(2), 5.0, n.Isotropic.Sigma(1, 0.1)))
    for k, estimator in enumerate((n.mEstimator.Huber.Create(1.0), n.mEstimator.Fair.Create(1.3998))):
        graph.add(gtsam.PriorFactorPoint2(L(2), np.array([3.0, 3.0 + k]),
                                          n.Robust.Create(estimator, n.Isotropic.Sigma(2, 0.1))))
    values = values_of(x=(X(1), gtsam.Pose2(0.3, -0.2, 0.1)), l=(L(2), np.array([1.0, 0.0])))
    optimizer = WeightedLevenbergMarquardt(graph, values)
    assert not optimizer.problem.native
    assert optimizer.objective() == pytest.approx(graph.error(values), rel=1e-12)
    ours = optimizer.optimize().values
    theirs = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    assert graph.error(ours) == pytest.approx(graph.error(theirs), rel=1e-8)
    np.testing.assert_allclose(ours.atPoint2(L(2)), theirs.atPoint2(L(2)), atol=1e-6)


def test_camera_operations_against_differences():
    """A kind on two cameras and a point: camera.pose(), calibration(), project and two cameras'
    localCoordinates, its Jacobians against Richardson differences of its own error under GTSAM's
    retraction of the cameras (PinholeCamera::retract: the tangent order is GTSAM's), in front of
    the camera and near its optical axis; the projection's values are GTSAM's."""
    from lie_factors.expressions import ops

    @lf.factor("PinholeCameraCal3_S2", "PinholeCameraCal3Bundler", "Point3")
    def cameras(c, d, l):
        return ops.stack(c.project(l), d.localCoordinates(d), d.pose().localCoordinates(c.pose()),
                         d.calibration() * c.calibration()[0:3], c.project(l) - d.project(l))

    rng = np.random.default_rng(9)
    for lateral in (0.7, 1e-9, 0.0):
        x = pose3(rng)
        c = gtsam.PinholeCameraCal3_S2(x, gtsam.Cal3_S2(500.0, 480.0, 0.1, 320.0, 240.0))
        d = gtsam.PinholeCameraCal3Bundler(x.retract(rng.normal(0, 0.1, 6)),
                                           gtsam.Cal3Bundler(450.0, 0.1, -0.02, 3.0, 4.0))
        p = x.transformFrom(np.array([lateral, -lateral, 4.0]))
        values = values_of(c=(X(1), c), d=(X(2), d), l=(L(3), p))
        f = cameras(X(1), X(2), L(3), gtsam.noiseModel.Unit.Create(cameras.kind.dim))
        e = f.unwhitenedError(values)
        np.testing.assert_allclose(e[:2], c.project(p), rtol=1e-12)
        A = f.linearize(values).jacobian()[0]
        N = _richardson(f, values, h=1e-4)
        np.testing.assert_allclose(A, N, rtol=0, atol=1e-6 * max(1.0, float(np.abs(N).max())))
