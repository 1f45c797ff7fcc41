"""Factor kinds (lf.factor): definition-time errors, construction checks, the factor inside GTSAM's
optimizers, ISAM2 and Marginals, and the batch solver reading a kind into arrays."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

import lie_factors as lf
from lie_factors.errors import InputError
from lie_factors.expressions import ops
from lie_factors.factors import BetweenFactorPose2, BetweenFactorPose3, PriorFactorPose2, PriorFactorPose3

X = gtsam.symbol_shorthand.X
L = gtsam.symbol_shorthand.L


@lf.factor("Pose2", "Point2", measured="Point2")
def landmark(x, l, z):
    return x.transformTo(l) - z


# ----------------------------------------------------------------------- definition


def _line_of(fn_source_marker: str, fn) -> int:
    lines, start = __import__("inspect").getsourcelines(fn)
    return start + next(i for i, line in enumerate(lines) if fn_source_marker in line)


def test_an_operation_outside_the_vocabulary_names_itself_the_type_and_the_line():
    def residual(x, l):
        q = x.transformTo(l)
        return q.normalized(l)  # not in the vocabulary

    with pytest.raises(InputError) as err:
        lf.factor("Pose3", "Point3")(residual)
    text = str(err.value)
    assert "normalized" in text and "Point3" in text and f"line {_line_of('q.normalized', residual)}" in text


def test_types_that_do_not_fit_are_refused_at_definition():
    def residual(x, y):
        return x.compose(y).logmap()

    with pytest.raises(InputError, match=r"line \d+: compose of a Pose3 and a Pose2"):
        lf.factor("Pose3", "Pose2")(residual)
    with pytest.raises(InputError, match="transformTo's point takes a vector of dimension 3, got a Point2"):
        lf.factor("Pose3", "Point2")(lambda x, p: x.transformTo(p))
    with pytest.raises(InputError, match="the residual is a Pose3"):
        lf.factor("Pose3", "Pose3")(lambda a, b: a.between(b))
    with pytest.raises(InputError, match="unknown type 'Pose4'"):
        lf.factor("Pose4")(lambda x: x)
    with pytest.raises(InputError, match="not a number"):
        lf.factor("Point3")(lambda p: np.sin(float(p)) * p)
    with pytest.raises(InputError, match="cannot branch"):
        lf.factor("Point3")(lambda p: p if p.norm() else -p)


def test_construction_checks_shapes_values_and_the_noise_model():
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 0.1)
    with pytest.raises(InputError, match="shape"):
        landmark(1, 2, np.zeros(3), noise)
    with pytest.raises(InputError, match="not finite"):
        landmark(1, 2, np.array([np.nan, 0.0]), noise)
    with pytest.raises(InputError, match="dimension 3, the residual 2"):
        landmark(1, 2, np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(3, 0.1))
    with pytest.raises(TypeError, match="keys must be non-negative"):
        landmark(-1, 2, np.zeros(2), noise)
    with pytest.raises(TypeError, match="positional arguments"):
        landmark(1, np.zeros(2), noise)
    with pytest.raises(InputError, match="keys must differ"):
        landmark(1, 1, np.zeros(2), noise)
    K = lf.factor("Pose3", "Point3", measured="Point2", K="Cal3_S2")(lambda x, p, z, K: ops.project(x, p, K) - z)
    with pytest.raises(TypeError, match=r"constant\(s\) \['K'\] must be given"):
        K(1, 2, np.zeros(2), noise)
    rot = lf.factor("Pose3", measured="Pose3")(lambda x, z: z.localCoordinates(x))
    with pytest.raises(InputError, match="rotation|orthonormal"):
        rot(1, np.diag([1.0, 1.0, 2.0, 1.0]), gtsam.noiseModel.Isotropic.Sigma(6, 0.1))


@pytest.mark.parametrize("group,m,d,n", [("Pose3", 4, 3, 6), ("Rot2", 2, 2, 1), ("Similarity2", 3, 2, 4)])
def test_a_group_constant_is_checked_at_the_orthonormality_bound(group, m, d, n):
    # RᵀR − I = (1+ε)² − 1 ≈ 2ε on the first diagonal entry: straddle ORTHONORMAL_TOL (1e-9)
    from lie_factors.kernels.validate import ORTHONORMAL_TOL

    kind = lf.factor(group, measured=group)(lambda x, z: z.localCoordinates(x))
    noise = gtsam.noiseModel.Isotropic.Sigma(n, 0.1)
    for factor_ in (0.9, 1.1):
        M = np.eye(m)
        M[0, 0] = np.sqrt(1.0 + factor_ * ORTHONORMAL_TOL)
        if factor_ < 1:
            kind(1, M, noise)
        else:
            with pytest.raises(InputError, match="orthonormal"):
                kind(1, M, noise)
    reflection = np.eye(m)
    reflection[1, 1] = -1.0
    with pytest.raises(InputError, match="reflection"):
        kind(1, reflection, noise)
    if m > d:
        bad_corner = np.eye(m)
        bad_corner[-1, 0] = 0.5
        with pytest.raises(InputError, match="last row"):
            kind(1, bad_corner, noise)


def test_a_key_holding_another_type_or_missing_raises_gtsams_named_error():
    """A key holding another type, or missing, when GTSAM evaluates the factor: GTSAM's
    ValuesIncorrectType (also a TypeError) and ValuesKeyDoesNotExist, both RuntimeErrors as GTSAM
    raises, both LieFactorsErrors, naming the key with GTSAM's key formatter."""
    from lie_factors.errors import EvaluationError, LieFactorsError, ValuesIncorrectType, ValuesKeyDoesNotExist

    f = landmark(X(1), L(2), np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, 0.1))
    values = gtsam.Values()
    values.insert(X(1), gtsam.Pose3())
    values.insert(L(2), np.zeros(2))
    with pytest.raises(ValuesIncorrectType, match="landmark: key x1 holds a value of another type than the "
                                                  "gtsam.Pose2 the factor reads") as err:
        f.error(values)
    assert isinstance(err.value, (TypeError)) and isinstance(err.value, RuntimeError)
    assert isinstance(err.value, EvaluationError) and isinstance(err.value, LieFactorsError)
    values = gtsam.Values()
    values.insert(X(1), gtsam.Pose2())
    for call in (f.error, f.linearize):
        with pytest.raises(ValuesKeyDoesNotExist, match="landmark: key l2 is not in the Values") as err:
            call(values)
        assert isinstance(err.value, RuntimeError) and isinstance(err.value, LieFactorsError)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(f)
    with pytest.raises(ValuesKeyDoesNotExist, match="key l2"):  # through GTSAM's optimizer
        gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    values.insert(L(2), np.zeros(3))
    with pytest.raises(ValuesIncorrectType, match="key l2 holds a value of another type than the Point2"):
        f.error(values)
    vector4 = lf.factor("Vector4")(lambda v: v)(L(2), gtsam.noiseModel.Unit.Create(4))
    with pytest.raises(ValuesIncorrectType, match="key l2 holds a vector of shape \\(3,\\), not the Vector4"):
        vector4.error(values)


def test_construction_errors_are_lie_factors_errors_and_name_keys_as_gtsam():
    from lie_factors.errors import ArgumentTypeError, LieFactorsError

    noise = gtsam.noiseModel.Isotropic.Sigma(2, 0.1)
    with pytest.raises(InputError, match="keys must differ, got x1, x1"):
        landmark(X(1), X(1), np.zeros(2), noise)
    for bad in (lambda: landmark("x1", 2, np.zeros(2), noise), lambda: landmark(1, 2, np.zeros(2), "noise"),
                lambda: landmark(1, 2, noise), lambda: landmark(1, 2, np.zeros(2), noise, K=1)):
        with pytest.raises(ArgumentTypeError) as err:
            bad()
        assert isinstance(err.value, TypeError) and isinstance(err.value, LieFactorsError)


# ----------------------------------------------------------------------- in GTSAM


def _landmark_problem(seed=0, poses=12, landmarks=5):
    rng = np.random.default_rng(seed)
    truth = [gtsam.Pose2(4 * np.cos(0.4 * i), 4 * np.sin(0.4 * i), 0.4 * i + np.pi / 2) for i in range(poses)]
    points = [rng.uniform(-6, 6, 2) for _ in range(landmarks)]
    odo = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.05, 0.02]))
    seen = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.08]))
    ours, native = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    ours.add(PriorFactorPose2(X(0), truth[0], odo))
    native.add(gtsam.PriorFactorPose2(X(0), truth[0], odo))
    for i in range(poses - 1):
        z = truth[i].between(truth[i + 1]).compose(gtsam.Pose2(*rng.normal(0, 0.02, 3)))
        ours.add(BetweenFactorPose2(X(i), X(i + 1), z, odo))
        native.add(gtsam.BetweenFactorPose2(X(i), X(i + 1), z, odo))
    for i in range(poses):
        for j, p in enumerate(points):
            z = truth[i].transformTo(p) + rng.normal(0, 0.03, 2)
            ours.add(landmark(X(i), L(j), z, seen))
            native.add(_native_landmark(X(i), L(j), z, seen))
    initial = gtsam.Values()
    for i, T in enumerate(truth):
        initial.insert(X(i), T.compose(gtsam.Pose2(*rng.normal(0, 0.1, 3))))
    for j, p in enumerate(points):
        initial.insert(L(j), p + rng.normal(0, 0.3, 2))
    return ours, native, initial


def _native_landmark(kx, kl, z, noise):
    """The same residual as a plain gtsam.CustomFactor with GTSAM's own Jacobians."""
    def error(this, values, H):
        x, l = values.atPose2(kx), values.atPoint2(kl)
        if H is None:
            return x.transformTo(l) - z
        H1, H2 = np.zeros((2, 3), order="F"), np.zeros((2, 2), order="F")
        e = x.transformTo(l, H1, H2) - z
        H[0], H[1] = H1, H2
        return e
    return gtsam.CustomFactor(noise, [kx, kl], error)


def test_a_kind_is_exact_against_gtsams_own_derivatives_in_every_optimizer():
    ours, native, initial = _landmark_problem()
    for i in range(ours.size()):
        if not isinstance(ours.at(i), landmark):
            continue  # GTSAM's own Pose2 Jacobians are not exact (docs/factors.md)
        a = ours.at(i).linearize(initial)
        b = native.at(i).linearize(initial)
        np.testing.assert_allclose(a.jacobian()[0], b.jacobian()[0], rtol=0, atol=1e-12)
    params = gtsam.LevenbergMarquardtParams()
    ref = gtsam.LevenbergMarquardtOptimizer(native, initial, params).optimize()
    got = gtsam.LevenbergMarquardtOptimizer(ours, initial, params).optimize()
    assert native.error(ref) == pytest.approx(ours.error(got), rel=1e-9)
    isam = gtsam.ISAM2()
    isam.update(ours, initial)
    est = isam.calculateEstimate()
    assert ours.error(est) < ours.error(initial)
    cov = gtsam.Marginals(ours, got).marginalCovariance(L(2))
    ref_cov = gtsam.Marginals(native, ref).marginalCovariance(L(2))
    np.testing.assert_allclose(cov, ref_cov, rtol=1e-7)


def test_the_batch_solver_reads_a_kind_into_arrays_and_reaches_gtsams_optimum():
    ours, native, initial = _landmark_problem(seed=1)
    ref = gtsam.LevenbergMarquardtOptimizer(native, initial, gtsam.LevenbergMarquardtParams()).optimize()
    result = lf.optimize(ours, initial)
    from lie_factors.batch.graph import Problem

    problem = Problem(ours, initial)
    assert not problem.native and len(problem.kinds) == 1 and problem.kinds[0].E == 12 * 5
    assert result.error == pytest.approx(native.error(ref), rel=1e-9, abs=1e-12)
    for j in range(5):
        np.testing.assert_allclose(result.values.atPoint2(L(j)), ref.atPoint2(L(j)), atol=1e-9)
    for i in range(12):
        np.testing.assert_allclose(result.values.atPose2(X(i)).matrix(), ref.atPose2(X(i)).matrix(), atol=1e-9)
    covs = lf.Marginals(ours, result.values)
    np.testing.assert_allclose(covs.marginalCovariance(L(3)),
                               gtsam.Marginals(native, ref).marginalCovariance(L(3)), rtol=1e-6)


def test_between_and_prior_are_expressible_and_equal_the_hand_written_factors():
    between = lf.factor("Pose3", "Pose3", measured="Pose3")(lambda a, b, z: z.localCoordinates(a.between(b)))
    prior = lf.factor("Pose3", measured="Pose3")(lambda x, z: z.localCoordinates(x))
    rng = np.random.default_rng(3)
    noise = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    for _ in range(10):
        A, B, Z = (gtsam.Pose3.Expmap(rng.normal(size=6)) for _ in range(3))
        values = gtsam.Values()
        values.insert(1, A)
        values.insert(2, B)
        for ours, hand in ((between(1, 2, Z, noise), BetweenFactorPose3(1, 2, Z, noise)),
                           (prior(2, Z, noise), PriorFactorPose3(2, Z, noise))):
            a, b = ours.linearize(values), hand.linearize(values)
            # the same derivative by two products (the chain rule's and the hand-written one):
            # equal to rounding, 1e-9 of the entries' scale
            scale = np.max(np.abs(b.jacobian()[0]))
            np.testing.assert_allclose(a.jacobian()[0], b.jacobian()[0], atol=1e-9 * scale)
            np.testing.assert_allclose(a.jacobian()[1], b.jacobian()[1], atol=1e-9 * scale)


def test_robust_noise_on_a_kind_in_the_batch_solver():
    ours, native, initial = _landmark_problem(seed=2)
    huber = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.0),
                                           gtsam.noiseModel.Isotropic.Sigma(2, 0.05))
    ours.add(landmark(X(3), L(1), np.array([5.0, -5.0]), huber))  # a false observation
    native.add(_native_landmark(X(3), L(1), np.array([5.0, -5.0]), huber))
    ref = gtsam.LevenbergMarquardtOptimizer(native, initial, gtsam.LevenbergMarquardtParams()).optimize()
    result = lf.optimize(ours, initial)
    assert result.error == pytest.approx(native.error(ref), rel=1e-8)


def test_the_smoother_linearizes_a_kind_in_one_kernel_call_per_update(monkeypatch):
    """In lf.Smoother, an update's factors of a kind are linearized by one call of its kernel
    (no GTSAM callback per factor), and the estimate is gtsam.ISAM2's on the same factors."""
    from lie_factors.expressions import kind as kind_module

    ours, native, initial = _landmark_problem(seed=4, poses=8, landmarks=4)
    calls = {"kernel": 0, "callbacks": 0}
    real_kernel = kind_module.Kind.evaluate

    def counted(self, *args):
        calls["kernel"] += 1
        return real_kernel(self, *args)

    real_callback = kind_module.KindFactor._evaluate

    def callback(self, this, values, H):
        calls["callbacks"] += 1
        return real_callback(self, this, values, H)

    monkeypatch.setattr(kind_module.Kind, "evaluate", counted)
    monkeypatch.setattr(kind_module.KindFactor, "_evaluate", callback)
    smoother = lf.Smoother()
    smoother.update(ours, initial)
    assert calls == {"kernel": 1, "callbacks": 0}
    isam = gtsam.ISAM2()  # GTSAM's ISAM2 on the same factors, through their callbacks
    isam.update(ours, initial)
    ours_estimate, theirs = smoother.calculateEstimate(), isam.calculateEstimate()
    for j in range(4):
        np.testing.assert_allclose(ours_estimate.atPoint2(L(j)), theirs.atPoint2(L(j)), atol=1e-9)
