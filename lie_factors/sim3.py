"""Sim(3), GTSAM's Similarity3: closed-form exp, log, adjoints and D_exp / D_log.

Tangent ordering and matrices (exactly GTSAM 4.3's, checked in tests/test_sim3.py)::

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

Evaluation. The φ1-family coefficients are integrals of e^{sλ} times the SO(3)
coefficient functions of sθ (a = sin x/x, b = (1 − cos x)/x², c − b, qa; their
Taylor bands are those of :mod:`lie_factors._coeffs`)::

    a1 = ∫ e^{sλ},  b1 = ∫ e^{sλ} s a(sθ),  c1 = ∫ e^{sλ} s² b(sθ),
    d1 = ∫ e^{sλ} s³ (c − b)(sθ),  e1 = ∫ e^{sλ} s⁴ qa(sθ),  Re φ1(z) = ∫ e^{sλ} cos sθ,
    φ2(B) likewise with weight (1 − s),

summed by Gauss–Legendre quadrature (``QUAD_NODES`` nodes per panel, panels of
(|λ| + θ)·width ≤ ``QUAD_PANEL``). The integrands are entire, so this has no
removable singularity at θ → 0, λ → 0 or both, and no cancellation: the
closed forms in z lose ~ε/θ² (c1) and ~ε/θ⁴ (d1, e1) and would need a
two-parameter series band. D_log's lower-left block uses −W⁻¹ Q J⁻¹ for θ <
``DLOG_SPECTRAL`` and formula (L) with f = g above, where J⁻¹ and W⁻¹ grow like
1/(2π − θ) and the product would amplify rounding by their product.

``dexp`` is the LEFT Jacobian Σ ad^i/(i+1)! (seed 000, Eq. 35):
exp(x + ε) ≈ exp(dexp(x) ε)·exp(x); a GTSAM-style right Jacobian is dexp(−x).
"""

from __future__ import annotations

import math

import numpy as np

from lie_factors import _check, _jit, _validate
from lie_factors import so3 as _so3
from lie_factors._coeffs import (
    _A_SERIES, _C_SERIES, _QA_SERIES, A_TAYLOR, C_TAYLOR, QA_TAYLOR, _horner, a_theta, b_theta, c_theta, dot3,
    e_omega, norm3, theta_dd,
)
from lie_factors._jit import kernel
from lie_factors.se3 import _lin9, _rod9

DIM = 7
MAT = 4

#: Gauss–Legendre nodes per panel.
QUAD_NODES = 12
#: Largest (|λ| + θ)·(panel width) per panel: the integrands are entire of
#: exponential type |λ| + θ, so 12 nodes leave an error ~ (P/4)^24/24! ≈ 2e-20 at P = 6.
QUAD_PANEL = 6.0
#: For |λ| + θ ≤ QUAD_SMALL (the usual size of a between-pose increment) one panel
#: of QUAD_NODES_SMALL nodes: error ~ (2/4)^16/16! ≈ 7e-19.
QUAD_SMALL = 2.0
QUAD_NODES_SMALL = 8
#: e^{sλ} below e^{−QUAD_CUT} of its maximum on [0, 1] is dropped (|λ| > QUAD_CUT only).
QUAD_CUT = 45.0
#: D_log lower-left block: product form below this θ, spectral form (L) from it on.
DLOG_SPECTRAL = 1.0

_GL_X, _GL_W = np.polynomial.legendre.leggauss(QUAD_NODES)
_GL_S = 0.5 * (_GL_X + 1.0)
_GL_H = 0.5 * _GL_W
_GL_X8, _GL_W8 = np.polynomial.legendre.leggauss(QUAD_NODES_SMALL)
_GL_S8 = 0.5 * (_GL_X8 + 1.0)
_GL_H8 = 0.5 * _GL_W8
_TWO_PI_HI = 6.283185307179586
_TWO_PI_LO = 2.4492935982947064e-16


# ---------------------------------------------------------------- scalar coefficients


@kernel
def _ab(x):
    """(a, b, cos x) with a = sin x/x, b = (1 − cos x)/x² (seed 000, Eqs. 50–51), from one
    sine and cosine of x/2; b = ½ (sin(x/2)/(x/2))² has no cancellation."""
    y = 0.5 * x
    if x < A_TAYLOR:
        a = _horner(_A_SERIES, x * x)
        ah = _horner(_A_SERIES, y * y)
    else:
        sh = math.sin(y)
        ch = math.cos(y)
        a = sh * ch / y
        ah = sh / y
    b = 0.5 * ah * ah
    return a, b, 1.0 - x * x * b


@kernel
def _kappa(x):
    """(a, b, c − b, qa, cos) of the SO(3) coefficient functions at x ≥ 0 (seed 000, Eqs. 50–52, 64)."""
    a, b, co = _ab(x)
    t = x * x
    if x < C_TAYLOR:
        c = _horner(_C_SERIES, t)
    else:
        c = (1.0 - a) / t
    if x < QA_TAYLOR:
        qa = _horner(_QA_SERIES, t)
    else:
        qa = (a - 2.0 * b) / t
    return a, b, c - b, qa, co


@kernel
def _span(lam, th):
    """Quadrature rule: (nodes, weights) on [0, 1], interval [lo, hi] ⊂ [0, 1], number of panels."""
    if abs(lam) + th <= QUAD_SMALL:
        return _GL_S8, _GL_H8, 0.0, 1.0, 1
    lo = 0.0
    hi = 1.0
    if lam < -QUAD_CUT:
        hi = QUAD_CUT / -lam
    elif lam > QUAD_CUT:
        lo = 1.0 - QUAD_CUT / lam
    m = (abs(lam) + th) * (hi - lo) / QUAD_PANEL
    n = 1 + int(min(m, 1e5))
    return _GL_S, _GL_H, lo, hi, n


@kernel
def _integrals(lam, th):
    """(a1, b1, c1, d1, e1, re1, a2, b2, c2): φ1(B) = a1 I + b1 Ω + c1 Ω², d1 = ∂b1/∂θ/θ,
    e1 = ∂c1/∂θ/θ, re1 = Re φ1(λ + iθ), φ2(B) = a2 I + b2 Ω + c2 Ω² (module docstring)."""
    S, H, lo, hi, n = _span(lam, th)
    h = (hi - lo) / n
    a1 = b1 = c1 = d1 = e1 = r1 = a2 = b2 = c2 = 0.0
    for p in range(n):
        s0 = lo + p * h
        for k in range(len(S)):
            s = s0 + h * S[k]
            w = h * H[k] * math.exp(s * lam)
            a, b, cb, qa, co = _kappa(s * th)
            s2 = s * s
            fb = w * s * a
            fc = w * s2 * b
            a1 += w
            b1 += fb
            c1 += fc
            d1 += w * s2 * s * cb
            e1 += w * s2 * s2 * qa
            r1 += w * co
            v = 1.0 - s
            a2 += v * w
            b2 += v * fb
            c2 += v * fc
    return a1, b1, c1, d1, e1, r1, a2, b2, c2


@kernel
def _w_integrals(lam, th):
    """(a1, b1, c1, re1) only, for exp and log: the same sums as :func:`_integrals`."""
    S, H, lo, hi, n = _span(lam, th)
    h = (hi - lo) / n
    a1 = b1 = c1 = r1 = 0.0
    for p in range(n):
        s0 = lo + p * h
        for k in range(len(S)):
            s = s0 + h * S[k]
            w = h * H[k] * math.exp(s * lam)
            a, b, co = _ab(s * th)
            a1 += w
            b1 += w * s * a
            c1 += w * s * s * b
            r1 += w * co
    return a1, b1, c1, r1


@kernel
def _phi1_div_z_it(lam, th):
    """φ1[λ + iθ, iθ] = ∫₀¹ s e^{isθ} φ1(sλ) ds (Hermite–Genocchi; no 1/λ)."""
    # φ1(sλ) decays only like 1/(s|λ|): the whole of [0, 1] counts
    n = 1 + int(min((abs(lam) + th) / QUAD_PANEL, 1e5))
    h = 1.0 / n
    re = 0.0
    im = 0.0
    for p in range(n):
        s0 = p * h
        for k in range(QUAD_NODES):
            s = s0 + h * _GL_S[k]
            y = s * lam
            f = math.expm1(y) / y if y != 0.0 else 1.0
            f *= h * _GL_H[k] * s
            re += f * math.cos(s * th)
            im += f * math.sin(s * th)
    return complex(re, im)


# ---------------------------------------------------------------- 3×3 helpers on 9-tuples


@kernel
def _mv(M, v0, v1, v2):
    return (
        M[0] * v0 + M[1] * v1 + M[2] * v2,
        M[3] * v0 + M[4] * v1 + M[5] * v2,
        M[6] * v0 + M[7] * v1 + M[8] * v2,
    )


@kernel
def _mm(A, B):
    return (
        A[0] * B[0] + A[1] * B[3] + A[2] * B[6],
        A[0] * B[1] + A[1] * B[4] + A[2] * B[7],
        A[0] * B[2] + A[1] * B[5] + A[2] * B[8],
        A[3] * B[0] + A[4] * B[3] + A[5] * B[6],
        A[3] * B[1] + A[4] * B[4] + A[5] * B[7],
        A[3] * B[2] + A[4] * B[5] + A[5] * B[8],
        A[6] * B[0] + A[7] * B[3] + A[8] * B[6],
        A[6] * B[1] + A[7] * B[4] + A[8] * B[7],
        A[6] * B[2] + A[7] * B[5] + A[8] * B[8],
    )


@kernel
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@kernel
def _skew_times(v0, v1, v2, M):
    """v× M for a 9-tuple M."""
    return (
        v1 * M[6] - v2 * M[3], v1 * M[7] - v2 * M[4], v1 * M[8] - v2 * M[5],
        v2 * M[0] - v0 * M[6], v2 * M[1] - v0 * M[7], v2 * M[2] - v0 * M[8],
        v0 * M[3] - v1 * M[0], v0 * M[4] - v1 * M[1], v0 * M[5] - v1 * M[2],
    )


@kernel
def _Q9(w0, w1, w2, u0, u1, u2, th, b1, c1, d1, e1, W):
    """D_exp's lower-left block Q = ∂(W u)/∂ω + (W u)× J (module docstring)."""
    J = _rod9(w0, w1, w2, b_theta(th), c_theta(th))
    Wu = _mv(W, u0, u1, u2)
    P = _skew_times(Wu[0], Wu[1], Wu[2], J)
    g = w0 * u0 + w1 * u1 + w2 * u2
    o = _cross(w0, w1, w2, u0, u1, u2)
    oo = _cross(w0, w1, w2, o[0], o[1], o[2])
    w = (w0, w1, w2)
    u = (u0, u1, u2)
    r = (d1 * o[0] + e1 * oo[0], d1 * o[1] + e1 * oo[1], d1 * o[2] + e1 * oo[2])
    Ux = (0.0, -u2, u1, u2, 0.0, -u0, -u1, u0, 0.0)
    out = [0.0] * 9
    for i in range(3):
        for j in range(3):
            v = -b1 * Ux[3 * i + j] + c1 * (w[i] * u[j] - 2.0 * u[i] * w[j]) + r[i] * w[j]
            if i == j:
                v += c1 * g
            out[3 * i + j] = v + P[3 * i + j]
    return (out[0], out[1], out[2], out[3], out[4], out[5], out[6], out[7], out[8])


# ---------------------------------------------------------------- cores


@kernel
def _hat(x, out):
    out[0, 0] = 0.0
    out[0, 1] = -x[2]
    out[0, 2] = x[1]
    out[1, 0] = x[2]
    out[1, 1] = 0.0
    out[1, 2] = -x[0]
    out[2, 0] = -x[1]
    out[2, 1] = x[0]
    out[2, 2] = 0.0
    out[0, 3] = x[3]
    out[1, 3] = x[4]
    out[2, 3] = x[5]
    out[3, 0] = 0.0
    out[3, 1] = 0.0
    out[3, 2] = 0.0
    out[3, 3] = -x[6]


@kernel
def _vee(X, out):
    out[0] = X[2, 1]
    out[1] = X[0, 2]
    out[2] = X[1, 0]
    out[3] = X[0, 3]
    out[4] = X[1, 3]
    out[5] = X[2, 3]
    out[6] = -X[3, 3]


@kernel
def _exp(x, out):
    w0, w1, w2 = x[0], x[1], x[2]
    lam = x[6]
    th = norm3(w0, w1, w2)
    a1, b1, c1, r1 = _w_integrals(lam, th)
    R = _rod9(w0, w1, w2, a_theta(th), b_theta(th))
    # t = ∫₀¹ e^{(1−τ)Ω} u e^{−τλ} dτ = e^{−λ} φ1(Ω + λI) u
    c = math.exp(-lam)
    W = _lin9(w0, w1, w2, c * a1, c * b1, c * c1)
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
    a1, b1, c1, r1 = _w_integrals(lam, th)
    # W⁻¹ = g(B) by (F): g(λ) = 1/a1, g(z) = 1/(r1 + iθ b1), m = |φ1(z)|²
    m = r1 * r1 + th * th * b1 * b1
    Wi = _lin9(w0, w1, w2, 1.0 / a1, -b1 / m, (b1 * b1 - r1 * c1) / (a1 * m))
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
    # X hat(ω, u, λ) X⁻¹ = hat(R ω, s (t × R ω + R u − λ t), λ) with s = 1/X33
    s = 1.0 / X[3, 3]
    t0, t1, t2 = X[0, 3], X[1, 3], X[2, 3]
    for j in range(3):
        r0, r1, r2 = X[0, j], X[1, j], X[2, j]
        out[0, j] = r0
        out[1, j] = r1
        out[2, j] = r2
        out[3, j + 3] = s * r0
        out[4, j + 3] = s * r1
        out[5, j + 3] = s * r2
        out[0, j + 3] = 0.0
        out[1, j + 3] = 0.0
        out[2, j + 3] = 0.0
        out[3, j] = s * (t1 * r2 - t2 * r1)
        out[4, j] = s * (t2 * r0 - t0 * r2)
        out[5, j] = s * (t0 * r1 - t1 * r0)
        out[6, j] = 0.0
        out[6, j + 3] = 0.0
    out[0, 6] = 0.0
    out[1, 6] = 0.0
    out[2, 6] = 0.0
    out[3, 6] = -s * t0
    out[4, 6] = -s * t1
    out[5, 6] = -s * t2
    out[6, 6] = 1.0


@kernel
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


@kernel
def _dexp(x, out):
    w0, w1, w2 = x[0], x[1], x[2]
    u0, u1, u2 = x[3], x[4], x[5]
    lam = x[6]
    th = norm3(w0, w1, w2)
    a1, b1, c1, d1, e1, r1, a2, b2, c2 = _integrals(lam, th)
    J = _rod9(w0, w1, w2, b_theta(th), c_theta(th))
    W = _lin9(w0, w1, w2, a1, b1, c1)
    Q = _Q9(w0, w1, w2, u0, u1, u2, th, b1, c1, d1, e1, W)
    q = _mv(_lin9(w0, w1, w2, -a2, -b2, -c2), u0, u1, u2)
    _write_blocks(J, Q, W, q, out)


@kernel
def _dlog(x, out):
    w0, w1, w2 = x[0], x[1], x[2]
    u0, u1, u2 = x[3], x[4], x[5]
    lam = x[6]
    th = norm3(w0, w1, w2)
    a1, b1, c1, d1, e1, r1, a2, b2, c2 = _integrals(lam, th)
    Ji = _rod9(w0, w1, w2, -0.5, e_omega(w0, w1, w2))
    if th < DLOG_SPECTRAL:
        m = r1 * r1 + th * th * b1 * b1
        Wi = _lin9(w0, w1, w2, 1.0 / a1, -b1 / m, (b1 * b1 - r1 * c1) / (a1 * m))
        W = _lin9(w0, w1, w2, a1, b1, c1)
        Q = _Q9(w0, w1, w2, u0, u1, u2, th, b1, c1, d1, e1, W)
        M = _mm(_mm(Wi, Q), Ji)
        L = (-M[0], -M[1], -M[2], -M[3], -M[4], -M[5], -M[6], -M[7], -M[8])
        q = _mv(_lin9(w0, w1, w2, a2, b2, c2), u0, u1, u2)
        p = _mv(Wi, q[0], q[1], q[2])
        _write_blocks(Ji, L, Wi, p, out)
        return
    # θ from its components in double-double: sin θ, sin(θ/2) near 2π through δ = 2π − θ
    hi, lo = theta_dd(w0, w1, w2)
    th = hi
    if th > math.pi:
        d = (_TWO_PI_HI - hi) + (_TWO_PI_LO - lo)
        sn = -math.sin(d)
        co = math.cos(d)
        sh = math.sin(0.5 * d)
    else:
        sn = math.sin(th)
        co = math.cos(th)
        sh = math.sin(0.5 * th)
    z = complex(lam, th)
    # φ1(iθ) = (e^{iθ} − 1)/(iθ); φ1(z) = (e^z − 1)/z with e^z − 1 free of cancellation
    f_it = complex(sn, 2.0 * sh * sh) / th
    f_z = complex(math.expm1(lam) * co - 2.0 * sh * sh, math.exp(lam) * sn) / z
    g_l = 1.0 / a1
    g_it = 1.0 / f_it
    g_z = 1.0 / f_z
    phi2_z = complex(a2 - c2 * th * th, th * b2)
    # g[a, b] = −g(a) g(b) φ1[a, b]
    AB = -g_z * g_it * _phi1_div_z_it(lam, th)
    CD = -g_z * phi2_z
    GH = -g_l * g_it * (a1 - f_it) / complex(lam, -th)
    A, B = AB.real, AB.imag
    C, D = CD.real, CD.imag
    G, H = GH.real, GH.imag
    t2 = th * th
    k1 = (A - G) / t2
    k2 = (B - D - H) / (t2 * th)
    k3 = -(D + H) / th
    k4 = D / th
    k5 = H / th
    k6 = (G - C) / t2
    # ω·u multiplies k2 ~ 1/(2π − θ)²: compensated
    gu = dot3(w0, w1, w2, u0, u1, u2)
    o = _cross(w0, w1, w2, u0, u1, u2)
    S = _lin9(w0, w1, w2, k3 * gu, k1 * gu, k2 * gu)
    w = (w0, w1, w2)
    u = (u0, u1, u2)
    Ux = (0.0, -u2, u1, u2, 0.0, -u0, -u1, u0, 0.0)
    L9 = [0.0] * 9
    for i in range(3):
        for j in range(3):
            L9[3 * i + j] = (
                G * Ux[3 * i + j] + S[3 * i + j] + k4 * u[i] * w[j] + k5 * w[i] * u[j] + k6 * o[i] * w[j]
            )
    L = (L9[0], L9[1], L9[2], L9[3], L9[4], L9[5], L9[6], L9[7], L9[8])
    # W⁻¹ = g(B), ψ(B) = −g[B, 0] by (F)
    Wi = _lin9(w0, w1, w2, g_l, g_z.imag / th, (g_l - g_z.real) / t2)
    psi_z = -CD
    psi_l = g_l * a2
    p = _mv(_lin9(w0, w1, w2, psi_l, psi_z.imag / th, (psi_l - psi_z.real) / t2), u0, u1, u2)
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


# ---------------------------------------------------------------- one element, one numba call
# The public functions below try these first: a float64 array of exactly the
# element's shape is validated and computed in ONE numba call (through its entry
# point, _jit.one_element) instead of the general path's numpy checks and
# batching (see docs/benchmarks.md, "One element per call", for the cost).
# Each returns True when ``out`` holds the result and False when the input must
# take the general path, which raises the ValueError naming the problem
# (_check.finite / element_ok make the same checks as the general path).
# They are compiled for inputs of any memory order (GTSAM's ``.matrix()`` is
# Fortran-ordered); ``np.ascontiguousarray`` copies the input (at most 16
# numbers, ≈0.02 µs) so that the cores only ever see, and are only compiled
# for, C-ordered arrays, as on the general path.


@kernel
def _hat1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _hat(x, out)
    return True


@kernel
def _vee1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.finite(X):
        return False
    _vee(X, out)
    return True


@kernel
def _exp1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _exp(x, out)
    return True


@kernel
def _log1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.element_ok(X, 3, _check.POSITIVE):
        return False
    _log(X, out)
    return True


@kernel
def _ad1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _ad(x, out)
    return True


@kernel
def _Ad1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.element_ok(X, 3, _check.POSITIVE):
        return False
    _Ad(X, out)
    return True


@kernel
def _dexp1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _dexp(x, out)
    return True


@kernel
def _dlog1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _dlog(x, out)
    return True


@kernel
def _compose1(X, Y, out):
    X = np.ascontiguousarray(X)
    Y = np.ascontiguousarray(Y)
    if not (_check.element_ok(X, 3, _check.POSITIVE) and _check.element_ok(Y, 3, _check.POSITIVE)):
        return False
    _compose(X, Y, out)
    return True


@kernel
def _inverse1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.element_ok(X, 3, _check.POSITIVE):
        return False
    _inverse(X, out)
    return True


# Python's handles on the wrappers above: their compiled entry points, bound on first use.
_hat_one = _jit.one_element(_hat1, (1,), 2, globals(), "_hat_one")
_vee_one = _jit.one_element(_vee1, (2,), 1, globals(), "_vee_one")
_exp_one = _jit.one_element(_exp1, (1,), 2, globals(), "_exp_one")
_log_one = _jit.one_element(_log1, (2,), 1, globals(), "_log_one")
_ad_one = _jit.one_element(_ad1, (1,), 2, globals(), "_ad_one")
_Ad_one = _jit.one_element(_Ad1, (2,), 2, globals(), "_Ad_one")
_dexp_one = _jit.one_element(_dexp1, (1,), 2, globals(), "_dexp_one")
_dlog_one = _jit.one_element(_dlog1, (1,), 2, globals(), "_dlog_one")
_compose_one = _jit.one_element(_compose1, (2, 2), 2, globals(), "_compose_one")
_inverse_one = _jit.one_element(_inverse1, (2,), 2, globals(), "_inverse_one")


# ---------------------------------------------------------------- public API
# Each public function first tries its one-element fast path (``_exp_one`` …): taken when
# the input is an ndarray of exactly the element's shape and dtype float64 (any memory
# order); batches, lists, other dtypes and refused inputs take the general path.
# Both run the same cores.

_ND, _F64, _empty = _check.NDARRAY, _check.F64, np.empty
_V, _M, _J = (DIM,), (MAT, MAT), (DIM, DIM)

_ROW = "[0, 0, 0, 1/s]"


def _element(X, name="X"):
    arr = _validate.square(X, MAT, name)
    _validate.rotation_block(arr, name, 3)
    _validate.bottom_row(arr, name, _ROW, last_positive=True)
    return arr


def hat(x):
    """(..., 7) → (..., 4, 4): [[ω×, u], [0, −λ]] for x = [ω, u, λ]."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_M)
        if _hat_one(x, out):
            return out
    return _jit.apply(_hat, _validate.tangent(x, DIM), 1, (MAT, MAT))


def vee(X):
    """(..., 4, 4) → (..., 7): [X21, X02, X10, X03, X13, X23, −X33], the inverse of :func:`hat`."""
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_V)
        if _vee_one(X, out):
            return out
    return _jit.apply(_vee, _validate.square(X, MAT), 2, (DIM,))


def exp(x):
    """(..., 7) → (..., 4, 4): [[R, e^{−λ} φ1(Ω + λI) u], [0, e^{−λ}]] = expm(hat x)."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_M)
        if _exp_one(x, out):
            return out
    return _jit.apply(_exp, _validate.tangent(x, DIM), 1, (MAT, MAT))


def log(X):
    """(..., 4, 4) → (..., 7): [Log R, g(Ω + λI) t/X33, −ln X33] with |ω| ≤ π.

    Raises ValueError unless the rotation block is a rotation and the last row is
    [0, 0, 0, 1/s] with 1/s > 0.
    """
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_V)
        if _log_one(X, out):
            return out
    return _jit.apply(_log, _element(X), 2, (DIM,))


def ad(x):
    """(..., 7) → (..., 7, 7): [[Ω, 0, 0], [U, Ω + λI, −u], [0, 0, 0]]."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_J)
        if _ad_one(x, out):
            return out
    return _jit.apply(_ad, _validate.tangent(x, DIM), 1, (DIM, DIM))


def Ad(X):
    """(..., 4, 4) → (..., 7, 7): [[R, 0, 0], [s t× R, s R, −s t], [0, 0, 1]], s = 1/X33.

    X hat(y) X⁻¹ = hat(Ad(X) y); validates like :func:`log`.
    """
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_J)
        if _Ad_one(X, out):
            return out
    return _jit.apply(_Ad, _element(X), 2, (DIM, DIM))


def dexp(x):
    """(..., 7) → (..., 7, 7): left Jacobian φ1(ad_x) = [[J, 0, 0], [Q, W, −φ2(B) u], [0, 0, 1]]."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_J)
        if _dexp_one(x, out):
            return out
    return _jit.apply(_dexp, _validate.tangent(x, DIM), 1, (DIM, DIM))


def dlog(x):
    """(..., 7) → (..., 7, 7): D_exp(x)⁻¹ = g(ad_x) in closed form.

    Singular where φ1(λ + iθ) = 0 or J is, i.e. θ = 2πk (k ≥ 1).
    """
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_J)
        if _dlog_one(x, out):
            return out
    return _jit.apply(_dlog, _validate.tangent(x, DIM), 1, (DIM, DIM))


def compose(X, Y):
    """(..., 4, 4) × (..., 4, 4) → (..., 4, 4): X·Y, batch axes broadcast."""
    if (type(X) is _ND and type(Y) is _ND and X.shape == _M and Y.shape == _M
            and X.dtype is _F64 and Y.dtype is _F64):
        out = _empty(_M)
        if _compose_one(X, Y, out):
            return out
    return _jit.apply2(_compose, _element(X, "X"), _element(Y, "Y"), (2, 2), (MAT, MAT))


def inverse(X):
    """(..., 4, 4) → (..., 4, 4): [[Rᵀ, −Rᵀ t/X33], [0, 1/X33]]."""
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_M)
        if _inverse_one(X, out):
            return out
    return _jit.apply(_inverse, _element(X), 2, (MAT, MAT))
