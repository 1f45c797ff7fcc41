"""Unit dual quaternions [q_r, q_d], q_d = ½ (0, t) ⊗ q_r, tangent [ω, v] as se3 (Jackson)."""

import math

import mpmath as mp
import numpy as np
import pytest

from lie_factors.errors import InputError
from lie_factors.kernels import coeffs as C
from support.compiled import call
from lie_factors import dual_quaternion as DQ
from lie_factors.testing import reference as ref
from lie_factors import se3


TOL = 1e-14
PI = math.pi


def dq_exp_mp(xi):
    """[q_r, ½ (0, t) ⊗ q_r] from the definitions: q_r by the quaternion series, t from expm(hat xi)."""
    m = ref.mpf_vec(xi)
    qr = ref.quat_exp(m[:3])
    X = ref.exp("se3", m)
    qd = [v / 2 for v in ref.quat_mul([mp.mpf(0), X[0, 3], X[1, 3], X[2, 3]], qr)]
    return qr + qd


def dq_log_mp(dq):
    """vee(logm) of the 4×4 transform of the float dual quaternion, at 50 digits."""
    q = [mp.mpf(float(v)) for v in dq]
    qr, qd = q[:4], q[4:]
    conj = [qr[0], -qr[1], -qr[2], -qr[3]]
    t = [2 * v for v in ref.quat_mul(qd, conj)[1:]]
    R = ref.quat_to_rotation(qr)
    X = mp.matrix(4, 4)
    for i in range(3):
        for j in range(3):
            X[i, j] = R[i, j]
        X[i, 3] = t[i]
    X[3, 3] = 1
    return ref.log("se3", X)


def _straddle(thr):
    return [thr * (1 + s) for s in (-1e-2, -1e-9, 1e-9, 1e-2)]


# exp evaluates a, b, c at h = θ/2; log evaluates a at φ = θ/2 and c at 2φ = θ.
EDGES = [2 * C.A_TAYLOR, 2 * C.C_TAYLOR, C.C_TAYLOR]
ANGLES = sorted([0.0, 1e-200] + list(np.logspace(-15, 0, 8)) + [t for e in EDGES for t in _straddle(e)]
                + [2.0, 3.0, PI - 1e-6])


def _points(angles, seed=0, combos=3):
    rng = np.random.default_rng(seed)
    pts, k = [], 0
    for th in angles:
        for _ in range(combos):
            d = rng.standard_normal((2, 3))
            n = d[0] / np.linalg.norm(d[0])
            mode, norm = k % 3, [1e-3, 1.0, 1e2][(k // 3) % 3]
            k += 1
            u = d[1] if mode == 0 else (n + 1e-7 * d[1] if mode == 1 else np.cross(n, d[1]))
            pts.append(np.r_[th * n, norm * u / np.linalg.norm(u)])
    return pts


def test_exp_accuracy():
    worst = 0.0
    for xi in _points(ANGLES + [4.0, 6.0]):
        worst = max(worst, ref.rel_err(DQ.exp(xi), dq_exp_mp(xi)))
    assert worst <= TOL, worst


def test_exp_is_se3_exp_as_rigid_transform():
    worst = 0.0
    for xi in _points(ANGLES, seed=1):
        worst = max(worst, ref.rel_err(DQ.to_matrix(DQ.exp(xi)), ref.exp("se3", ref.mpf_vec(xi))))
        scale = max(1.0, np.abs(xi).max())
        assert np.abs(DQ.to_matrix(DQ.exp(xi)) - se3.exp(xi)).max() <= 4e-15 * scale
    assert worst <= TOL, worst


def test_log_accuracy():
    worst = 0.0
    for xi in _points([t for t in ANGLES if t <= 3.0], seed=2, combos=2):
        dq = np.array([float(v) for v in dq_exp_mp(xi)])
        worst = max(worst, ref.rel_err(DQ.log(dq), dq_log_mp(dq)))
    assert worst <= TOL, worst


@pytest.mark.parametrize("delta", [1e-6, 1e-12, 0.0])
def test_log_near_pi_round_trip_and_sign(delta):
    for xi in _points([PI - delta, PI + 1.0], seed=3):
        dq = DQ.exp(xi)
        L = DQ.log(dq)
        assert np.linalg.norm(L[:3]) <= PI * (1 + 4e-16)
        np.testing.assert_array_equal(L, DQ.log(-dq))
        scale = max(1.0, np.abs(se3.exp(xi)).max())
        assert np.abs(DQ.to_matrix(DQ.exp(L)) - se3.exp(xi)).max() <= 4e-15 * scale
        if delta > 0:
            np.testing.assert_allclose(L, se3.log(se3.exp(xi)), atol=1e-13 * scale)


def test_compose_inverse():
    a, b = _points([0.7, 2.9], seed=4, combos=1)
    A, B = DQ.exp(a), DQ.exp(b)
    np.testing.assert_allclose(DQ.to_matrix(DQ.compose(A, B)), se3.exp(a) @ se3.exp(b), atol=1e-12)
    np.testing.assert_allclose(DQ.to_matrix(DQ.inverse(A)), se3.inverse(se3.exp(a)), atol=1e-13)


# ------------------------------------------------------------ Jackson checks (docs/errata.md)


def test_jackson_exp_formula_verified():
    """Jackson's boxed dual exponential, literally, equals ours (and [ω, v] = se3's order)."""
    for xi in _points([0.3, 1.0, 2.5], seed=5, combos=1):
        w, v = xi[:3], xi[3:]
        th, g, h = np.linalg.norm(w), w @ v, np.linalg.norm(w) / 2
        jackson = np.r_[np.cos(h), np.sin(h) / th * w, -g / (2 * th) * np.sin(h),
                     g * (0.5 * np.cos(h) - np.sin(h) / th) / th**2 * w + np.sin(h) / th * v]
        np.testing.assert_allclose(jackson, DQ.exp(xi), atol=1e-14)


def test_erratum_dq_log_small_angle_series():
    """Jackson replaces (r0 − a)γ/θ² (θ = |r|) by γ (θ cos(θ/2) − tan⁻¹(θ/r0))/θ³, using
    r0 = cos(θ/2) although θ there is |r| = sin(φ), r0 = cos(φ); and gives the series
    5/24 − 379/1920 θ² + … The correct quantity (θ r0 − tan⁻¹(θ/r0))/θ³ with
    r0 = √(1 − θ²) is −2/3 − θ²/5 − 3θ⁴/28 − …"""
    s = mp.mpf("1e-3")
    r0 = mp.sqrt(1 - s**2)
    correct = (s * r0 - mp.atan(s / r0)) / s**3
    jackson_expr = (s * mp.cos(s / 2) - mp.atan(s / mp.cos(s / 2))) / s**3
    jackson_series = mp.mpf(5) / 24 - mp.mpf(379) / 1920 * s**2
    assert abs(correct - (-mp.mpf(2) / 3 - s**2 / 5)) < 1e-12
    assert abs(jackson_expr - correct) > 0.5 and abs(jackson_series - correct) > 0.5
    # ours: the same quantity as −4 c(2φ)/a(φ)³, φ = asin(s)
    phi = float(mp.asin(s))
    ours = -4 * call(C.c_theta, 2 * phi) / call(C.a_theta, phi) ** 3
    assert abs(ours - correct) <= 1e-15
    # and with Jackson's series plugged in, log is wrong by ≈ 1.75 (rᵀd) |r|:
    xi = np.array([2e-3, 0.0, 0.0, 5.0, 1.0, 0.0])
    dq = DQ.exp(xi)
    r0, r, d0, d = dq[0], dq[1:4], dq[4], dq[5:]
    a = np.arctan(np.linalg.norm(r) / r0) / np.linalg.norm(r)
    bad = 2 * (a * d + (float(jackson_series) * (r @ d) - d0) * r)
    assert np.abs(bad - xi[3:]).max() > 1e-6  # ~0.9 γ|r|, vs ≤ 1e-14 required
    assert ref.rel_err(DQ.log(dq), dq_log_mp(dq)) <= TOL


def test_jackson_exact_log_formula_verified():
    """Away from θ = 0 Jackson's exact dual log (with tan⁻¹) is right."""
    for xi in _points([0.5, 2.0, 3.0], seed=6, combos=1):
        dq = DQ.exp(xi)
        r0, r, d0, d = dq[0], dq[1:4], dq[4], dq[5:]
        th = np.linalg.norm(r)
        a, b = np.arctan(th / r0) / th, (r @ d) / th**2
        jackson = np.r_[2 * a * r, 2 * (a * d + ((r0 - a) * b - d0) * r)]
        np.testing.assert_allclose(jackson, DQ.log(dq), atol=1e-12 * max(1, np.abs(xi).max()))


# ------------------------------------------------------------ shapes / validation


@pytest.mark.parametrize("batch", [(), (5,), (2, 3), (2, 1, 4), (0,)])
def test_to_matrix_broadcasts(batch):
    dq = DQ.exp(np.random.default_rng(0).standard_normal(batch + (6,)))
    assert DQ.to_matrix(dq).shape == batch + (4, 4)
    for idx in np.ndindex(*batch):
        np.testing.assert_array_equal(DQ.to_matrix(dq)[idx], DQ.to_matrix(dq[idx]))


def test_to_matrix_rejects_non_unit():
    with pytest.raises(InputError, match="unit"):
        DQ.to_matrix(np.r_[1.1, 0, 0, 0, 0, 0, 0, 0])
    with pytest.raises(InputError, match="unit"):
        DQ.to_matrix(np.r_[1.0, 0, 0, 0, 0.5, 0, 0, 0])  # q_r . q_d != 0


@pytest.mark.parametrize("t", [1e-300, 1.0, 1e200, 1e300])
@pytest.mark.parametrize("th", [0.0, 1e-200, 0.7])
def test_extreme_translations_round_trip_without_overflow(t, th):
    """Huge and tiny translations: no overflow in the unit check (‖q_d‖² would be inf at 1e200)."""
    x = np.array([th, 0.0, 0.0, t, -0.5 * t, 0.25 * t])
    with np.errstate(over="raise", invalid="raise"):
        dq = DQ.exp(x)
        back = DQ.log(dq)
        M = DQ.to_matrix(dq)
    ref = se3.exp(x)[:3, 3]
    assert np.all(np.isfinite(M)) and np.all(np.isfinite(back))
    assert np.max(np.abs(back - x)) <= 1e-15 * np.max(np.abs(x))
    assert np.max(np.abs(M[:3, 3] - ref)) <= 1e-15 * np.max(np.abs(ref))


def test_non_orthogonal_dual_part_rejected_even_when_huge():
    dq = DQ.exp(np.array([0.1, 0.2, 0.3, 1e200, 0.0, 0.0]))
    bad = dq.copy()
    bad[4:] += 1e-3 * np.abs(bad[4:]).max() * bad[:4]  # q_r·q_d no longer 0
    with pytest.raises(InputError, match="unit dual quaternions"):
        DQ.log(bad)
