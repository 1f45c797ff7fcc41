"""SE(3) kernels, tangent [ω, v], against lie_factors.testing.reference (mpmath, 50 digits).

Bound 1e-14 (docs/conventions.md error measure) over θ = 0, 1e-200, 1e-15…1, the
coefficient thresholds straddled, up to π (exp/log) and 2π − 1e-3 (dexp/dlog),
translations 1e-3…1e2 in random directions, nearly parallel and perpendicular to ω.
"""

import functools
import math

import gtsam
import mpmath as mp
import numpy as np
import pytest

from lie_factors.kernels import coeffs as C
from support.compiled import call
from lie_factors.testing import reference as ref
from lie_factors import se3, so3

TOL = 1e-14
PI = math.pi


def _straddle(thr):
    return [thr * (1 + s) for s in (-1e-2, -1e-9, 1e-9, 1e-2)]


THRESHOLDS = [C.A_TAYLOR, C.C_TAYLOR, C.E_TAYLOR, C.QA_TAYLOR, C.QB_TAYLOR]
ANGLES_TO_PI = sorted(
    [0.0, 1e-200]
    + list(np.logspace(-15, 0, 8))
    + [t for thr in THRESHOLDS for t in _straddle(thr)]
    + [1.5, 3.0, PI - 1e-6, PI - 1e-12]
)
ANGLES_TO_2PI = ANGLES_TO_PI + [PI, PI * (1 + 1e-9), 4.0, 5.0, 6.0, 2 * PI - 1e-3]
NORMS = [1e-3, 1.0, 1e2]
MODES = ["random", "parallel", "perpendicular"]


def _points(angles, seed=0, combos=3):
    """For each angle, `combos` (translation norm, direction mode) pairs, cycling."""
    rng = np.random.default_rng(seed)
    pts = []
    k = 0
    for th in angles:
        for _ in range(combos):
            d = rng.standard_normal((2, 3))
            n = d[0] / np.linalg.norm(d[0])
            mode = MODES[k % 3]
            norm = NORMS[(k // 3) % 3]
            k += 1
            if mode == "random":
                u = d[1]
            elif mode == "parallel":
                u = n + 1e-7 * d[1]
            else:
                u = np.cross(n, d[1])
            pts.append(np.r_[th * n, norm * u / np.linalg.norm(u)])
    return pts


@functools.lru_cache(maxsize=None)
def _ref_dexp(key):
    return ref.dexp("se3", ref.mpf_vec(np.array(key)))


def _check(fun, ref_fun, pts):
    worst = (0.0, None)
    for x in pts:
        e = ref.rel_err(fun(x), ref_fun(x))
        if e > worst[0]:
            worst = (e, x)
    assert worst[0] <= TOL, worst
    return worst[0]


def test_exp_accuracy():
    _check(se3.exp, lambda x: ref.exp("se3", ref.mpf_vec(x)), _points(ANGLES_TO_PI, seed=1))


def test_dexp_accuracy():
    _check(se3.dexp, lambda x: _ref_dexp(tuple(x)), _points(ANGLES_TO_2PI, seed=2))


def test_dlog_accuracy():
    _check(se3.dlog, lambda x: mp.inverse(_ref_dexp(tuple(x))), _points(ANGLES_TO_2PI, seed=2))


def test_dlog_accuracy_near_two_pi_and_ef_threshold():
    angles = _straddle(C.EF_TAYLOR) + [2 * PI - 1e-3, 2 * PI - 1e-2]
    _check(se3.dlog, lambda x: mp.inverse(_ref_dexp(tuple(x))), _points(angles, seed=4, combos=9))


def test_ad_hat_accuracy():
    pts = _points([0.0, 0.3, 2.0, 5.0], seed=5)
    _check(se3.ad, lambda x: ref.ad("se3", ref.mpf_vec(x)), pts)
    _check(se3.hat, lambda x: ref.hat_se3(ref.mpf_vec(x)), pts)


@pytest.mark.slow
def test_log_against_mp_logm():
    worst = 0.0
    for x in _points([t for t in ANGLES_TO_PI if t <= 3.0], seed=6, combos=2):
        X = ref.to_numpy(ref.exp("se3", ref.mpf_vec(x)))
        worst = max(worst, ref.rel_err(se3.log(X), ref.log("se3", X)))
    assert worst <= TOL, worst


@pytest.mark.parametrize("delta", [1e-3, 1e-8, 1e-12, 0.0])
def test_log_near_and_at_pi_round_trip(delta):
    for x in _points([PI - delta], seed=7, combos=6):
        X = ref.to_numpy(ref.exp("se3", ref.mpf_vec(x)))
        L = se3.log(X)
        assert np.linalg.norm(L[:3]) <= PI * (1 + 4e-16)
        scale = max(1.0, np.abs(X).max())
        assert np.abs(se3.exp(L) - X).max() <= 2e-15 * scale


def test_dlog_closed_form_equals_eade_eq75_product():
    """Our L = −½u× + e(ω×u× + u×ω×) + (ωᵀu) f ω×² is Eq. (75)'s −J⁻¹ B J⁻¹."""
    for x in _points([1e-3, 0.5, 1.7, 3.0, 4.5], seed=9):
        D = se3.dexp(x)
        Ji = so3.dlog(x[:3])
        prod = -Ji @ D[3:, :3] @ Ji
        assert np.abs(se3.dlog(x)[3:, :3] - prod).max() <= 1e-13 * max(1, np.abs(prod).max())


# ------------------------------------------------------------ errata (docs/errata.md)


def test_erratum_eq65_coefficient_of_ad_is_b_not_a():
    """Eade Eq. (65) reads I + a_θ ad_x + c_θ ad_x² + (ωᵀu)[[0, Q],[0, 0]];
    the series Σ ad^i/(i+1)! gives b_θ (as Eq. 66 and 71 do)."""
    x = np.array([0.3, -0.9, 1.2, 0.7, 0.2, -0.5])
    w, u = x[:3], x[3:]
    th = np.linalg.norm(w)
    a, b, c = call(C.a_theta, th), call(C.b_theta, th), call(C.c_theta, th)
    W = so3.hat(w)
    Q = call(C.qa_theta, th) * W + call(C.qb_theta, th) * W @ W
    A = se3.ad(x)
    Qb = np.zeros((6, 6))
    Qb[3:, :3] = Q  # Eq. (65)'s upper-right block, in [ω, v] order
    R = ref.to_numpy(_ref_dexp(tuple(x)))
    eade = np.eye(6) + a * A + c * A @ A + (w @ u) * Qb
    fixed = np.eye(6) + b * A + c * A @ A + (w @ u) * Qb
    assert np.abs(eade - R).max() > 1e-2
    assert np.abs(fixed - R).max() < 1e-15
    assert ref.rel_err(se3.dexp(x), _ref_dexp(tuple(x))) <= TOL


def test_eq63_ad_cubed_verified():
    x = np.array([0.3, -0.9, 1.2, 0.7, 0.2, -0.5])
    w, u = x[:3], x[3:]
    A = se3.ad(x)
    Z = np.zeros((6, 6))
    Z[3:, :3] = so3.hat(w)
    np.testing.assert_allclose(A @ A @ A, -(w @ w) * A - 2 * (w @ u) * Z, atol=1e-15)


# ------------------------------------------------------------ group operations


def test_Ad_compose_inverse():
    for x in _points([0.2, 1.0, 3.0], seed=10):
        X = se3.exp(x)
        y = np.array([0.1, -0.2, 0.3, 1.0, -2.0, 0.5])
        np.testing.assert_allclose(X @ se3.hat(y) @ np.linalg.inv(X), se3.hat(se3.Ad(X) @ y),
                                   atol=1e-13 * max(1, np.abs(X).max()) ** 2)
        np.testing.assert_allclose(se3.compose(X, se3.inverse(X)), np.eye(4),
                                   atol=4e-15 * max(1, np.abs(X).max()))
        np.testing.assert_allclose(se3.compose(X, X), X @ X, atol=1e-15 * max(1, np.abs(X).max()) ** 2)
        # Ad(exp(x)) = exp(ad(x)) (Eade, Eq. 9)
        assert ref.rel_err(se3.Ad(X), mp.expm(ref.ad("se3", ref.mpf_vec(x)))) <= TOL
    assert np.array_equal(se3.vee(se3.hat(x)), x)


# ------------------------------------------------------------ GTSAM (tangent [ω, v], right Jacobians)


def test_against_gtsam_pose3():
    for x in _points([1e-6, 0.1, 1.0, 2.0, 3.0], seed=12):
        X = se3.exp(x)
        np.testing.assert_allclose(gtsam.Pose3.Expmap(x).matrix(), X, atol=1e-12)
        np.testing.assert_allclose(gtsam.Pose3.Logmap(gtsam.Pose3(X)), se3.log(X), atol=1e-10)
        np.testing.assert_allclose(gtsam.Pose3.ExpmapDerivative(x), se3.dexp(-x), atol=1e-9)
        np.testing.assert_allclose(gtsam.Pose3.LogmapDerivative(x), se3.dlog(-x), atol=1e-9)
        np.testing.assert_allclose(gtsam.Pose3(X).AdjointMap(), se3.Ad(X), atol=1e-12)


def test_near_pi_ours_exact_gtsam_recorded():
    gt = 0.0
    for x in _points([PI - 1e-4], seed=13):
        r = mp.inverse(_ref_dexp(tuple(-x)))
        assert ref.rel_err(se3.dlog(-x), r) <= TOL
        gt = max(gt, ref.rel_err(gtsam.Pose3.LogmapDerivative(x), r))
    print(f"GTSAM Pose3.LogmapDerivative error at pi-1e-4: {gt:.2e}")


def test_erratum_jackson_se3_series_and_blocks():
    """Jackson (SE(3) section) expands exp of [[ω×, v], [0, 1]] — the algebra element has
    0, not 1, in the corner (with 1 the corner of the exponential is e, not 1) — and says
    'the upper right block is just the rotation matrix': it is the upper LEFT block;
    the upper right is V v. Its final V and V⁻¹ formulas are right."""
    x = np.array([0.3, -0.9, 1.2, 0.7, 0.2, -0.5])
    w, v = x[:3], x[3:]
    M = ref.hat_se3(ref.mpf_vec(x))
    M[3, 3] = 1
    assert abs(mp.expm(M)[3, 3] - mp.e) < 1e-40
    X = se3.exp(x)
    np.testing.assert_allclose(X[:3, :3], so3.exp(w), atol=1e-15)
    assert np.abs(X[:3, 3] - so3.exp(w) @ v).max() > 0.1
    th = np.linalg.norm(w)
    W = so3.hat(w)
    V = np.eye(3) + (1 - np.cos(th)) / th**2 * W + (th - np.sin(th)) / th**3 * W @ W
    Vi = np.eye(3) - W / 2 + (1 - th * np.sin(th) / (2 * (1 - np.cos(th)))) / th**2 * W @ W
    np.testing.assert_allclose(X[:3, 3], V @ v, atol=1e-15)
    np.testing.assert_allclose(Vi @ V, np.eye(3), atol=1e-15)
