"""Sim(2) closed forms against 50-digit references built from the definitions.

error = max|ours - ref| / max(1, max|ref|) ≤ 1e-14 everywhere (docs/conventions.md).
"""

from __future__ import annotations

import math

import gtsam
import mpmath as mp
import numpy as np
import pytest

from lie_factors.testing import reference as ref
from lie_factors import sim2

TOL = 1e-14
G = "sim2"
NORMS = (1e-3, 1.0, 1e2)

_THETAS = [0.0, 1e-200, 1e-15, 1e-8, 1e-4, 0.3, 1.0, 2.0, 3.0, math.pi - 1e-12, math.pi]
_LAMBDAS = [0.0, 1e-200, 1e-15, 1e-8, 1e-3, 0.3, 1.0, 2.5, 5.0]
_RADII = [1e-200, 1e-15, 1e-10, 1e-5, 1e-3, 0.1, 0.5, 2.0, 3.0]
# the Taylor/closed-form switch on |λ + iθ|, straddled in 8 directions
_STRADDLE_R = [sim2.PHI_TAYLOR * f for f in (1 - 1e-9, 1 + 1e-9, 1 - 1e-6, 1 + 1e-6, 0.5, 2.0)]


def _pairs():
    """(θ, λ) covering: grid incl. λ = 0 with θ ≠ 0 and θ = 0 with λ ≠ 0, both signs;
    λ = ±θ down to 1e-200; the |z| threshold straddled along 8 directions."""
    rng = np.random.default_rng(7)
    out = []
    for th in _THETAS:
        for lam in _LAMBDAS:
            out.append((th * rng.choice([-1.0, 1.0]), lam * rng.choice([-1.0, 1.0])))
    for m in _RADII:
        for st_, sl in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            out.append((st_ * m, sl * m))
    for r in _STRADDLE_R:
        for ang in np.arange(8) * (math.pi / 4) + 0.1:
            out.append((r * math.sin(ang), r * math.cos(ang)))
    return out


PAIRS = _pairs()
PAIRS_BEYOND_PI = [(s * th, lam) for th in (3.5, 4.5, 6.0, 6.2) for lam in (0.0, 0.5, -2.0, 5.0) for s in (1.0, -1.0)]


def _points(pairs):
    rng = np.random.default_rng(99)
    pts = []
    for i, (th, lam) in enumerate(pairs):
        u = rng.normal(size=2)
        u *= NORMS[i % 3] / np.linalg.norm(u)
        pts.append(np.array([u[0], u[1], th, lam]))
    return pts


def _mp(x):
    return ref.mpf_vec(x)


def _newton_log(X):
    """vee(log X) at 50 digits by Newton on exp(hat x) = X (:func:`reference.log_near`): mp.logm
    fails near θ = π."""
    return ref.log_near(G, X, [X[0, 2], X[1, 2], math.atan2(X[1, 0], X[0, 0]), -math.log(X[2, 2])])


def _log_ref(X):
    th = abs(math.atan2(X[1, 0], X[0, 0]))
    return ref.log(G, X) if th < 3.0 else _newton_log(X)


# --- accuracy sweeps ---------------------------------------------------------------------------


def _check(fn, reffn, pts):
    worst, at = 0.0, None
    for x in pts:
        e = ref.rel_err(fn(x), reffn(_mp(x)))
        if e > worst:
            worst, at = e, x
    assert worst <= TOL, (worst, at)


def test_exp_accuracy():
    _check(sim2.exp, lambda m: ref.exp(G, m), _points(PAIRS))


def test_ad_accuracy():
    _check(sim2.ad, lambda m: ref.ad(G, m), _points(PAIRS + PAIRS_BEYOND_PI))


def test_dexp_dlog_accuracy():
    worst = {"dexp": (0.0, None), "dlog": (0.0, None)}
    for x in _points(PAIRS + PAIRS_BEYOND_PI):
        D = ref.dexp(G, _mp(x))
        for name, ours, r in (("dexp", sim2.dexp(x), D), ("dlog", sim2.dlog(x), mp.inverse(D))):
            e = ref.rel_err(ours, r)
            if e > worst[name][0]:
                worst[name] = (e, x)
    assert worst["dexp"][0] <= TOL, worst
    assert worst["dlog"][0] <= TOL, worst


@pytest.mark.slow
def test_log_accuracy():
    worst, at = 0.0, None
    for x in _points([(th, lam) for th, lam in PAIRS if abs(th) < math.pi]):
        X = sim2.exp(x)
        e = ref.rel_err(sim2.log(X), _log_ref(X))
        if e > worst:
            worst, at = e, x
    assert worst <= TOL, (worst, at)


def test_newton_log_reference_agrees_with_logm():
    X = sim2.exp(np.array([0.4, -1.3, 2.5, -0.7]))
    assert ref.rel_err(np.array(ref.log(G, X), dtype=float), _newton_log(X)) < 1e-15


def test_Ad_definition():
    for x in _points(PAIRS)[::4]:
        X = sim2.exp(x)
        Xm = mp.matrix(X.tolist())
        Xi = mp.inverse(Xm)
        R = mp.matrix(4, 4)
        for j in range(4):
            e = [0, 0, 0, 0]
            e[j] = 1
            col = ref.vee_sim2(Xm * ref.hat_sim2(e) * Xi)
            for i in range(4):
                R[i, j] = col[i]
        assert ref.rel_err(sim2.Ad(X), R) <= TOL, x


# --- round trips -------------------------------------------------------------------------------


# --- shapes and validation -----------------------------------------------------------------------


# --- GTSAM --------------------------------------------------------------------------------------

_MODERATE = [
    np.array(v)
    for v in ([0.3, -0.2, 0.5, 0.7], [1.3, 0.2, -2.5, -1.0], [-4.0, 2.0, 0.05, 3.0], [10.0, -3.0, 3.0, 0.0], [0.1, 0.2, 0.0, -0.4])
]


@pytest.mark.parametrize("v", _MODERATE, ids=str)
def test_gtsam_similarity2_same_convention(v):
    """gtsam.Similarity2 uses our tangent [x, y, θ, λ] and corner e^{-λ} unchanged."""
    S = gtsam.Similarity2.Expmap(v)
    X = sim2.exp(v)
    assert np.max(np.abs(S.matrix() - X)) < 1e-12
    assert abs(S.scale() - 1.0 / X[2, 2]) < 1e-12 * S.scale()  # GTSAM's scale() = e^{λ}
    assert np.max(np.abs(gtsam.Similarity2.Logmap(S) - sim2.log(S.matrix()))) < 1e-12
    assert np.max(np.abs(np.asarray(gtsam.Similarity2.Hat(v)) - sim2.hat(v))) == 0.0
    assert np.max(np.abs(S.AdjointMap() - sim2.Ad(S.matrix()))) < 1e-12


def test_gtsam_similarity2_small_angle_accuracy_recorded():
    """Ours ≤ 1e-14 at small θ; GTSAM's Expmap error there is recorded (≈1e-13 in 4.3)."""
    errs = {}
    for th, lam in ((1e-4, 0.0), (1e-4, 1e-4), (1e-6, -1e-6), (0.0, 0.3)):
        v = np.array([0.3, -0.2, th, lam])
        r = ref.exp(G, _mp(v))
        assert ref.rel_err(sim2.exp(v), r) <= TOL
        errs[(th, lam)] = ref.rel_err(gtsam.Similarity2.Expmap(v).matrix(), r)
    print("GTSAM Similarity2.Expmap errors:", errs)


# --- errata (docs/errata.md) -------------------------------------------------------------------


def _Q_P(x):
    lam, th, X0, Y0 = x[3], x[2], x[0], x[1]
    return np.array([[lam, -th], [th, lam]]), np.array([[Y0, -X0], [-X0, -Y0]])


def test_checked_correct_eq88_eq91_to_93():
    """Eq. (88) ad_m and the eigendecomposition (91)-(93) hold as written."""
    x = np.array([0.7, -0.4, 1.1, -0.3])
    assert ref.rel_err(sim2.ad(x), ref.ad(G, _mp(x))) == 0.0
    Q, _ = _Q_P(x)
    V = np.array([[1, 1], [1j, -1j]]) / math.sqrt(2)
    E = np.diag([x[3] - 1j * x[2], x[3] + 1j * x[2]])
    assert np.max(np.abs(V @ E @ V.conj().T - Q)) < 1e-15


def test_erratum_eq90_n0_and_eq96_bottom_right():
    """Eq. (90) ad^n = [[Q^n, Q^{n-1}P], [0, 0]] holds only for n ≥ 1 (n = 0 gives Q⁻¹P and a
    zero corner instead of I), so Eqs. (95)-(98) carry a 0 bottom-right block; right is I
    (as Eq. (100) has)."""
    x = np.array([0.7, -0.4, 1.1, -0.3])
    Q, P = _Q_P(x)
    A = ref.to_numpy(ref.ad(G, _mp(x)))
    for n in (1, 2, 3, 5):
        An = np.linalg.matrix_power(A, n)
        lit = np.block([[np.linalg.matrix_power(Q, n), np.linalg.matrix_power(Q, n - 1) @ P], [np.zeros((2, 4))]])
        assert np.max(np.abs(An - lit)) < 1e-12
    lit0 = np.block([[np.eye(2), np.linalg.inv(Q) @ P], [np.zeros((2, 4))]])
    assert np.max(np.abs(lit0 - np.eye(4))) > 0.5
    D = ref.dexp(G, _mp(x))
    eq96 = sim2.dexp(x).copy()
    eq96[2:, 2:] = 0.0
    assert ref.rel_err(eq96, D) >= 1.0 / max(1.0, float(mp.norm(D, mp.inf)))
    assert ref.rel_err(sim2.dexp(x), D) <= TOL


def _pq_eade(lam, th):
    n2 = lam * lam + th * th
    p = (math.exp(lam) * (lam * math.cos(th) + th * math.sin(th)) - lam) / n2  # Eq. (101)
    q = (math.exp(lam) * (lam * math.sin(th) - th * math.cos(th)) + th) / n2  # Eq. (102)
    return p, q


def test_checked_correct_eq101_eq102():
    for x in (np.array([0.7, -0.4, 1.1, -0.3]), np.array([2.0, 1.0, -2.5, 1.5])):
        p, q = _pq_eade(x[3], x[2])
        D = sim2.dexp(x).copy()
        D[0, 0], D[0, 1], D[1, 0], D[1, 1] = p, -q, q, p
        assert ref.rel_err(D, ref.dexp(G, _mp(x))) < 1e-14


def test_erratum_eq103_eq104():
    """With p, q as defined in Eqs. (101)-(102), the literal (103)-(104) have an extra
    factor 1/(λ² + θ²); right: g = [λ(p-1) + θq]/(λ²+θ²), h = [λq - θ(p-1)]/(λ²+θ²)."""
    for x in (np.array([0.7, -0.4, 1.1, -0.3]), np.array([2.0, 1.0, -2.5, 1.5]), np.array([-1.0, 3.0, 0.4, 2.0])):
        lam, th = x[3], x[2]
        n2 = lam * lam + th * th
        p, q = _pq_eade(lam, th)
        Q, P = _Q_P(x)
        r = ref.dexp(G, _mp(x))

        def with_gh(g, h):
            D = sim2.dexp(x).copy()
            D[:2, 2:] = np.array([[g, -h], [h, g]]) @ P
            return D

        g_lit = ((lam * p + th * q) / n2 - lam) / n2
        h_lit = ((lam * q - th * p) / n2 + th) / n2
        assert ref.rel_err(with_gh(g_lit, h_lit), r) > 1e-3
        g_fix = (lam * (p - 1) + th * q) / n2
        h_fix = (lam * q - th * (p - 1)) / n2
        assert ref.rel_err(with_gh(g_fix, h_fix), r) < 1e-13
        assert ref.rel_err(sim2.dexp(x), r) <= TOL


def test_erratum_eq105_to_108_small_z():
    """Eqs. (105)-(108) write the small-|z| forms with a, b; the only a, b in the note are
    a_θ = sinθ/θ, b_θ = (1-cosθ)/θ² (Eqs. 50-51), which give p ≈ 3/2. Right: a → λ, b → θ
    (p = 1 + λ/2, q = θ/2, g = 1/2 + λ/6, h = θ/6), and even then only first order:
    error ~|z|²/6, so at |z| = 1e-3 it is ~1e-7, far above 1e-14 (we sum 20 series terms)."""
    for th, lam in ((1e-3, 0.0), (7e-4, 7e-4), (0.0, -1e-3), (1e-3, -1e-3)):
        x = np.array([0.5, -0.8, th, lam])
        r = ref.dexp(G, _mp(x))
        _, P = _Q_P(x)

        def from_pqgh(p, q, g, h):
            D = np.eye(4)
            D[:2, :2] = [[p, -q], [q, p]]
            D[:2, 2:] = np.array([[g, -h], [h, g]]) @ P
            return D

        a = math.sin(th) / th if th else 1.0
        b = (1 - math.cos(th)) / th**2 if th else 0.5
        assert ref.rel_err(from_pqgh(1 + a / 2, b / 2, 0.5 + a / 6, b / 6), r) > 0.1
        e_first = ref.rel_err(from_pqgh(1 + lam / 2, th / 2, 0.5 + lam / 6, th / 6), r)
        assert 1e-9 < e_first < 1e-6
        assert ref.rel_err(sim2.dexp(x), r) <= TOL


def test_checked_correct_eq110_block_inverse():
    x = np.array([0.7, -0.4, 1.1, -0.3])
    D = sim2.dexp(x)
    A, B = D[:2, :2], D[:2, 2:]
    Ai = np.linalg.inv(A)
    lit = np.block([[Ai, -Ai @ B], [np.zeros((2, 2)), np.eye(2)]])
    assert ref.rel_err(lit, ref.dlog(G, _mp(x))) < 1e-14
