"""Unit quaternions [w, x, y, z], half-angle exp/log (Jackson), against mpmath at 50 digits."""

import math

import gtsam
import mpmath as mp
import numpy as np
import pytest

from lie_factors.errors import InputError
from lie_factors.kernels import coeffs as C
from lie_factors import quaternion as Q
from lie_factors.testing import reference as ref
from lie_factors import so3

TOL = 1e-14
PI = math.pi


# ------------------------------------------------------------ mp references from definitions


def qlog_mp(q):
    """Shortest log of the normalised float quaternion, at 50 digits."""
    q = [mp.mpf(float(v)) for v in q]
    n = mp.sqrt(sum(v * v for v in q))
    q = [v / n for v in q]
    if q[0] < 0:
        q = [-v for v in q]
    r = mp.sqrt(q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    if r == 0:
        return [mp.mpf(0)] * 3
    k = 2 * mp.atan2(r, q[0]) / r
    return [k * v for v in q[1:]]


def _dirs(k, seed):
    d = np.random.default_rng(seed).standard_normal((k, 3))
    return d / np.linalg.norm(d, axis=1)[:, None]


def _straddle(thr):
    return [thr * (1 + s) for s in (-1e-2, -1e-9, 1e-9, 1e-2)]


# exp uses a(θ/2): its band edge sits at θ = 2 A_TAYLOR.
ANGLES = sorted([0.0, 1e-200] + list(np.logspace(-15, 0, 16)) + _straddle(2 * C.A_TAYLOR)
                + [2.0, 3.0, PI - 1e-6, PI - 1e-12, PI, 4.0, 6.0, 2 * PI - 1e-3])


def _points(angles, per=2, seed=0):
    d = _dirs(per * len(angles), seed)
    return [a * d[per * i + j] for i, a in enumerate(angles) for j in range(per)]


def test_exp_accuracy_against_series():
    worst = 0.0
    for w in _points(ANGLES):
        worst = max(worst, ref.rel_err(Q.exp(w), ref.quat_exp(ref.mpf_vec(w))))
    assert worst <= TOL, worst


def test_rotation_of_exp_is_so3_exp():
    worst = 0.0
    for w in _points(ANGLES, seed=1):
        worst = max(worst, ref.rel_err(Q.to_rotation(Q.exp(w)), ref.exp("so3", ref.mpf_vec(w))))
        np.testing.assert_allclose(Q.to_rotation(Q.exp(w)), so3.exp(w), atol=2e-15)
    assert worst <= TOL, worst


def test_log_accuracy():
    worst = 0.0
    for w in _points([t for t in ANGLES if t <= PI], seed=2):
        q = np.array([float(v) for v in ref.quat_exp(ref.mpf_vec(w))])
        worst = max(worst, ref.rel_err(Q.log(q), qlog_mp(q)))
    assert worst <= TOL, worst


def test_log_agrees_with_matrix_log_definition():
    """qlog_mp is a closed form; check it and ours against mp.logm of the rotation."""
    for w in _points([1e-8, 0.1, 1.0, 2.5], seed=3):
        q = Q.exp(w)
        R = ref.quat_to_rotation([mp.mpf(float(v)) for v in q])
        assert ref.rel_err(Q.log(q), ref.log("so3", R)) <= TOL


def test_log_shortest_and_sign_invariant():
    for w in _points([0.5, 2.0, 3.0, 4.0, 5.5, 2 * PI - 1e-3], seed=4):
        q = Q.exp(w)
        L = Q.log(q)
        assert np.linalg.norm(L) <= PI * (1 + 4e-16)
        np.testing.assert_array_equal(L, Q.log(-q))
        np.testing.assert_allclose(so3.exp(L), so3.exp(w), atol=1e-14)
        p = Q.exp(L)
        assert min(np.abs(p - q).max(), np.abs(p + q).max()) <= 2e-16 * 4


def test_log_exactly_pi():
    for n in _dirs(4, 5):
        q = np.r_[0.0, n]
        L = Q.log(q)
        assert abs(np.linalg.norm(L) - PI) <= 1e-15
        np.testing.assert_allclose(Q.to_rotation(Q.exp(L)), Q.to_rotation(q), atol=1e-15)


def test_jackson_tan_inverse_form_is_the_shortest_log():
    """Jackson writes log q = 2 tan⁻¹(|q⃗|/q0) q⃗/|q⃗|. Verified correct (not an erratum):
    for q0 < 0 the negative angle it yields is exactly the shortest log; only q0 = 0
    needs IEEE division (|q⃗|/0 = inf, atan(inf) = π/2)."""
    for w in _points([0.3, 2.0, 4.0, 6.0], seed=6):
        q = Q.exp(w)
        r = np.linalg.norm(q[1:])
        jackson = 2 * np.arctan(r / q[0]) * q[1:] / r
        np.testing.assert_allclose(jackson, Q.log(q), atol=1e-15)


def test_from_rotation_round_trip():
    for w in _points(ANGLES, seed=7):
        q = Q.exp(w)
        p = Q.from_rotation(so3.exp(w))
        assert min(np.abs(p - q).max(), np.abs(p + q).max()) <= 1e-15


def test_compose_matches_rotation_product():
    a, b = _points([1.0, 2.5], per=1, seed=8)
    np.testing.assert_allclose(Q.to_rotation(Q.compose(Q.exp(a), Q.exp(b))), so3.exp(a) @ so3.exp(b), atol=1e-15)
    np.testing.assert_allclose(Q.to_rotation(Q.inverse(Q.exp(a))), so3.exp(-a), atol=1e-15)


@pytest.mark.parametrize("batch", [(), (5,), (2, 3), (2, 1, 4), (0,)])
def test_rotation_conversions_broadcast(batch):
    w = np.random.default_rng(0).standard_normal(batch + (3,))
    q = Q.exp(w)
    assert Q.to_rotation(q).shape == batch + (3, 3)
    assert Q.from_rotation(so3.exp(w)).shape == batch + (4,)
    for idx in np.ndindex(*batch):
        np.testing.assert_array_equal(Q.to_rotation(q)[idx], Q.to_rotation(q[idx]))


def test_rotation_conversions_reject_bad_input():
    with pytest.raises(InputError, match="unit"):
        Q.to_rotation(np.array([2.0, 0, 0, 0]))
    with pytest.raises(InputError, match="orthonormal"):
        Q.from_rotation(np.eye(3) * 1.01)
    with pytest.raises(InputError, match=r"\(\.\.\., 3, 3\)"):
        Q.from_rotation(np.eye(4))


def test_against_gtsam_quaternion():
    for w in _points([0.1, 1.0, 3.0], seed=9):
        q = Q.exp(w)
        R = gtsam.Rot3.Quaternion(*q).matrix()
        np.testing.assert_allclose(R, so3.exp(w), atol=1e-14)
        gq = gtsam.Rot3.Expmap(w).toQuaternion()
        p = np.array([gq.w(), gq.x(), gq.y(), gq.z()])
        assert min(np.abs(p - q).max(), np.abs(p + q).max()) <= 1e-14


@pytest.mark.parametrize("theta", [1e-200, 1e-300])
def test_log_of_tiny_rotations_is_exact(theta):
    """The norm of q⃗ (≈ θ/2) must not underflow: log returns θ, not 0 (q⃗ holds θ/2, so
    below ~1e-307 the halving itself rounds: subnormal numbers have fewer bits)."""
    for axis in (np.array([1.0, 0.0, 0.0]), np.array([0.6, -0.8, 0.0]), np.array([2.0, 1.0, -2.0]) / 3.0):
        w = theta * axis
        np.testing.assert_allclose(Q.log(Q.exp(w)), w, rtol=4e-16, atol=0.0)
        np.testing.assert_allclose(Q.log(Q.from_rotation(so3.exp(w))), w, rtol=4e-16, atol=0.0)
        np.testing.assert_allclose(Q.log(-Q.exp(w)), w, rtol=4e-16, atol=0.0)
