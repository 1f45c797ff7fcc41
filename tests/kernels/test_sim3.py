"""Sim(3) kernels, tangent [ω, u, λ], against lie_factors.testing.reference (mpmath, 50 digits).

error = max|ours − ref| / max(1, max|ref|) (docs/conventions.md) ≤ 1e-14 everywhere and ≤ 2e-15
where |λ| ≤ 5, on the 2-D grid θ ∈ {0, 1e-200, 1e-15, 1e-8, 1e-4, 1e-2, 0.3, 1, 2,
3, π − 1e-12, π} (and π(1 + 1e-9), 4, 5, 6, 2π − 1e-3 for dexp and dlog) × λ ∈ {0, ±1e-200,
±1e-4, ±0.1, ±1, ±5, ±45, ±θ}: θ and λ → 0 apart (one of them 0 or 1e-200) and
together (λ = ±θ, and λ² + θ² → 0 along other directions), translations 1e-3, 1, 1e2 in
random directions, nearly parallel and perpendicular to ω. Every branch threshold of the
module (Z_BAND and Z_BAND_W in several directions of z, L_TAYLOR, SPECTRAL, LAM_SPECTRAL) and of the SO(3)
coefficient functions it evaluates is straddled by ×(1 ± 1e-9). Each point's 50-digit D_exp
is computed once and serves both dexp and dlog (the 50-digit references are most of the
file's time).
"""

from __future__ import annotations

import math

import gtsam
import mpmath as mp
import numpy as np
import pytest

from lie_factors.kernels import coeffs as C
from lie_factors.testing import reference as ref
from lie_factors import sim3

TOL = 1e-14
PI = math.pi
G = "sim3"

TOL_SMALL_LAMBDA = 2e-15  # wherever |λ| ≤ 5
THETAS = [0.0, 1e-200, 1e-15, 1e-8, 1e-4, 1e-2, 0.3, 1.0, 2.0, 3.0, PI - 1e-12, PI]
THETAS_BEYOND_PI = [PI * (1 + 1e-9), 4.0, 5.0, 6.0, 2 * PI - 1e-3]
NORMS = [1e-3, 1.0, 1e2]
MODES = ["random", "parallel", "perpendicular"]


def _lambdas(th):
    vals = (1e-200, 1e-4, 0.1, 1.0, 5.0, 45.0) + ((th,) if th not in (0.0, 1e-200) else ())
    return [0.0] + [s * v for v in vals for s in (1.0, -1.0)]


def _tol(x):
    return TOL_SMALL_LAMBDA if abs(x[6]) <= 5.0 else TOL


def _straddle(thr):
    return [thr * (1 - 1e-9), thr * (1 + 1e-9)]


THRESHOLD_THETAS = [
    t
    for thr in (C.A_TAYLOR, C.C_TAYLOR, C.QA_TAYLOR, C.QB_TAYLOR, C.E_TAYLOR, sim3.SPECTRAL, sim3.Z_BAND)
    for t in _straddle(thr)
]


def _grid(thetas, lam_subset=None):
    out = []
    for th in thetas:
        lams = _lambdas(th) if lam_subset is None else lam_subset
        out.extend((th, lam) for lam in lams)
    return out


def _special():
    """(θ, λ) straddling the z band |z| = Z_BAND in several directions, the λ band |λ| = L_TAYLOR
    and |λ| = LAM_SPECTRAL at several θ, and λ² + θ² → 0 off the diagonals."""
    out = []
    for f in _straddle(sim3.Z_BAND) + _straddle(sim3.Z_BAND_W):
        for ang in (0.0, 0.3, 0.5 * PI, 0.8 * PI, PI, 1.3 * PI):
            out.append((f * abs(math.sin(ang)), f * math.cos(ang)))
    for f in _straddle(sim3.L_TAYLOR):
        for th in (0.0, 0.1, 0.3, 1.0, 2.5, 5.0):
            out += [(th, f), (th, -f)]
    for f in _straddle(sim3.LAM_SPECTRAL):
        for th in (0.0, 1e-8, 0.3, 0.99, 1.5):
            out += [(th, f), (th, -f)]
    for r in (1e-200, 1e-12, 1e-6, 1e-3):
        out += [(r, 3 * r), (3 * r, -r)]
    return out


def _threshold_pairs():
    lams = [(0.0, -0.5, 45.0), (1e-9, 5.0, -1.0), (-1e-5, 0.5, -45.0)]
    return [(th, lam) for k, th in enumerate(THRESHOLD_THETAS) for lam in lams[k % 3]]


PAIRS = _grid(THETAS) + _threshold_pairs() + _special()
PAIRS_2PI = PAIRS + _grid(THETAS_BEYOND_PI) + _grid(_straddle(PI), [0.0, -1e-9, 0.5])


def _points(pairs, seed=0):
    rng = np.random.default_rng(seed)
    pts = []
    for k, (th, lam) in enumerate(pairs):
        d = rng.standard_normal((2, 3))
        n = d[0] / np.linalg.norm(d[0])
        mode = MODES[k % 3]
        if mode == "random":
            u = d[1]
        elif mode == "parallel":
            u = n + 1e-7 * d[1]
        else:
            u = np.cross(n, d[1])
        u = NORMS[(k // 3) % 3] * u / np.linalg.norm(u)
        pts.append(np.r_[th * n, u, lam])
    return pts


def _mp(x):
    return ref.mpf_vec(x)


def _worst(pairs_errs):
    worst = max(pairs_errs, key=lambda p: p[0])
    return worst


# --- accuracy sweeps --------------------------------------------------------------------------


def _over(errs):
    """The points whose error exceeds their tolerance (1e-14, or 2e-15 where |λ| ≤ 5)."""
    return [(e, x) for e, x in errs if e > _tol(x)]


def test_exp_accuracy():
    errs = [(ref.rel_err(sim3.exp(x), ref.exp(G, _mp(x))), tuple(x)) for x in _points(PAIRS)]
    print("sim3.exp worst", _worst(errs))
    assert not _over(errs), _over(errs)


@pytest.mark.slow
def test_dexp_dlog_accuracy():
    errs = {"dexp": [], "dlog": []}
    for x in _points(PAIRS_2PI, seed=1):
        D = ref.dexp(G, _mp(x))  # once per point, for both
        errs["dexp"].append((ref.rel_err(sim3.dexp(x), D), tuple(x)))
        errs["dlog"].append((ref.rel_err(sim3.dlog(x), mp.inverse(D)), tuple(x)))
    print("sim3.dexp/dlog worst", {k: _worst(v) for k, v in errs.items()})
    assert not _over(errs["dexp"]), _over(errs["dexp"])
    assert not _over(errs["dlog"]), _over(errs["dlog"])


def _log_ref(X, x):
    """vee(log X) from the definition exp = expm(hat): ω = logm(R) (principal, θ < 3), λ = −ln X33,
    and u from t = T u, T's columns the translation of expm(hat(ω, e_j, λ)) (linear in u).
    Near π, Newton on expm(hat x) = X (mp.logm may pick a complex branch there)."""
    th = float(np.linalg.norm(x[:3]))
    if th >= 3.0:
        return ref.log_near(G, X, _mp(x))
    Xm = mp.matrix(np.asarray(X).tolist())
    w = ref.vee_so3(mp.logm(Xm[0:3, 0:3]))
    w = [mp.re(v) for v in w]
    lam = -mp.log(Xm[3, 3])
    T = mp.matrix(3, 3)
    for j in range(3):
        e = [0, 0, 0]
        e[j] = 1
        E = mp.expm(ref.hat_sim3(w + e + [lam]))
        for i in range(3):
            T[i, j] = E[i, 3]
    u = mp.lu_solve(T, mp.matrix([Xm[0, 3], Xm[1, 3], Xm[2, 3]]))
    return w + [u[0], u[1], u[2], lam]


def test_log_reference_agrees_with_logm():
    x = np.array([0.3, -0.9, 0.5, 1.0, -2.0, 0.4, 0.8])
    X = sim3.exp(x)
    assert ref.rel_err(np.array(ref.log(G, X), dtype=float), _log_ref(X, x)) < 1e-15


@pytest.mark.slow
def test_log_accuracy():
    # θ ≥ 3 needs the Newton reference (a 50-digit D_log per step): every third pair there
    pairs = [(th, lam) for k, (th, lam) in enumerate(PAIRS) if th < 3.0 or (th < PI and k % 3 == 0)]
    errs = []
    for x in _points(pairs, seed=2):
        X = sim3.exp(x)
        errs.append((ref.rel_err(sim3.log(X), _log_ref(X, x)), tuple(x)))
    print("sim3.log worst", _worst(errs))
    assert not _over(errs), _over(errs)


def test_log_precision_hole_closed():
    """Rotation and scale small together (θ ≈ λ ≈ 1e-8, |u| ≈ 1e-3), where the closed forms of W⁻¹
    would lose two digits."""
    rng = np.random.default_rng(12)
    for th, lam in ((1e-8, 1e-8), (1e-8, -1e-8), (3e-8, 1e-8), (1e-6, 2e-6), (1e-10, -1e-10)):
        for _ in range(3):
            n = rng.standard_normal(3)
            u = rng.standard_normal(3)
            x = np.r_[th * n / np.linalg.norm(n), 1e-3 * u / np.linalg.norm(u), lam]
            X = sim3.exp(x)
            assert ref.rel_err(sim3.log(X), _log_ref(X, x)) <= TOL_SMALL_LAMBDA


def test_extreme_scales():
    """|λ| up to 700 (s = e^±700): nothing overflows before e^λ itself (the W, W⁻¹ and φ2
    coefficients are formed from ratios ≤ 1 first)."""
    for lam in (-700.0, -300.0, 45.0, 300.0, 700.0):
        for th in (0.0, 1e-8, 0.3, 2.0):
            x = np.r_[th * np.array([0.6, 0.0, -0.8]), 1.0, -2.0, 0.5, lam]
            X = sim3.exp(x)
            assert ref.rel_err(X, ref.exp(G, _mp(x))) <= TOL_SMALL_LAMBDA
            assert np.max(np.abs(sim3.log(X) - x)) <= 1e-14 * max(1.0, abs(lam)), x
            assert np.isfinite(sim3.dexp(x)).all() and np.isfinite(sim3.dlog(x)).all(), x


def test_log_at_pi():
    for x in _points([(PI, lam) for lam in (0.0, 1e-9, -0.5, 5.0)], seed=3):
        X = sim3.exp(x)
        y = sim3.log(X)
        assert abs(np.linalg.norm(y[:3]) - PI) < 1e-15
        assert ref.rel_err(sim3.exp(y), mp.matrix(X.tolist())) <= TOL


def _Ad_ref(X):
    Xm = mp.matrix(np.asarray(X).tolist())
    Xi = mp.inverse(Xm)
    R = mp.matrix(7, 7)
    for j in range(7):
        e = [0] * 7
        e[j] = 1
        col = ref.vee_sim3(Xm * ref.hat_sim3(e) * Xi)
        for i in range(7):
            R[i, j] = col[i]
    return R


def test_Ad_definition():
    errs = []
    for x in _points(PAIRS, seed=4)[::2]:
        X = sim3.exp(x)
        errs.append((ref.rel_err(sim3.Ad(X), _Ad_ref(X)), tuple(x)))
    print("sim3.Ad worst", _worst(errs))
    assert not _over(errs), _over(errs)


def test_ad_accuracy():
    for x in _points(PAIRS_2PI[::3], seed=5):
        assert ref.rel_err(sim3.ad(x), ref.ad(G, _mp(x))) == 0.0


def test_dlog_spectral_and_product_forms_agree_at_switch():
    """Both forms of D_log's lower-left block are accurate on both sides of SPECTRAL."""
    for f in (1 - 1e-9, 1 + 1e-9):
        for x in _points([(sim3.SPECTRAL * f, lam) for lam in (0.0, 1e-5, -0.5, 5.0)], seed=10):
            assert ref.rel_err(sim3.dlog(x), ref.dlog(G, _mp(x))) <= TOL


# --- shapes and validation ---------------------------------------------------------------------


def test_tiny_positive_corner_is_accepted():
    X = np.eye(4)
    X[3, 3] = 1e-300  # s = 1e300 is a valid (huge) scale
    assert sim3.log(X)[6] == pytest.approx(-math.log(1e-300), rel=1e-15)


# --- GTSAM --------------------------------------------------------------------------------------

_MODERATE = [
    np.array(v)
    for v in (
        [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7],
        [1.3, -0.2, 0.5, -4.0, 2.0, 0.3, -1.0],
        [-0.05, 0.02, 0.01, 10.0, -3.0, 1.0, 3.0],
        [2.0, 1.0, -1.5, 0.3, 0.3, -0.2, 0.0],
        [0.0, 0.0, 0.0, 1.0, 2.0, 3.0, -0.4],
    )
]


@pytest.mark.parametrize("v", _MODERATE, ids=str)
def test_gtsam_similarity3_same_convention(v):
    """gtsam.Similarity3 uses our tangent [ω, u, λ], Hat and matrix [[R, t], [0, 1/s]] unchanged."""
    S = gtsam.Similarity3.Expmap(v)
    X = sim3.exp(v)
    assert np.max(np.abs(S.matrix() - X)) < 1e-12 * max(1.0, np.abs(X).max())
    assert abs(S.scale() - 1.0 / X[3, 3]) < 1e-12 * S.scale()  # GTSAM's scale() = e^λ
    assert np.max(np.abs(gtsam.Similarity3.Logmap(S) - sim3.log(S.matrix()))) < 1e-10 * max(1.0, np.abs(v).max())
    assert np.max(np.abs(np.asarray(gtsam.Similarity3.Hat(v)) - sim3.hat(v))) == 0.0
    assert np.max(np.abs(gtsam.Similarity3.Vee(sim3.hat(v)) - v)) == 0.0
    assert np.max(np.abs(S.AdjointMap() - sim3.Ad(S.matrix()))) < 1e-12 * max(1.0, np.abs(S.AdjointMap()).max())
    assert np.max(np.abs(S.adjointMap(v) - sim3.ad(v))) == 0.0
    Y = gtsam.Similarity3.Expmap(v[::-1].copy())
    assert np.max(np.abs(S.compose(Y).matrix() - sim3.compose(X, Y.matrix()))) < 1e-12 * 100
    assert np.max(np.abs(S.inverse().matrix() - sim3.inverse(X))) < 1e-12 * 100
    # retract(δ) = X·Expmap(δ): the right perturbation the factors differentiate against
    d = np.linspace(-0.3, 0.3, 7)
    assert np.max(np.abs(S.retract(d).matrix() - sim3.compose(X, sim3.exp(d)))) < 1e-12 * 100


def test_gtsam_similarity3_accuracy_recorded():
    """Ours ≤ 1e-14 where GTSAM's Expmap is less accurate (small λ); GTSAM's error is printed.

    Erratum (docs/errata.md): GTSAM's Similarity3.Expmap is said to equal expm(Hat) to 2e-16; at λ = 3e-5 it
    is off by 5e-12 … 8e-12 (relative, |u| ≈ 1.6), at λ = 1e-5 by 5e-13 … 9e-13."""
    errs = {}
    for th, lam in ((0.3, 3e-5), (0.3, 1e-5), (1e-4, 1e-4), (1e-6, -1e-6), (0.0, 1e-7), (2.0, 1e-9)):
        v = np.r_[th * np.array([0.6, 0.0, 0.8]), 0.3, -0.2, 1.5, lam]
        r = ref.exp(G, _mp(v))
        assert ref.rel_err(sim3.exp(v), r) <= TOL
        errs[(th, lam)] = ref.rel_err(gtsam.Similarity3.Expmap(v).matrix(), r)
    print("GTSAM Similarity3.Expmap errors:", errs)
    assert errs[(0.3, 3e-5)] > 1e-12 and errs[(0.3, 1e-5)] > 1e-13


# --- the derivation map (docs/sim3.md), checked -----------------------


def test_note_coefficient_limits_at_zero():
    """a1 = 1, b1 = 1/2, c1 = 1/6, d1 = −1/12, e1 = −1/60, φ2 → 1/2 at θ = λ = 0."""
    a1, b1, c1, d1, e1, r1, a2, b2, c2 = sim3._coefs(0.0, 0.0)
    for got, want in ((a1, 1), (b1, 1 / 2), (c1, 1 / 6), (d1, -1 / 12), (e1, -1 / 60), (a2, 1 / 2), (r1, 1)):
        # a quadrature sum: the project's measure, |error|/max(1, |ref|), at ≤ 2 ulps of 1
        assert abs(got - want) <= 2 * np.finfo(float).eps


def test_note_W_inverse_and_psi_column():
    """W⁻¹ = (1/a1) I + b3 Ω + c3 Ω² (note's b3, c3) and D_log's λ column ψ(Ω + λI) u."""
    x = np.array([0.7, -0.4, 1.1, 2.0, -1.0, 0.5, -0.8])
    w, u, lam = x[:3], x[3:6], x[6]
    th = np.linalg.norm(w)
    a1, b1, c1, *_ = sim3._coefs(lam, th)
    m = (a1 - c1 * th**2) ** 2 + b1**2 * th**2
    b3, c3 = -b1 / m, (b1**2 - a1 * c1 + c1**2 * th**2) / (a1 * m)
    Om = sim3.hat(np.r_[w, 0, 0, 0, 0])[:3, :3]
    Wi = np.eye(3) / a1 + b3 * Om + c3 * Om @ Om
    D = ref.dlog(G, _mp(x))
    assert ref.rel_err(Wi, D[3:6, 3:6]) < 1e-14
    B = mp.matrix((Om + lam * np.eye(3)).tolist())
    psi = mp.inverse(B) - mp.inverse(mp.expm(B) - mp.eye(3))
    assert ref.rel_err(sim3.dlog(x)[3:6, 6], psi * mp.matrix(u.tolist())) < 1e-14


# --- the scalar coefficients on a dense (λ, θ) grid -----------------------------------------------


def _coef_refs(lam, th):
    """The coefficients from their definitions through (F), in mpmath with enough digits for the
    cancellation of each definition: b1 = Im φ1(z)/θ, c1 = (φ1(λ) − Re φ1(z))/θ²,
    d1 = (Re φ1′(z) − b1)/θ², e1 = (Im φ1′(z)/θ − 2 c1)/θ², b2, c2 likewise for φ2."""
    small = min([abs(v) for v in (lam, th) if v != 0.0] + [1.0])
    th_m = mp.mpf(th) if th != 0.0 else mp.mpf(10) ** -40  # θ = 0: the limit, to 1e-80
    with mp.workdps(int(90 + 4.5 * max(0.0, -math.log10(small)))):
        lam_m = mp.mpf(lam)
        z = mp.mpc(lam_m, th_m)
        A = mp.expm1(lam_m) / lam_m if lam != 0.0 else mp.mpf(1)
        a2 = (A - 1) / lam_m if lam != 0.0 else mp.mpf(1) / 2
        p1 = (mp.exp(z) - 1) / z
        dp1 = (mp.exp(z) - p1) / z
        p2 = (p1 - 1) / z
        b1 = mp.im(p1) / th_m
        c1 = (A - mp.re(p1)) / th_m**2
        d1 = (mp.re(dp1) - b1) / th_m**2
        e1 = (mp.im(dp1) / th_m - 2 * c1) / th_m**2
        b2 = mp.im(p2) / th_m
        c2 = (a2 - mp.re(p2)) / th_m**2
        return [A, b1, c1, d1, e1, mp.re(p1), a2, b2, c2], (abs(p1), abs(dp1), abs(p2))


def test_W_coefficients_exp_log_band():
    """exp and log take a1, b1, c1 from _wcoefs, whose z band is Z_BAND_W (not Z_BAND): the same
    weighted measure as below across both bands, |z| = Z_BAND_W straddled in several directions."""
    worst = 0.0
    pts = [(f * math.cos(a), f * abs(math.sin(a))) for f in _straddle(sim3.Z_BAND_W) + _straddle(sim3.Z_BAND)
           for a in (0.0, 0.4, 0.5 * PI, 2.0, PI)]
    pts += [(lam, th) for th in (0.0, 1e-200, 1e-8, 5e-4, 2e-3, 0.1, 1.0, 3.0)
            for lam in (0.0, 1e-200, 1e-8, -5e-4, 2e-3, -0.3, 0.51, 5.0, -45.0)]
    for lam, th in pts:
        r, (m1, _, _) = _coef_refs(lam, th)
        _, a1, b1, c1, a, b = sim3._wcoefs(lam, th)
        s1 = max(r[0], m1)
        e = max(abs(mp.mpf(a1) - r[0]) / s1, abs(mp.mpf(b1) - r[1]) * th / s1, abs(mp.mpf(c1) - r[2]) * th * th / s1)
        worst = max(worst, float(e))
    print("W coefficients (exp/log) worst", worst)
    assert worst <= TOL_SMALL_LAMBDA


def test_coefficients_2d_sweep():
    """Each coefficient of _coefs times the power of θ it meets in the matrices (b1 Ω, c1 Ω², c1 θ in
    Q, d1 θ², e1 θ³, b2 Ω, c2 Ω²), relative to the size of its function (|φ1|, |φ1′|, |φ2|), on a
    30 × 49 grid through every band; ≤ 2e-15 for |λ| ≤ 5, ≤ 1e-14 up to |λ| = 45."""
    ths = [0.0, 1e-200, 1e-30, 1e-15, 1e-8, 1e-5, 1e-3, 0.01, sim3.Z_BAND_W * (1 - 1e-9), sim3.Z_BAND_W * (1 + 1e-9), 0.05, 0.1, 0.2, 0.24, 0.26, 0.3, 0.4, 0.5,
           0.7, 0.8, 1.0, 1.5, 2.0, 2.5, 3.0, PI, 3.5, 4.0, 5.0, 6.0, 2 * PI - 1e-3, sim3.Z_BAND * (1 + 1e-9)]
    lams = [0.0] + [s * v for v in (1e-200, 1e-30, 1e-15, 1e-8, 1e-5, 1e-3, 0.01, 0.05, 0.1, 0.2, 0.25, 0.3,
                                       0.49, 0.51, 0.7, 1.0, 1.5, 2.0, 3.0, 4.99, 5.01, 7.0, 10.0, 45.0)
                    for s in (1.0, -1.0)]
    worst = {}
    for th in ths:
        for lam in lams:
            r, (m1, md, m2) = _coef_refs(lam, th)
            got = [mp.mpf(v) for v in sim3._coefs(lam, th)]
            d = [abs(g - v) for g, v in zip(got, r)]
            s1, sd, s2 = max(r[0], m1), max(r[1], md), max(r[6], m2)
            w = th if th != 0.0 else 0.0
            errs = [d[0] / s1, d[1] * w / s1, d[2] * w * w / s1, d[2] * w / sd, d[3] * w * w / sd,
                    d[4] * w**3 / sd, d[5] / s1, d[6] / s2, d[7] * w / s2, d[8] * w * w / s2]
            e = float(max(errs))
            key = abs(lam) <= 5.0
            if e > worst.get(key, (0.0,))[0]:
                worst[key] = (e, lam, th)
    print("coefficient sweep worst (|λ| ≤ 5, |λ| > 5):", worst.get(True), worst.get(False))
    assert worst[True][0] <= TOL_SMALL_LAMBDA, worst
    assert worst[False][0] <= TOL, worst
