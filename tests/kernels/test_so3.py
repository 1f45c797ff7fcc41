"""SO(3) kernels and the shared coefficients of lie_factors.kernels.coeffs.

Accuracy is measured as in docs/conventions.md against lie_factors.testing.reference
(mpmath, 50 digits, from the definitions), bound 1e-14 everywhere.
"""

import math

import gtsam
import mpmath as mp
import numpy as np
import pytest

from lie_factors.kernels import coeffs as C
from support.compiled import call
from lie_factors.testing import reference as ref
from lie_factors import so3

TOL = 1e-14
PI = math.pi


def _dirs(k, seed):
    d = np.random.default_rng(seed).standard_normal((k, 3))
    return d / np.linalg.norm(d, axis=1)[:, None]


def _straddle(thr):
    return [thr * (1 + s) for s in (-1e-2, -1e-6, -1e-9, 1e-9, 1e-6, 1e-2)]


THRESHOLDS = [C.A_TAYLOR, C.C_TAYLOR, C.E_TAYLOR, C.QA_TAYLOR, C.QB_TAYLOR]
# 0, 1e-200, log sweep 1e-15..1, every threshold straddled, up to π.
ANGLES_TO_PI = sorted(
    [0.0, 1e-200, 1e-100]
    + list(np.logspace(-15, 0, 16))
    + [t for thr in THRESHOLDS for t in _straddle(thr)]
    + [1.5, 2.5, 3.0, PI - 1e-3, PI - 1e-6, PI - 1e-12, PI]
)
# dexp/dlog are also defined for π < θ < 2π.
ANGLES_TO_2PI = ANGLES_TO_PI + [
    t for t in _straddle(C.E_REFLECT) if t > PI
] + [4.0, 5.0, 6.0, 2 * PI - 1e-3, 2 * PI - 1e-6]


def _points(angles, per_angle=2, seed=0):
    d = _dirs(per_angle * len(angles), seed)
    return [a * d[per_angle * i + j] for i, a in enumerate(angles) for j in range(per_angle)]


def _worst(fun, ref_fun, pts):
    worst = (0.0, None)
    for x in pts:
        e = ref.rel_err(fun(x), ref_fun(ref.mpf_vec(x)))
        if e > worst[0]:
            worst = (e, x)
    return worst


# ------------------------------------------------------------ coefficients

_MP_COEFFS = {
    "a_theta": lambda t: mp.sin(t) / t,
    "b_theta": lambda t: (1 - mp.cos(t)) / t**2,
    "c_theta": lambda t: (t - mp.sin(t)) / t**3,
    "e_theta": lambda t: 1 / t**2 - mp.cot(t / 2) / (2 * t),
    "qa_theta": lambda t: (mp.sin(t) / t - 2 * (1 - mp.cos(t)) / t**2) / t**2,
    "qb_theta": lambda t: ((1 - mp.cos(t)) / t**2 - 3 * (t - mp.sin(t)) / t**3) / t**2,
}
_LIMITS = {"a_theta": 1, "b_theta": 0.5, "c_theta": mp.mpf(1) / 6, "e_theta": mp.mpf(1) / 12,
           "qa_theta": -mp.mpf(1) / 12, "qb_theta": -mp.mpf(1) / 60}


@pytest.mark.parametrize("name", sorted(_MP_COEFFS))
def test_coefficients_relative_accuracy_straddling_thresholds(name):
    """Every coefficient to ≤ 2e-15 relative, at both sides of every threshold."""
    helper = getattr(C, name)

    def f(t):
        return call(helper, t)

    angles = sorted(set([1e-300, 1e-200, 1e-15, 1e-8, 1e-4, 0.1, 0.5, 1.0, 1.9, 2.2, 3.0, PI, 4.0, 5.5])
                    | {t for thr in THRESHOLDS for t in _straddle(thr)})
    if name == "e_theta":
        angles = [t for t in angles if t <= PI]  # beyond π: e_omega (double-double)
    for t in angles:
        with mp.workdps(150):  # the definitions cancel ~θ⁴ at small θ
            r = _MP_COEFFS[name](mp.mpf(t)) if t > 1e-100 else _LIMITS[name]
        assert abs(f(t) - r) <= 2e-15 * abs(r), (name, t)
    assert f(0.0) == float(_LIMITS[name])


def test_e_omega_near_two_pi():
    for t in [3.2, 4.0, 5.0, 6.0, 2 * PI - 1e-3, 2 * PI - 1e-6]:
        for d in _dirs(3, 7):
            w = t * d
            tm = mp.sqrt(sum(mp.mpf(float(v)) ** 2 for v in w))
            r = _MP_COEFFS["e_theta"](tm)
            assert abs(call(C.e_omega, *w) - r) <= 2e-15 * abs(r), t


def test_norm3_no_underflow():
    assert call(C.norm3, 1e-200, 0.0, 0.0) == 1e-200
    assert call(C.norm3, 3e-170, 4e-170, 0.0) == pytest.approx(5e-170, rel=1e-15)
    assert call(C.norm3, 3e200, 4e200, 0.0) == pytest.approx(5e200, rel=1e-15)


# ------------------------------------------------------------ accuracy sweeps


@pytest.mark.parametrize("fname", ["exp", "dexp", "dlog", "ad", "hat"])
def test_accuracy_against_mp_reference(fname):
    angles = ANGLES_TO_PI if fname == "exp" else ANGLES_TO_2PI
    ref_fun = {
        "exp": lambda x: ref.exp("so3", x),
        "dexp": lambda x: ref.dexp("so3", x),
        "dlog": lambda x: ref.dlog("so3", x),
        "ad": lambda x: ref.ad("so3", x),
        "hat": lambda x: ref.hat_so3(x),
    }[fname]
    err, x = _worst(getattr(so3, fname), ref_fun, _points(angles))
    assert err <= TOL, (fname, err, x)


def _log_points():
    # log of float64(exp(x)) against mp.logm of that float matrix, θ ≤ 3.
    return _points([t for t in ANGLES_TO_PI if t <= 3.0], per_angle=2, seed=3)


def test_log_against_mp_logm():
    worst = 0.0
    for x in _log_points():
        X = ref.to_numpy(ref.exp("so3", ref.mpf_vec(x)))
        worst = max(worst, ref.rel_err(so3.log(X), ref.log("so3", X)))
    assert worst <= TOL, worst


@pytest.mark.parametrize("delta", [1e-1, 1e-3, 1e-6, 1e-9, 1e-12, 1e-15, 0.0])
def test_log_near_and_at_pi(delta):
    """Near π the principal log is ill-posed for the rounded matrix: check the
    round trip exp(log X) = X, |log X| ≤ π, and closeness to the true x."""
    for d in _dirs(4, 11):
        x = (PI - delta) * d
        X = ref.to_numpy(ref.exp("so3", ref.mpf_vec(x)))
        L = so3.log(X)
        assert np.linalg.norm(L) <= PI * (1 + 4e-16)
        assert ref.rel_err(so3.exp(L), ref.exp("so3", ref.mpf_vec(L))) <= TOL
        assert np.abs(so3.exp(L) - X).max() <= 1e-15
        if delta >= 1e-12:
            assert np.abs(L - x).max() <= 1e-14
        else:  # at π, x and −x are both logs
            assert min(np.abs(L - x).max(), np.abs(L + x).max()) <= 1e-14


def test_log_exactly_pi_integer_matrices():
    for R in [np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1]),
              np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])]:
        L = so3.log(R)
        assert abs(np.linalg.norm(L) - PI) <= 4e-16
        assert np.abs(so3.exp(L) - R).max() <= 1e-15


def test_log_branch_straddle_sym_cos():
    # cos θ = LOG_SYM_COS ⇔ θ = π/2: both branches must agree there.
    for t in [PI / 2 * (1 + s) for s in (-1e-9, -1e-12, 0, 1e-12, 1e-9)]:
        for x in _points([t], per_angle=3, seed=5):
            X = ref.to_numpy(ref.exp("so3", ref.mpf_vec(x)))
            assert ref.rel_err(so3.log(X), ref.log("so3", X)) <= TOL


def test_Ad_and_group_ops():
    xs = _points([0.3, 1.0, 2.0, 3.0], seed=9)
    for x in xs:
        X = so3.exp(x)
        assert np.array_equal(so3.Ad(X), X)
        y = np.array([0.1, -0.2, 0.3])
        np.testing.assert_allclose(X @ so3.hat(y) @ X.T, so3.hat(so3.Ad(X) @ y), atol=1e-15)
        np.testing.assert_allclose(so3.compose(X, so3.inverse(X)), np.eye(3), atol=1e-15)
    Xs = so3.exp(np.array(xs))
    np.testing.assert_allclose(so3.compose(Xs, Xs[::-1]), Xs @ Xs[::-1], atol=1e-15)
    np.testing.assert_array_equal(so3.inverse(Xs), np.swapaxes(Xs, -1, -2))


# ------------------------------------------------------------ GTSAM (right Jacobians)


def test_against_gtsam_moderate_angles():
    for x in _points([1e-6, 0.1, 0.5, 1.0, 2.0, 3.0], per_angle=3, seed=21):
        R = so3.exp(x)
        np.testing.assert_allclose(gtsam.Rot3.Expmap(x).matrix(), R, atol=1e-14)
        np.testing.assert_allclose(gtsam.Rot3.Logmap(gtsam.Rot3(R)), so3.log(R), atol=1e-12)
        np.testing.assert_allclose(gtsam.Rot3.ExpmapDerivative(x), so3.dexp(-x), atol=1e-9)
        np.testing.assert_allclose(gtsam.Rot3.LogmapDerivative(x), so3.dlog(-x), atol=1e-9)


def test_near_pi_ours_exact_gtsam_recorded():
    """Near π GTSAM's LogmapDerivative drifts (~1e-10); ours stays ≤ 1e-14."""
    gt_err = 0.0
    for x in _points([PI - 1e-4, PI - 1e-6], per_angle=2, seed=23):
        r = ref.dlog("so3", ref.mpf_vec(-x))
        assert ref.rel_err(so3.dlog(-x), r) <= TOL
        gt_err = max(gt_err, ref.rel_err(gtsam.Rot3.LogmapDerivative(x), r))
    print(f"GTSAM Rot3.LogmapDerivative error near pi: {gt_err:.2e}")
