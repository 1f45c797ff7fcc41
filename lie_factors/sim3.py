"""Sim(3), GTSAM's Similarity3: tangent x = [ω, u, λ], elements 4×4 [[R, t], [0, 1/s]], s = e^λ.

Shapes: ``hat``, ``exp`` (..., 7) → (..., 4, 4); ``vee``, ``log`` (..., 4, 4) → (..., 7);
``ad``, ``dexp``, ``dlog`` (..., 7) → (..., 7, 7); ``Ad`` (..., 4, 4) → (..., 7, 7);
``inverse`` (..., 4, 4) → (..., 4, 4); ``compose`` (..., 4, 4) × (..., 4, 4) → (..., 4, 4).
:mod:`lie_factors.kernels.public` builds these functions (validation, broadcasting, the
single-element fast path) around the cores below, which the factors call directly.
Tangent ordering and matrices are exactly GTSAM 4.3's (checked in tests/kernels/test_sim3.py)::

    x = [ω (3), u (3), λ]                                   shape (..., 7)
    hat(x) = [[ω×, u], [0, −λ]]                              shape (..., 4, 4)
    element X = [[R, t], [0, 1/s]],  s = e^λ > 0             shape (..., 4, 4)

``gtsam.Similarity3.Expmap(x).matrix() == sim3.exp(x)`` (= expm(hat x)),
``Similarity3.Logmap(S) == sim3.log(S.matrix())``, ``Similarity3.Hat == hat``,
``S.AdjointMap() == Ad(S.matrix())``; GTSAM's ``scale()`` is s = 1/X[3, 3].
The action on points is p ↦ s(R p + t); compose is the matrix product.

Notation: Ω = ω×, U = u×, θ = |ω|, B = Ω + λI, z = λ + iθ, and the scalar
functions φ1(z) = (e^z − 1)/z = ∫₀¹ e^{sz} ds, φ2(z) = (e^z − 1 − z)/z² =
∫₀¹ (1 − s) e^{sz} ds, g(z) = 1/φ1(z) = z/(e^z − 1), ψ(z) = 1/z − 1/(e^z − 1).

Every matrix function of B reduces to three scalars because Ω has eigenvalues
0, ±iθ (Cayley–Hamilton, Ω³ = −θ²Ω), so B has λ, λ ± iθ::

    f(B) = f(λ) I + (Im f(z)/θ) Ω + ((f(λ) − Re f(z))/θ²) Ω²          (F)

The closed forms (derived in docs/sim3.md, verified against 50-digit references):

    exp(x) = [[R, e^{−λ} W u], [0, e^{−λ}]],   R = exp(Ω) (Rodrigues),
             W = φ1(B) = a1 I + b1 Ω + c1 Ω²            (hat is block triangular)
    log(X) = [ω = Log R, u = W⁻¹ (t/X33), λ = −ln X33],  W⁻¹ = g(B)
    ad_x   = [[Ω, 0, 0], [U, B, −u], [0, 0, 0]]
    Ad_X   = [[R, 0, 0], [s t× R, s R, −s t], [0, 0, 1]]
    D_exp  = φ1(ad_x) = [[J, 0, 0], [Q, W, −φ2(B) u], [0, 0, 1]],   J = SO(3)'s D_exp
             Q = ∂(W u)/∂ω + (W u)× J
               = −b1 U + c1 (ω uᵀ + (ω·u) I − 2 u ωᵀ) + d1 (Ω u) ωᵀ + e1 (Ω² u) ωᵀ + (W u)× J
    D_log  = g(ad_x) = [[J⁻¹, 0, 0], [L, W⁻¹, ψ(B) u], [0, 0, 1]],   L = −W⁻¹ Q J⁻¹

with a1 = φ1(λ), b1 = Im φ1(z)/θ, c1 = (a1 − Re φ1(z))/θ², d1 = (∂b1/∂θ)/θ,
e1 = (∂c1/∂θ)/θ. The lower-left block of f(ad_x) for ANY analytic f is, by the
spectral projectors of Ω (docs/sim3.md),

    L_f = G U + k1 (ω·u) Ω + k2 (ω·u) Ω² + k3 (ω·u) I + k4 u ωᵀ + k5 ω uᵀ + k6 (Ω u) ωᵀ    (L)
    A + iB = f[z, iθ],  C + iD = f[z, 0],  G + iH = f[λ, iθ]   (divided differences)
    k1 = (A − G)/θ², k2 = (B − D − H)/θ³, k3 = −(D + H)/θ, k4 = D/θ, k5 = H/θ, k6 = (G − C)/θ²

and for f = g = 1/φ1 the divided differences need no subtraction:
g[a, b] = −g(a) g(b) φ1[a, b].

Evaluation (docs/sim3.md §6; Eade, "Derivative of the Exponential Map", Eqs. 91–100 do
the same for Sim(2): functions of the eigenvalues λ ± iθ over λ² + θ², Eq. 99). With E = e^λ, A = φ1(λ), I1 = φ1′(λ),
a2 = φ2(λ), the SO(3) functions a, b, c, qa = b′/θ, qb = c′/θ of θ (Eade, Eqs. 50–52,
64) and D = λ² + θ², the θ → 0 limits are taken analytically::

    b1 = (λ² I1 + θ² E (b − λc))/D           c1 = (λ (E b − I1) + θ² E c)/D          (C)
    d1 = (E [2(b − λc) + θ² (qa − λ qb)] − 2 b1)/D
    e1 = (E (λ qa + 2c + θ² qb) − 2 c1)/D
    b2 = (Q (λ² − θ²) − 2λθ² (a2 − E b))/D²   c2 = ((E b − a2)(λ² − θ²) − 2λ Q)/D²
    Q = λ (I1 − a2) − E θ² c

so only |z| → 0 is left: for |z| < ``Z_BAND`` all coefficients are the power series of
φ1, φ2 in z in real arithmetic (:func:`_zseries`; exp and log, which need only W's
coefficients, only below ``Z_BAND_W``); for |λ| < ``L_TAYLOR`` I1 is its
Taylor series and a2 = A − I1. For θ ≥ ``SPECTRAL`` (dexp, dlog) the complex closed
forms φ1(z) = (e^z − 1)/z, φ2(z) = (φ1(z) − 1)/z, g = 1/φ1 are used directly and the
lower-left blocks come from (L), with φ1[z, iθ] = (e^{iθ} φ1(λ) − φ1(iθ))/z; (L) is also
used for |λ| ≥ ``LAM_SPECTRAL``, where Q's terms cancel ~|λ|-fold. Below, D_log's block
is −W⁻¹ Q J⁻¹ (J⁻¹ and W⁻¹ well conditioned there), collapsed to rank-one terms
(:func:`_L_product`).

``dexp`` is the LEFT Jacobian Σ ad^i/(i+1)! (Eade, Eq. 35):
exp(x + ε) ≈ exp(dexp(x) ε)·exp(x); a GTSAM-style right Jacobian is dexp(−x).
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

from lie_factors import so3 as _so3
from lie_factors.kernels import public as _public, registry as _registry
from lie_factors.kernels.coeffs import (A_SERIES, C_SERIES, E_SERIES, QA_SERIES, QB_SERIES, A_TAYLOR, C_TAYLOR, E_TAYLOR, QA_TAYLOR, QB_TAYLOR, horner, horner4, a_theta, b_theta, c_theta, dot3, norm3, rounded, theta_dd)
from lie_factors.kernels.jit import helper_kernel, kernel
from lie_factors import se3 as _se3
from lie_factors.se3 import lin9, rod9

_info = _registry.SIM3
DIM, MAT = _info.dim, _info.mat

#: |z|² = λ² + θ² < Z_BAND²: every coefficient from the power series of φ1, φ2 in z
#: (real recurrences in λ and θ², see :func:`_zseries`); the closed forms in z divide by
#: |z|² = λ² + θ² and cancel there.
Z_BAND = 0.25
#: terms of the z series: the first omitted one is ≤ n² Z_BAND^n/(n+1)! < 1e-18 relative.
Z_TERMS = 14
#: exp and log need only W = φ1(B), whose (C) forms lose ~ε/|z| on c1 near z → 0 but only ~ε|z|
#: on c1 Ω² (what W and W⁻¹ contain): their z series is needed only where λ² + θ² would
#: underflow or vanish, |z| < Z_BAND_W, with Z_TERMS_W terms (first omitted < 1e-20).
Z_BAND_W = 1e-3
Z_TERMS_W = 6
#: |λ| < L_TAYLOR: φ1′(λ) and φ2(λ) from their Taylor series ((e^λ − φ1(λ))/λ and
#: (φ1(λ) − 1)/λ lose ~ε/|λ|).
L_TAYLOR = 0.5
L_TERMS = 16
#: D_exp and D_log: coefficient closed forms (C) and the product forms below this θ, complex
#: closed forms in z and the spectral form (L) of the lower-left block from it on.
SPECTRAL = 1.0
#: θ < SPECTRAL: the lower-left blocks of D_exp and D_log from (L) too when |λ| ≥ LAM_SPECTRAL,
#: where Q's terms cancel to ~1/|λ| of their size (a1 − b1 ~ e^λ/λ²): switching at 2 rather
#: than near 5 keeps that loss well inside the bound the tests hold |λ| ≤ 5 to (docs/conventions.md).
LAM_SPECTRAL = 2.0
# D_log's θ < SPECTRAL branch takes e_θ from its Taylor band without testing θ against E_TAYLOR
assert SPECTRAL <= E_TAYLOR

_TWO_PI_HI = 6.283185307179586
_TWO_PI_LO = 2.4492935982947064e-16

# φ1′(λ) = Σ λ^k/(k!(k+2)) and 1/(n+1)!, n = 0, 1, ...: exact rationals rounded once
_DPHI1_SERIES = rounded(Fraction(1, math.factorial(k) * (k + 2)) for k in range(L_TERMS))
_INV_FACT = rounded(Fraction(1, math.factorial(n + 1)) for n in range(Z_TERMS + 1))
# the same as a frozen array: indexing a global tuple with the loop counter costs a branch
# table per load inside the series loops
_INV_FACT_ARR = np.array(_INV_FACT)


# ---------------------------------------------------------------- scalar coefficients


@helper_kernel
def _theta_abc(th):
    """(a, b, c) of the SO(3) coefficient functions at θ ≥ 0 (Eade, Eqs. 50–52) from one sine
    and cosine of θ/2: a = sin θ/θ, b = ½ (sin(θ/2)/(θ/2))² (no cancellation), c = (1 − a)/θ²;
    Taylor bands of :mod:`lie_factors.kernels.coeffs`."""
    h = 0.5 * th
    t = th * th
    if th < A_TAYLOR:
        a = horner(A_SERIES, t)
        ah = horner(A_SERIES, h * h)
    else:
        sh = math.sin(h)
        ch = math.cos(h)
        a = sh * ch / h
        ah = sh / h
    b = 0.5 * ah * ah
    if th < C_TAYLOR:
        c = horner(C_SERIES, t)
    else:
        c = (1.0 - a) / t
    return a, b, c


@helper_kernel
def _theta5(th):
    """(a, b, c, qa, qb): :func:`_theta_abc` and qa = (a − 2b)/θ² = b′(θ)/θ, qb = (b − 3c)/θ² =
    c′(θ)/θ (Eade, Eq. 64)."""
    a, b, c = _theta_abc(th)
    t = th * th
    if th < QA_TAYLOR:
        qa = horner(QA_SERIES, t)
    else:
        qa = (a - 2.0 * b) / t
    if th < QB_TAYLOR:
        qb = horner(QB_SERIES, t)
    else:
        qb = (b - 3.0 * c) / t
    return a, b, c, qa, qb


@helper_kernel
def _lam3(lam):
    """(e^λ, φ1(λ), φ1′(λ)) with φ1′(λ) = (e^λ − φ1(λ))/λ = ∫₀¹ s e^{sλ} ds (Taylor series for
    |λ| < L_TAYLOR, where that difference loses ~ε/|λ|)."""
    if abs(lam) < L_TAYLOR:
        # one transcendental: e^λ = 1 + expm1(λ) keeps its relative accuracy for |λ| < 1/2
        em = math.expm1(lam)
        A = em / lam if lam != 0.0 else 1.0
        return 1.0 + em, A, horner4(_DPHI1_SERIES, lam)
    E = math.exp(lam)
    A = (E - 1.0) / lam  # |λ| ≥ L_TAYLOR: e^λ − 1 loses < 2 ulps
    return E, A, (E - A) / lam


@helper_kernel
def _zseries(lam, T, terms):
    """(a1, b1, c1, d1, e1, a2, b2, c2) for small |z| (module docstring, "z band"), ``terms`` terms.

    With zⁿ = pₙ + iθ qₙ, rₙ = (λⁿ − pₙ)/θ², sₙ = (n pₙ₋₁ − qₙ)/θ², tₙ = (n qₙ₋₁ − 2 rₙ)/θ²
    (all polynomials in λ and T = θ², no division):
        φ1(λ) = Σ λⁿ/(n+1)!,  b1 = Σ qₙ/(n+1)!,  c1 = Σ rₙ/(n+1)!,
        d1 = Σ sₙ/(n+1)!,     e1 = Σ tₙ/(n+1)!,  and a2, b2, c2 the same with 1/(n+2)!,
    from p₊ = λp − Tq, q₊ = p + λq, r₊ = λr + q, s₊ = λs − n qₙ₋₁, t₊ = λt + s.
    """
    p = 1.0
    q = 0.0
    r = 0.0
    s = 0.0
    t = 0.0
    qm = 0.0
    lp = 1.0
    a1 = b1 = c1 = d1 = e1 = a2 = b2 = c2 = 0.0
    fn = 0.0  # n as a float, counted alongside (no int → float conversion per term)
    for n in range(terms):
        f1 = _INV_FACT_ARR[n]
        f2 = _INV_FACT_ARR[n + 1]
        a1 += lp * f1
        b1 += q * f1
        c1 += r * f1
        d1 += s * f1
        e1 += t * f1
        a2 += lp * f2
        b2 += q * f2
        c2 += r * f2
        pn = lam * p - T * q
        qn = p + lam * q
        tn = lam * t + s
        s = lam * s - fn * qm
        r = lam * r + q
        qm = q
        p = pn
        q = qn
        t = tn
        lp *= lam
        fn += 1.0
    return a1, b1, c1, d1, e1, a2, b2, c2


@kernel
def _coefs(lam, th):
    """(a1, b1, c1, d1, e1, re1, a2, b2, c2): φ1(B) = a1 I + b1 Ω + c1 Ω², d1 = ∂b1/∂θ/θ,
    e1 = ∂c1/∂θ/θ, re1 = Re φ1(λ + iθ), φ2(B) = a2 I + b2 Ω + c2 Ω² (closed forms (C) of the
    module docstring; z series for |z| < Z_BAND)."""
    T = th * th
    D = lam * lam + T
    if D < Z_BAND * Z_BAND:
        a1, b1, c1, d1, e1, a2, b2, c2 = _zseries(lam, T, Z_TERMS)
        return a1, b1, c1, d1, e1, a1 - T * c1, a2, b2, c2
    E, A, I1 = _lam3(lam)
    # φ2(λ) = ∫(1 − s) e^{sλ} = φ1 − φ1′: no cancellation for small λ; (φ1 − 1)/λ for large
    a2 = A - I1 if abs(lam) < L_TAYLOR else (A - 1.0) / lam
    a, b, c, qa, qb = _theta5(th)
    bl = b - lam * c
    Di = 1.0 / D
    ld = lam * Di
    td = T * Di
    b1 = lam * ld * I1 + td * E * bl
    c1 = ld * (E * b - I1) + td * E * c
    d1 = (E * (2.0 * bl + T * (qa - lam * qb)) - 2.0 * b1) * Di
    e1 = (E * (lam * qa + 2.0 * c + T * qb) - 2.0 * c1) * Di
    # φ2(z) − φ2(λ) = θ (P + iQ)/z², P = θ (φ2(λ) − e^λ b), Q = λ (φ1′(λ) − φ2(λ)) − e^λ θ² c
    p = a2 - E * b
    q = lam * (I1 - a2) - E * T * c
    l2 = (lam * lam - T) * Di * Di  # (λ² − θ²)/D² before the e^λ-sized factors: no overflow
    b2 = q * l2 - 2.0 * ld * td * p
    c2 = -p * l2 - 2.0 * ld * Di * q
    return A, b1, c1, d1, e1, A - T * c1, a2, b2, c2


@kernel
def _wcoefs(lam, th):
    """(e^λ, a1, b1, c1, a, b): W = φ1(B) = a1 I + b1 Ω + c1 Ω² as in :func:`_coefs`, and
    R = I + a Ω + b Ω² (exp and log)."""
    a, b, c = _theta_abc(th)
    T = th * th
    D = lam * lam + T
    if D < Z_BAND_W * Z_BAND_W:
        a1, b1, c1, _, _, _, _, _ = _zseries(lam, T, Z_TERMS_W)
        return math.exp(lam), a1, b1, c1, a, b
    E, A, I1 = _lam3(lam)
    Di = 1.0 / D
    # λ²/D, θ²/D ≤ 1 first: no overflow before e^λ itself does (λ ≈ 709.8)
    ld = lam * Di
    td = T * Di
    b1 = lam * ld * I1 + td * E * (b - lam * c)
    c1 = ld * (E * b - I1) + td * E * c
    return E, A, b1, c1, a, b


# ---------------------------------------------------------------- 3×3 helpers on 9-tuples


@helper_kernel
def _mv(M, v0, v1, v2):
    return (
        M[0] * v0 + M[1] * v1 + M[2] * v2,
        M[3] * v0 + M[4] * v1 + M[5] * v2,
        M[6] * v0 + M[7] * v1 + M[8] * v2,
    )


@helper_kernel
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@helper_kernel
def _skew_times(v0, v1, v2, M):
    """v× M for a 9-tuple M."""
    return (
        v1 * M[6] - v2 * M[3], v1 * M[7] - v2 * M[4], v1 * M[8] - v2 * M[5],
        v2 * M[0] - v0 * M[6], v2 * M[1] - v0 * M[7], v2 * M[2] - v0 * M[8],
        v0 * M[3] - v1 * M[0], v0 * M[4] - v1 * M[1], v0 * M[5] - v1 * M[2],
    )


@helper_kernel
def _Q9(w0, w1, w2, u0, u1, u2, b1, c1, d1, e1, W, J):
    """D_exp's lower-left block Q = ∂(W u)/∂ω + (W u)× J (module docstring), J = SO(3)'s D_exp."""
    Wu = _mv(W, u0, u1, u2)
    P = _skew_times(Wu[0], Wu[1], Wu[2], J)
    g = w0 * u0 + w1 * u1 + w2 * u2
    o = _cross(w0, w1, w2, u0, u1, u2)
    oo = _cross(w0, w1, w2, o[0], o[1], o[2])
    r0 = d1 * o[0] + e1 * oo[0]
    r1 = d1 * o[1] + e1 * oo[1]
    r2 = d1 * o[2] + e1 * oo[2]
    cg = c1 * g
    # Q_ij = −b1 U_ij + c1 (ω_i u_j − 2 u_i ω_j + δ_ij ω·u) + r_i ω_j + P_ij  (no list: no allocation)
    return (
        c1 * (w0 * u0 - 2.0 * u0 * w0) + r0 * w0 + P[0] + cg,
        b1 * u2 + c1 * (w0 * u1 - 2.0 * u0 * w1) + r0 * w1 + P[1],
        -b1 * u1 + c1 * (w0 * u2 - 2.0 * u0 * w2) + r0 * w2 + P[2],
        -b1 * u2 + c1 * (w1 * u0 - 2.0 * u1 * w0) + r1 * w0 + P[3],
        c1 * (w1 * u1 - 2.0 * u1 * w1) + r1 * w1 + P[4] + cg,
        b1 * u0 + c1 * (w1 * u2 - 2.0 * u1 * w2) + r1 * w2 + P[5],
        b1 * u1 + c1 * (w2 * u0 - 2.0 * u2 * w0) + r2 * w0 + P[6],
        -b1 * u0 + c1 * (w2 * u1 - 2.0 * u2 * w1) + r2 * w1 + P[7],
        c1 * (w2 * u2 - 2.0 * u2 * w2) + r2 * w2 + P[8] + cg,
    )


@helper_kernel
def _winv_coefs(th, a1, b1, c1, r1):
    """W⁻¹ = g(B) = al0 I + al1 Ω + al2 Ω² by (F): g(λ) = 1/a1, g(z) = 1/(r1 + iθ b1),
    al1 = −b1/m, al2 = (b1² − r1 c1)/(a1 m), m = |φ1(z)|² = r1² + θ² b1²; formed from the
    coefficients scaled by 1/a1 so that m cannot overflow (a1 ~ e^λ/λ)."""
    s = 1.0 / a1
    b = b1 * s
    c = c1 * s
    r = r1 * s
    m = r * r + th * th * b * b
    return s, -b * s / m, (b * b - r * c) * s / m


@helper_kernel
def _Winv(w0, w1, w2, th, a1, b1, c1, r1):
    al0, al1, al2 = _winv_coefs(th, a1, b1, c1, r1)
    return lin9(w0, w1, w2, al0, al1, al2)


@helper_kernel
def _L_product(w, u, th, ek, coefs, winv):
    """D_log's lower-left block L = −W⁻¹ Q J⁻¹ without a 3×3 product (docs/sim3.md §5).

    ``w``, ``u``: ω and u as 3-tuples; ``coefs``: :func:`_coefs`' 9-tuple (a1, b1, c1, d1,
    e1 used here); ``winv``: :func:`_winv_coefs`' (al0, al1, al2).

    J⁻¹ = I − ½Ω + e Ω² (ek = e_θ), W⁻¹ = al0 I + al1 Ω + al2 Ω². With Q = K + (W u)× J,
    K = ∂(W u)/∂ω (§4): Q J⁻¹ = K J⁻¹ + (W u)×, and since ωᵀ J⁻¹ = ωᵀ, U Ω = ω uᵀ − g I,
    U Ω² = −ω oᵀ − g Ω (g = ω·u, o = ω × u, oo = ω × o):

        Q J⁻¹ = s× + ω pᵀ + r ωᵀ + d0 I + d1′ Ω + d2 Ω²,
        s = W u − b1 u,  p = ½ b1 u + b1 e o + c1 J⁻ᵀu,  r = −2 c1 u + d1 o + e1 oo,
        d0 = g (c1 − ½ b1),  d1′ = g (b1 e − ½ c1),  d2 = g c1 e;

    and W⁻¹ s× = al0 s× + (al1 s + al2 ω × s) ωᵀ − (ω·s)(al1 I + al2 Ω) (Ω s× = s ωᵀ − (ω·s) I),
    W⁻¹ ω = al0 ω, W⁻¹ (d0 I + d1′ Ω + d2 Ω²) by Ω³ = −θ² Ω.
    """
    w0, w1, w2 = w
    u0, u1, u2 = u
    a1, b1, c1, d1, e1 = coefs[0], coefs[1], coefs[2], coefs[3], coefs[4]
    al0, al1, al2 = winv
    g = w0 * u0 + w1 * u1 + w2 * u2
    o0, o1, o2 = _cross(w0, w1, w2, u0, u1, u2)
    q0, q1, q2 = _cross(w0, w1, w2, o0, o1, o2)
    ab = a1 - b1
    s0 = ab * u0 + b1 * o0 + c1 * q0
    s1 = ab * u1 + b1 * o1 + c1 * q1
    s2 = ab * u2 + b1 * o2 + c1 * q2
    # p = ½ b1 u + b1 e o + c1 (u + ½ o + e oo)
    pu = 0.5 * b1 + c1
    po = b1 * ek + 0.5 * c1
    pq = c1 * ek
    p0 = pu * u0 + po * o0 + pq * q0
    p1 = pu * u1 + po * o1 + pq * q1
    p2 = pu * u2 + po * o2 + pq * q2
    r0 = -2.0 * c1 * u0 + d1 * o0 + e1 * q0
    r1 = -2.0 * c1 * u1 + d1 * o1 + e1 * q1
    r2 = -2.0 * c1 * u2 + d1 * o2 + e1 * q2
    # W⁻¹ r
    x0, x1, x2 = _cross(w0, w1, w2, r0, r1, r2)
    y0, y1, y2 = _cross(w0, w1, w2, x0, x1, x2)
    ws0, ws1, ws2 = _cross(w0, w1, w2, s0, s1, s2)
    Y0 = al1 * s0 + al2 * ws0 + al0 * r0 + al1 * x0 + al2 * y0
    Y1 = al1 * s1 + al2 * ws1 + al0 * r1 + al1 * x1 + al2 * y1
    Y2 = al1 * s2 + al2 * ws2 + al0 * r2 + al1 * x2 + al2 * y2
    d0 = g * (c1 - 0.5 * b1)
    dd1 = g * (b1 * ek - 0.5 * c1)
    d2 = g * c1 * ek
    t2 = th * th
    os = w0 * s0 + w1 * s1 + w2 * s2
    f0 = al0 * d0 - al1 * os
    f1 = al0 * dd1 + al1 * d0 - t2 * (al1 * d2 + al2 * dd1) - al2 * os
    f2 = al0 * d2 + al1 * dd1 + al2 * d0 - t2 * al2 * d2
    P = lin9(w0, w1, w2, f0, f1, f2)
    a0p0 = al0 * p0
    a0p1 = al0 * p1
    a0p2 = al0 * p2
    S0 = al0 * s0
    S1 = al0 * s1
    S2 = al0 * s2
    return (
        -(P[0] + Y0 * w0 + w0 * a0p0),
        -(P[1] - S2 + Y0 * w1 + w0 * a0p1),
        -(P[2] + S1 + Y0 * w2 + w0 * a0p2),
        -(P[3] + S2 + Y1 * w0 + w1 * a0p0),
        -(P[4] + Y1 * w1 + w1 * a0p1),
        -(P[5] - S0 + Y1 * w2 + w1 * a0p2),
        -(P[6] - S1 + Y2 * w0 + w2 * a0p0),
        -(P[7] + S0 + Y2 * w1 + w2 * a0p1),
        -(P[8] + Y2 * w2 + w2 * a0p2),
    )


# ---------------------------------------------------------------- cores


@kernel
def _hat(x, out):
    # [[ω×, u], [0, −λ]]
    _se3._hat(x, out)
    out[3, 3] = -x[6]


@kernel
def _vee(X, out):
    _se3._vee(X, out)
    out[6] = -X[3, 3]


@kernel
def _exp(x, out):
    w0, w1, w2 = x[0], x[1], x[2]
    lam = x[6]
    th = norm3(w0, w1, w2)
    E, a1, b1, c1, a, b = _wcoefs(lam, th)
    R = rod9(w0, w1, w2, a, b)
    # t = ∫₀¹ e^{(1−τ)Ω} u e^{−τλ} dτ = e^{−λ} φ1(Ω + λI) u
    c = 1.0 / E
    W = lin9(w0, w1, w2, c * a1, c * b1, c * c1)
    t = _mv(W, x[3], x[4], x[5])
    for i in range(3):
        out[i, 0] = R[3 * i]
        out[i, 1] = R[3 * i + 1]
        out[i, 2] = R[3 * i + 2]
        out[i, 3] = t[i]
        out[3, i] = 0.0
    out[3, 3] = c


@kernel
def _log(X, out):
    _so3._log(X, out)
    w0, w1, w2 = out[0], out[1], out[2]
    c = X[3, 3]
    lam = -math.log(c)
    th = norm3(w0, w1, w2)
    E, a1, b1, c1, a, b = _wcoefs(lam, th)
    Wi = _Winv(w0, w1, w2, th, a1, b1, c1, a1 - th * th * c1)
    u = _mv(Wi, X[0, 3] / c, X[1, 3] / c, X[2, 3] / c)
    out[3] = u[0]
    out[4] = u[1]
    out[5] = u[2]
    out[6] = lam


@kernel
def _ad(x, out):
    # [[Ω, 0, 0], [U, Ω + λI, −u], [0, 0, 0]]: vee([hat x, hat y]) column by column
    for i in range(7):
        for j in range(7):
            out[i, j] = 0.0
    w0, w1, w2 = x[0], x[1], x[2]
    u0, u1, u2 = x[3], x[4], x[5]
    lam = x[6]
    for k in (0, 3):
        out[k + 0, k + 1] = -w2
        out[k + 0, k + 2] = w1
        out[k + 1, k + 0] = w2
        out[k + 1, k + 2] = -w0
        out[k + 2, k + 0] = -w1
        out[k + 2, k + 1] = w0
    out[3, 1] = -u2
    out[3, 2] = u1
    out[4, 0] = u2
    out[4, 2] = -u0
    out[5, 0] = -u1
    out[5, 1] = u0
    out[3, 3] = lam
    out[4, 4] = lam
    out[5, 5] = lam
    out[3, 6] = -u0
    out[4, 6] = -u1
    out[5, 6] = -u2


@kernel
def _Ad(X, out):
    # X hat(ω, u, λ) X⁻¹ = hat(R ω, s (t × R ω + R u − λ t), λ) with s = 1/X33: SE(3)'s
    # [[R, 0], [t× R, R]] with its lower rows times s, then the column −s t
    _se3._Ad(X, out)
    s = 1.0 / X[3, 3]
    for i in range(3):
        for j in range(6):
            out[i + 3, j] = s * out[i + 3, j]
        out[i, 6] = 0.0
        out[i + 3, 6] = -s * X[i, 3]
    for j in range(6):
        out[6, j] = 0.0
    out[6, 6] = 1.0


@helper_kernel
def _write_blocks(A, L, D, p, out):
    """out = [[A, 0, 0], [L, D, p], [0, 0, 1]] for 9-tuples A, L, D and a 3-tuple p."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[3 * i + j]
            out[i, j + 3] = 0.0
            out[i + 3, j] = L[3 * i + j]
            out[i + 3, j + 3] = D[3 * i + j]
        out[i, 6] = 0.0
        out[i + 3, 6] = p[i]
        out[6, i] = 0.0
        out[6, i + 3] = 0.0
    out[6, 6] = 1.0


@helper_kernel
def _trig(w0, w1, w2, th):
    """(θ, cos θ, sin θ, 1 − cos θ = 2 sin²(θ/2)) for θ = |ω|; above π from δ = 2π − θ with θ
    in double-double (D_log: sin θ and sin(θ/2) → 0 as θ → 2π, and J⁻¹, W⁻¹ ~ 1/(2π − θ))."""
    # one sine/cosine pair of the half angle: sin θ = 2 sin(θ/2) cos(θ/2), cos θ = 1 − 2 sin²(θ/2)
    if th > math.pi:
        hi, lo = theta_dd(w0, w1, w2)
        h = 0.5 * ((_TWO_PI_HI - hi) + (_TWO_PI_LO - lo))
        sh = math.sin(h)
        omc = 2.0 * sh * sh
        return hi, 1.0 - omc, -2.0 * sh * math.cos(h), omc
    sh = math.sin(0.5 * th)
    omc = 2.0 * sh * sh
    return th, 1.0 - omc, 2.0 * sh * math.cos(0.5 * th), omc


@helper_kernel
def _L_spectral(w0, w1, w2, u0, u1, u2, th, gu, AB, CD, GH):
    """Lower-left block (L) of f(ad_x) from A + iB = f[z, iθ], C + iD = f[z, 0], G + iH = f[λ, iθ]
    (module docstring; gu = ω·u)."""
    A, B = AB.real, AB.imag
    C, D = CD.real, CD.imag
    G, H = GH.real, GH.imag
    # in n = ω/θ: k1 (ω·u) Ω = (A − G)(n·u) n×, ... (every k's power of θ cancels); at θ = 0
    # the k-terms vanish (A = G, B = D = H = 0, G = C) and n = 0 is used
    if th > 0.0:
        w0 = w0 / th
        w1 = w1 / th
        w2 = w2 / th
        gu = gu / th
    else:
        w0 = w1 = w2 = gu = 0.0
    k1 = A - G
    k2 = B - D - H
    k3 = -(D + H)
    k4 = D
    k5 = H
    k6 = G - C
    o = _cross(w0, w1, w2, u0, u1, u2)
    S = lin9(w0, w1, w2, k3 * gu, k1 * gu, k2 * gu)
    return (
        S[0] + k4 * u0 * w0 + k5 * w0 * u0 + k6 * o[0] * w0,
        -G * u2 + S[1] + k4 * u0 * w1 + k5 * w0 * u1 + k6 * o[0] * w1,
        G * u1 + S[2] + k4 * u0 * w2 + k5 * w0 * u2 + k6 * o[0] * w2,
        G * u2 + S[3] + k4 * u1 * w0 + k5 * w1 * u0 + k6 * o[1] * w0,
        S[4] + k4 * u1 * w1 + k5 * w1 * u1 + k6 * o[1] * w1,
        -G * u0 + S[5] + k4 * u1 * w2 + k5 * w1 * u2 + k6 * o[1] * w2,
        -G * u1 + S[6] + k4 * u2 * w0 + k5 * w2 * u0 + k6 * o[2] * w0,
        G * u0 + S[7] + k4 * u2 * w1 + k5 * w2 * u1 + k6 * o[2] * w1,
        S[8] + k4 * u2 * w2 + k5 * w2 * u2 + k6 * o[2] * w2,
    )


@helper_kernel
def _divdiff_small(lam, th, a1, b1, r1, a2, b2, c2):
    """φ1[z, iθ], φ1[z, 0] = φ2(z), φ1[λ, iθ] for θ < SPECTRAL from the real coefficients; no
    cancellation for |λ| ≥ LAM_SPECTRAL (φ1(λ) is then far from φ1(iθ) ≈ 1)."""
    a = a_theta(th)
    b = b_theta(th)
    f_it = complex(a, th * b)  # φ1(iθ) = a(θ) + iθ b(θ)
    e_it = complex(1.0 - th * th * b, th * a)  # e^{iθ}
    z = complex(lam, th)
    AB = (e_it * a1 - f_it) / z
    CD = complex(a2 - th * th * c2, th * b2)
    GH = (a1 - f_it) / complex(lam, -th)
    return AB, CD, GH


@helper_kernel
def _parts(x):
    """(ω0, ω1, ω2, u0, u1, u2, λ, θ = |ω|) of a tangent x."""
    return x[0], x[1], x[2], x[3], x[4], x[5], x[6], norm3(x[0], x[1], x[2])


@helper_kernel
def _fB(w0, w1, w2, th, fl, fz):
    """f(B) = f(λ) I + (Im f(z)/θ) Ω + ((f(λ) − Re f(z))/θ²) Ω², formula (F), as a 9-tuple."""
    return lin9(w0, w1, w2, fl, fz.imag / th, (fl - fz.real) / (th * th))


@kernel
def _dexp(x, out):
    w0, w1, w2, u0, u1, u2, lam, th = _parts(x)
    if th < SPECTRAL:
        a1, b1, c1, d1, e1, r1, a2, b2, c2 = _coefs(lam, th)
        J = rod9(w0, w1, w2, b_theta(th), c_theta(th))
        W = lin9(w0, w1, w2, a1, b1, c1)
        if abs(lam) < LAM_SPECTRAL:
            Q = _Q9(w0, w1, w2, u0, u1, u2, b1, c1, d1, e1, W, J)
        else:
            AB, CD, GH = _divdiff_small(lam, th, a1, b1, r1, a2, b2, c2)
            Q = _L_spectral(w0, w1, w2, u0, u1, u2, th, w0 * u0 + w1 * u1 + w2 * u2, AB, CD, GH)
        q = _mv(lin9(w0, w1, w2, -a2, -b2, -c2), u0, u1, u2)
        _write_blocks(J, Q, W, q, out)
        return
    # θ ≥ SPECTRAL: |z| ≥ 1, the complex closed forms have no cancellation
    th, co, sn, omc = _trig(w0, w1, w2, th)
    E, A, I1 = _lam3(lam)
    a2 = A - I1 if abs(lam) < L_TAYLOR else (A - 1.0) / lam
    z = complex(lam, th)
    f_it = complex(sn, omc) / th  # φ1(iθ) = (e^{iθ} − 1)/(iθ)
    # φ1(z), e^z − 1 free of cancellation; expm1(λ) = λ φ1(λ) to 2 ulps
    f_z = complex(A * lam * co - omc, E * sn) / z
    p2_z = (f_z - 1.0) / z  # φ2(z)
    t2 = th * th
    J = rod9(w0, w1, w2, omc / t2, (th - sn) / (t2 * th))
    W = _fB(w0, w1, w2, th, A, f_z)
    p2 = _mv(_fB(w0, w1, w2, th, a2, p2_z), u0, u1, u2)
    q = (-p2[0], -p2[1], -p2[2])
    # φ1[z, iθ] = (e^{iθ} φ1(λ) − φ1(iθ))/z, φ1[z, 0] = φ2(z), φ1[λ, iθ] = (φ1(λ) − φ1(iθ))/(λ − iθ)
    AB = (complex(co * A, sn * A) - f_it) / z
    GH = (A - f_it) / complex(lam, -th)
    L = _L_spectral(w0, w1, w2, u0, u1, u2, th, w0 * u0 + w1 * u1 + w2 * u2, AB, p2_z, GH)
    _write_blocks(J, L, W, q, out)


@kernel
def _dlog(x, out):
    w0, w1, w2, u0, u1, u2, lam, th = _parts(x)
    if th < SPECTRAL:
        # θ < SPECTRAL < E_TAYLOR: e_θ is its Taylor band; the θ computed above (no second norm)
        ek = horner4(E_SERIES, th * th)
        Ji = rod9(w0, w1, w2, -0.5, ek)
        coefs = _coefs(lam, th)
        a1, b1, c1, d1, e1, r1, a2, b2, c2 = coefs
        winv = _winv_coefs(th, a1, b1, c1, r1)
        Wi = lin9(w0, w1, w2, winv[0], winv[1], winv[2])
        if abs(lam) < LAM_SPECTRAL:
            L = _L_product((w0, w1, w2), (u0, u1, u2), th, ek, coefs, winv)
        else:
            AB, CD, GH = _divdiff_small(lam, th, a1, b1, r1, a2, b2, c2)
            # g[a, b] = −g(a) g(b) φ1[a, b]
            g_it = 1.0 / complex(a_theta(th), th * b_theta(th))
            g_z = 1.0 / complex(r1, th * b1)
            AB = -g_z * g_it * AB
            CD = -g_z * CD
            GH = -g_it * GH / a1
            L = _L_spectral(w0, w1, w2, u0, u1, u2, th, dot3(w0, w1, w2, u0, u1, u2), AB, CD, GH)
        q = _mv(lin9(w0, w1, w2, a2, b2, c2), u0, u1, u2)
        p = _mv(Wi, q[0], q[1], q[2])
        _write_blocks(Ji, L, Wi, p, out)
        return
    th, co, sn, omc = _trig(w0, w1, w2, th)
    t2 = th * th
    # e_θ = 1/θ² − cot(θ/2)/(2θ) (Eade, Eq. 57), cot(θ/2) = sin θ/(1 − cos θ) from the
    # (reflected) values above; its Taylor band below E_TAYLOR
    cot2 = sn / omc  # cot(θ/2)
    ek = horner4(E_SERIES, t2) if th < E_TAYLOR else 1.0 / t2 - cot2 / (2.0 * th)
    Ji = rod9(w0, w1, w2, -0.5, ek)
    E, A, I1 = _lam3(lam)
    a2 = A - I1 if abs(lam) < L_TAYLOR else (A - 1.0) / lam
    z = complex(lam, th)
    D = lam * lam + t2
    zi = complex(lam / D, -th / D)  # 1/z; 1/(λ − iθ) = z/D
    # φ1(iθ) = (e^{iθ} − 1)/(iθ), g(iθ) = iθ/(e^{iθ} − 1) = (θ/2) cot(θ/2) − iθ/2;
    # φ1(z) = (e^z − 1)/z with e^z − 1 free of cancellation, g(z) = z/(e^z − 1)
    f_it = complex(sn / th, omc / th)
    g_it = complex(0.5 * th * cot2, -0.5 * th)
    N = complex(A * lam * co - omc, E * sn)  # expm1(λ) = λ φ1(λ) to 2 ulps
    f_z = N * zi
    g_z = z * N.conjugate() / (N.real * N.real + N.imag * N.imag)
    g_l = 1.0 / A
    p2_z = (f_z - 1.0) * zi
    # g[a, b] = −g(a) g(b) φ1[a, b]; φ1[z, iθ] = (e^{iθ} φ1(λ) − φ1(iθ))/z: no 1/λ
    AB = -g_z * g_it * (complex(co * A, sn * A) - f_it) * zi
    CD = -g_z * p2_z
    GH = -g_l * g_it * (A - f_it) * z / D
    # ω·u multiplies k2 ~ 1/(2π − θ)²: compensated
    L = _L_spectral(w0, w1, w2, u0, u1, u2, th, dot3(w0, w1, w2, u0, u1, u2), AB, CD, GH)
    # W⁻¹ = g(B), ψ(B) = −g[B, 0] by (F)
    Wi = _fB(w0, w1, w2, th, g_l, g_z)
    p = _mv(_fB(w0, w1, w2, th, g_l * a2, -CD), u0, u1, u2)
    _write_blocks(Ji, L, Wi, p, out)


@kernel
def _compose(X, Y, out):
    for i in range(4):
        for j in range(4):
            out[i, j] = X[i, 0] * Y[0, j] + X[i, 1] * Y[1, j] + X[i, 2] * Y[2, j] + X[i, 3] * Y[3, j]
    for j in range(3):
        out[3, j] = 0.0


@kernel
def _inverse(X, out):
    # [[Rᵀ, −Rᵀ t/X33], [0, 1/X33]]
    ci = 1.0 / X[3, 3]
    for i in range(3):
        for j in range(3):
            out[i, j] = X[j, i]
        out[i, 3] = -(X[0, i] * X[0, 3] + X[1, i] * X[1, 3] + X[2, i] * X[2, 3]) * ci
        out[3, i] = 0.0
    out[3, 3] = ci


# ---------------------------------------------------------------- public functions

hat, vee, exp, log, ad, Ad, dexp, dlog, compose, inverse = _public.functions(_info, globals())
