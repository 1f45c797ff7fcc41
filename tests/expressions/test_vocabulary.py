"""The vocabulary's newer operations: constant offsets, sum(), cross, elementwise products, a
variable scalar times a vector, division by a scalar expression, matrices (an element's matrix()
and AdjointMap(), products, transposes, indexing), theta, rpy, transformPoseFrom/To.  Values
against GTSAM's own (or numpy's, from scratch), Jacobians against Richardson differences, across
each branch threshold (cross of parallel vectors, a division near zero, theta near ±π, rpy near
gimbal lock)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

import lie_factors as lf
from lie_factors.errors import EvaluationError, LieFactorsError
from lie_factors.expressions import kernels, ops
from lie_factors.expressions.types import value_type
from lie_factors.interop import to_gtsam
from support.kinds import evaluate, group_exp, relative_error, richardson

GROUPS = ["Rot2", "Rot3", "Pose2", "Pose3", "Similarity2", "Similarity3"]


def check(kind, values, constants, tol=1e-8, h=1e-3):
    e, H = evaluate(kind, values, constants)
    assert np.all(np.isfinite(e))
    for j, (a, n) in enumerate(zip(H, richardson(kind, values, constants, h=h))):
        err = relative_error(a, n)
        assert err <= tol, (kind.name, j, err)
    return e


def element(name, rng, scale=1.0):
    t = value_type(name)
    return group_exp(t, scale * rng.normal(size=t.dim))


def gtsam_of(name, M):
    if name == "Rot2":
        return gtsam.Rot2.atan2(M[1, 0], M[0, 0])
    return to_gtsam(name, M)


# ----------------------------------------------------------------------- vectors

M23 = np.arange(6.0).reshape(2, 3) - 2.0


@lf.factor("Point3", "Point3", "Vector1")
def vectors(a, b, s):
    return ops.stack(a - 1.0, 2.0 - a, np.ones(3) + a, a + np.array([0.5, -1.0, 2.0]), sum([a, b]), a.cross(b),
                     ops.cross(b, a), a * b, np.array([1.0, -2.0, 3.0]) * a, s * a, a * s, a / s, 1.0 / s,
                     np.float64(2.0) * a, M23 @ a, a @ M23.T, a.dot(b), s * np.array([1.0, 0.0, -1.0]))


def expected_vectors(a, b, s):
    return np.concatenate([a - 1.0, 2.0 - a, 1.0 + a, a + [0.5, -1.0, 2.0], a + b, np.cross(a, b), np.cross(b, a),
                           a * b, [1.0, -2.0, 3.0] * a, s * a, a * s, a / s, 1.0 / s, 2.0 * a, M23 @ a, a @ M23.T,
                           [a @ b], s * np.array([1.0, 0.0, -1.0])])


def test_vector_arithmetic_values_and_jacobians():
    rng = np.random.default_rng(1)
    for _ in range(5):
        a, b, s = rng.normal(size=3), rng.normal(size=3), rng.uniform(0.5, 2.0, 1) * rng.choice([-1, 1])
        e = check(vectors.kind, [a, b, s], [])
        np.testing.assert_allclose(e, expected_vectors(a, b, s), rtol=1e-14, atol=1e-14)


def test_cross_is_exact_for_parallel_vectors():
    """GTSAM's cross (C++ only: the wheel does not wrap it) is numpy's: D_a = −[b]×, D_b = [a]×."""
    a = np.array([0.3, -1.2, 2.0])
    for b in (2.5 * a, -a, a + 1e-9 * np.array([1.0, 0.0, 0.0])):  # parallel, and nearly
        e = check(vectors.kind, [a, b, np.array([1.0])], [])
        np.testing.assert_allclose(e[15:18], np.cross(a, b), atol=1e-15)


def test_sum_starts_at_zero_and_adding_zero_adds_no_node():
    kind = lf.factor("Point3", "Point3")(lambda a, b: sum([a, b]) - 0 + 0.0).kind
    assert [n.op for n in kind.nodes].count("add") == 1 and "literal" not in [n.op for n in kind.nodes]


def test_division_by_a_scalar_near_zero_is_finite_and_at_zero_refused():
    a, b = np.array([0.3, -1.2, 2.0]), np.array([1.0, 0.5, -0.2])
    for s in (1e-6, -1e-6, 1e-3):
        # a / s is finite and exact near zero; the step of the differences scales with s
        check(vectors.kind, [a, b, np.array([s])], [], tol=1e-7, h=abs(s) * 1e-2)
    e, _, status = evaluate(vectors.kind, [a, b, np.array([0.0])], [], status=True)
    node = vectors.kind.nodes[status - 1]
    assert node.op == "div"
    # the factor: an EvaluationError naming the line and the keys
    f = vectors(gtsam.symbol("p", 1), gtsam.symbol("p", 2), gtsam.symbol("s", 0), gtsam.noiseModel.Unit.Create(vectors.kind.dim))
    values = gtsam.Values()
    values.insert(gtsam.symbol("p", 1), a)
    values.insert(gtsam.symbol("p", 2), b)
    values.insert(gtsam.symbol("s", 0), np.array([0.0]))
    with pytest.raises(EvaluationError, match=r"vectors on p1, p2, s0: vectors, line \d+: division by zero") as err:
        f.error(values)
    assert isinstance(err.value, LieFactorsError) and isinstance(err.value, RuntimeError)


# ----------------------------------------------------------------------- matrices


@lf.factor(*GROUPS, "Vector3", "Point3")
def matrices(r2, r3, p2, p3, s2, s3, v, q):
    M = r3.matrix()
    return ops.stack(*(g.matrix().flatten() for g in (r2, r3, p2, p3, s2, s3)),
                     *(g.AdjointMap().flatten() for g in (r2, r3, p2, p3, s2, s3)),
                     (M.T @ M).flatten(), M @ q, q @ M, M[0, 1], M[:, 2], M[1], M.T[2, 0:2], M[::2, 1:].flatten(),
                     (M - np.eye(3)).flatten(), (2.0 * M + M).flatten(), (v[0] * M).flatten(), (np.eye(3) @ M).flatten(),
                     (M @ np.diag([1.0, 2.0, 3.0])).flatten(), M.norm(), p3.AdjointMap() @ ops.stack(v, q),
                     -(p3.matrix() @ np.array([1.0, 2.0, 3.0, 1.0])))


def test_matrix_and_adjoint_map_against_gtsams_and_differences():
    rng = np.random.default_rng(2)
    kind = matrices.kind
    for scale in (1e-7, 0.3, 1.5, 2.9):  # angles near 0 up to near π
        values = [element(g, rng, scale) for g in GROUPS] + [rng.normal(size=3), rng.normal(size=3)]
        e = check(kind, values, [])
        off = 0
        for name, X in zip(GROUPS, values):
            M = gtsam_of(name, X).matrix()
            np.testing.assert_allclose(e[off:off + M.size], M.ravel(), atol=1e-14)
            off += M.size
        for name, X in zip(GROUPS, values):
            Ad = gtsam_of(name, X).AdjointMap()
            np.testing.assert_allclose(e[off:off + Ad.size], np.ravel(Ad), atol=1e-12 * max(1.0, np.abs(Ad).max()))
            off += np.size(Ad)
        R, v, q, X = values[1], values[6], values[7], values[3]
        expected = np.concatenate([(R.T @ R).ravel(), R @ q, q @ R, [R[0, 1]], R[:, 2], R[1], R.T[2, 0:2],
                                   R[::2, 1:].ravel(), (R - np.eye(3)).ravel(), (3.0 * R).ravel(), (v[0] * R).ravel(),
                                   R.ravel(), (R @ np.diag([1.0, 2.0, 3.0])).ravel(), [np.linalg.norm(R)],
                                   gtsam.Pose3(X).AdjointMap() @ np.concatenate([v, q]),
                                   -(X @ np.array([1.0, 2.0, 3.0, 1.0]))])
        np.testing.assert_allclose(e[off:], expected, atol=1e-12)


# ----------------------------------------------------------------------- angles and poses


@lf.factor("Rot2", "Pose2", "Pose3", "Pose3")
def angles(a, x, X, Y):
    return ops.stack(a.theta(), x.theta(), X.transformPoseFrom(Y).logmap(), X.transformPoseTo(Y).logmap())


def test_theta_and_transform_pose_against_gtsams():
    rng = np.random.default_rng(3)
    # theta: up to 2e-3 of ±π, where a difference step of 1e-4 stays on one side of the cut
    for th in (0.0, 1e-9, 1.0, -2.5, np.pi - 2e-3, -np.pi + 2e-3):
        a = group_exp(value_type("Rot2"), np.array([th]))
        x = group_exp(value_type("Pose2"), np.array([0.3, -0.2, th]))
        X, Y = element("Pose3", rng), element("Pose3", rng)
        e = check(angles.kind, [a, x, X, Y], [], h=1e-4)
        gX, gY = gtsam.Pose3(X), gtsam.Pose3(Y)
        expected = np.concatenate([[gtsam_of("Rot2", a).theta(), gtsam_of("Pose2", x).theta()],
                                   gtsam.Pose3.Logmap(gX.transformPoseFrom(gY)),
                                   gtsam.Pose3.Logmap(gX.transformPoseTo(gY))])
        np.testing.assert_allclose(e, expected, atol=1e-12)
    # values at ±π itself: GTSAM's theta (atan2)
    for th in (np.pi, -np.pi + 1e-12, np.pi - 1e-12):
        a = group_exp(value_type("Rot2"), np.array([th]))
        e, _ = evaluate(angles.kind, [a, group_exp(value_type("Pose2"), np.array([0, 0, th])), np.eye(4), np.eye(4)], [])
        assert e[0] == gtsam_of("Rot2", a).theta() and e[1] == gtsam_of("Rot2", a).theta()


@lf.factor("Rot3")
def euler(R):
    return ops.stack(R.rpy(), R.ypr(), R.roll(), R.pitch(), R.yaw())


def _rpy_of_gtsam(R, jacobian=False):
    H = np.zeros((3, 3), order="F")
    v = gtsam.Rot3(R).rpy(H) if jacobian else gtsam.Rot3(R).rpy()
    return (v, H) if jacobian else v


def test_rpy_against_gtsams_values_and_jacobians():
    rng = np.random.default_rng(4)
    for pitch in (0.0, 0.7, -1.2, -np.pi / 2 + 0.05, np.pi / 2 - 0.05):
        R = gtsam.Rot3.Ypr(rng.uniform(-3, 3), pitch, rng.uniform(-3, 3)).matrix()
        e = check(euler.kind, [R], [], h=1e-4)
        v, H = _rpy_of_gtsam(R, True)
        np.testing.assert_allclose(e[:3], v, atol=1e-12)
        np.testing.assert_allclose(e[3:6], v[::-1], atol=1e-12)
        np.testing.assert_allclose(e[6:], v, atol=1e-12)
        _, (D,) = evaluate(euler.kind, [R], [])
        np.testing.assert_allclose(D[:3], H, atol=1e-9 * max(1.0, np.abs(H).max()))


def test_rpy_near_gimbal_lock_is_refused_as_gtsams_and_finite_where_gtsams_is():
    band = kernels.GIMBAL_BAND
    for pitch, refused in ((np.pi / 2 - 0.99 * band, True), (np.pi / 2 - 1.01 * band, False), (np.pi / 2, True),
                           (-np.pi / 2 + 0.99 * band, False), (-np.pi / 2 + 1e-4, False)):
        R = gtsam.Rot3.Ypr(0.3, pitch, -0.4).matrix()
        try:
            _rpy_of_gtsam(R, True)
            gtsam_refused = False
        except RuntimeError as exc:
            assert "gimbal lock" in str(exc)
            gtsam_refused = True
        assert gtsam_refused == refused
        e, (D,), status = evaluate(euler.kind, [R], [], status=True)
        np.testing.assert_allclose(e[:3], _rpy_of_gtsam(R), atol=1e-9)  # the values, always
        if refused:
            assert euler.kind.nodes[status - 1].op == "rpy"
        else:
            assert status == 0 and np.all(np.isfinite(D))
            check(euler.kind, [R], [], tol=1e-6, h=1e-7)
        e, _, status = evaluate(euler.kind, [R], [], jacobians=False, status=True)
        assert status == 0  # without the Jacobian nothing is refused, as GTSAM's rpy()
    f = euler(gtsam.symbol("r", 3), gtsam.noiseModel.Unit.Create(euler.kind.dim))
    values = gtsam.Values()
    values.insert(gtsam.symbol("r", 3), gtsam.Rot3.Ypr(0.3, np.pi / 2 - 1e-3, -0.4))
    f.error(values)
    with pytest.raises(EvaluationError, match=r"euler on r3: euler, line \d+: rpy: its derivative is undefined "
                                              r"within 0.01 of pitch = π/2 \(gimbal lock\)"):
        f.linearize(values)
