"""Scalar coefficients of the rotation-type closed forms (SO(3), SE(3), quaternions).

Each coefficient is a function of the rotation angle θ ≥ 0 with a Taylor band:
below its named threshold it is summed as a polynomial in θ² (Horner), above it
the closed form is used. The thresholds are placed where the closed form's
cancellation error has fallen below ~1e-15 relative (measured against mpmath at
40 digits), and the series carry enough terms that the first omitted term is
< 1e-17 relative at the threshold. Inside the Taylor band θ² may underflow to
0 (θ = 1e-200): nothing there divides by θ.

Notation follows Eade, "Derivative of the Exponential Map", §5.1–5.2:

    a_θ = sin θ / θ                       (Eq. 50)
    b_θ = (1 − cos θ) / θ²                (Eq. 51)
    c_θ = (1 − a_θ) / θ²                  (Eq. 52)
    e_θ = (b_θ − a_θ/2) / (1 − cos θ)     (Eq. 57; = 1/θ² − cot(θ/2)/(2θ))
    qa_θ = (a_θ − 2 b_θ) / θ²             (Eq. 64, coefficient of ω×)
    qb_θ = (b_θ − 3 c_θ) / θ²             (Eq. 64, coefficient of ω×²)
"""

from __future__ import annotations

import math
from fractions import Fraction

from lie_factors.kernels.jit import helper_kernel

#: a_θ: sin θ / θ has no cancellation; the band only avoids 0/0 at θ = 0.
A_TAYLOR = 1e-3
#: c_θ: (θ − sin θ)/θ³ loses ~6ε/θ² relative; 0.8 keeps it below 8e-16.
C_TAYLOR = 0.8
#: e_θ: 1/θ² − cot(θ/2)/(2θ) loses ~12ε/θ²; 2.0 keeps it below 7e-16.
E_TAYLOR = 2.0
#: e_θ for θ above this (up to 2π): sin(θ/2) → 0 as θ → 2π, so the rounding of
#: θ = |ω| (~ε·2π) is amplified by 1/(2π − θ); there θ and 2π − θ are formed in
#: double-double from the components of ω (e_omega).
E_REFLECT = math.pi
#: e_θ and f_θ = e_θ'/θ together (SE(3) D_exp⁻¹): Taylor series on all of [0, π]
#: (the closed form of f_θ = −2/θ⁴ + cot(θ/2)/(2θ³) + 1/(4θ² sin²(θ/2)) loses
#: 720ε/θ⁴ and is only ~2e-15 accurate even at θ = 3), reflected closed forms
#: with double-double δ = 2π − θ above.
EF_TAYLOR = math.pi
#: qa_θ = (a − 2b)/θ²: loses ~12ε/θ²; 2.0 keeps it below 9e-16.
QA_TAYLOR = 2.0
#: qb_θ = (b − 3c)/θ²: loses ~60ε/θ²; 2.5 keeps it below 1.6e-15.
QB_TAYLOR = 2.5

def rounded(terms) -> tuple:
    """Exact rationals (``fractions.Fraction``) → the nearest floats, as a tuple (a constant
    of the kernels that read it)."""
    return tuple(float(t) for t in terms)


def _abs_bernoulli_over_factorial(n: int) -> list:
    """|B_2k|/(2k)! for k = 0 … n − 1, exactly: the coefficients of (x/2) cot(x/2) =
    Σ (−1)^k B_2k x^2k/(2k)!, from Σ_{j=0}^{m} C(m + 1, j) B_j = 0 (B_1 = −1/2, B_odd>1 = 0)."""
    B = [Fraction(1)]
    for m in range(1, n):
        s = sum(math.comb(2 * m + 1, 2 * j) * B[j] for j in range(m)) - Fraction(2 * m + 1, 2)
        B.append(-s / (2 * m + 1))
    return [abs(b) / math.factorial(2 * k) for k, b in enumerate(B)]


# Series in t = θ², from exact rationals rounded once:
# a: Σ (−1)^k t^k/(2k+1)!   c: Σ (−1)^k t^k/(2k+3)!   e: Σ_{n≥1} |B_2n| t^(n−1)/(2n)!
# qa: Σ_{k≥1} (−1)^k 2k t^(k−1)/(2k+2)!   qb: Σ_{k≥1} (−1)^k 2k t^(k−1)/(2k+3)!
A_SERIES = rounded(Fraction((-1) ** k, math.factorial(2 * k + 1)) for k in range(5))
C_SERIES = rounded(Fraction((-1) ** k, math.factorial(2 * k + 3)) for k in range(10))
E_COEFFS = _abs_bernoulli_over_factorial(38)
E_SERIES = rounded(E_COEFFS[1:21])
QA_SERIES = rounded(Fraction((-1) ** k * 2 * k, math.factorial(2 * k + 2)) for k in range(1, 14))
QB_SERIES = rounded(Fraction((-1) ** k * 2 * k, math.factorial(2 * k + 3)) for k in range(1, 15))
# e_θ and f_θ = e_θ'/θ on [0, π] (ratio of terms → (θ/2π)² ≤ 1/4), 36 terms each (a
# multiple of 4, for the 4-way Horner): f_θ = Σ_{n≥1} 2n e_(n+1) t^(n−1).
EF_E_SERIES = rounded(E_COEFFS[1:37])
EF_F_SERIES = rounded(2 * n * E_COEFFS[n + 1] for n in range(1, 37))


@helper_kernel
def horner(coeffs, t):
    p = 0.0
    for i in range(len(coeffs) - 1, -1, -1):
        p = p * t + coeffs[i]
    return p


@helper_kernel
def horner4(coeffs, t):
    """Σ coeffs[i] tⁱ as four interleaved Horner chains in t⁴ (len(coeffs) % 4 == 0).

    Same rounding behaviour as Horner for these positive series, a quarter of the
    dependency-chain latency."""
    t2 = t * t
    t4 = t2 * t2
    p0 = 0.0
    p1 = 0.0
    p2 = 0.0
    p3 = 0.0
    for j in range(len(coeffs) // 4 - 1, -1, -1):
        p0 = p0 * t4 + coeffs[4 * j]
        p1 = p1 * t4 + coeffs[4 * j + 1]
        p2 = p2 * t4 + coeffs[4 * j + 2]
        p3 = p3 * t4 + coeffs[4 * j + 3]
    return p0 + t * p1 + t2 * (p2 + t * p3)


@helper_kernel
def norm3(x, y, z):
    """|(x, y, z)| without underflow of the squares (θ = 1e-200 stays 1e-200)."""
    s = x * x + y * y + z * z
    if s > 1e-280 and s < 1e280:
        return math.sqrt(s)
    m = max(abs(x), abs(y), abs(z))
    if m == 0.0:
        return 0.0
    x /= m
    y /= m
    z /= m
    return m * math.sqrt(x * x + y * y + z * z)


@helper_kernel
def a_theta(theta):
    """a_θ = sin θ/θ, Eade Eq. (50)."""
    if theta < A_TAYLOR:
        return horner(A_SERIES, theta * theta)
    return math.sin(theta) / theta


@helper_kernel
def b_theta(theta):
    """b_θ = (1 − cos θ)/θ² = ½ (sin(θ/2)/(θ/2))², Eade Eq. (51).

    The half-angle form has no cancellation at any θ.
    """
    h = a_theta(0.5 * theta)
    return 0.5 * h * h


@helper_kernel
def c_theta(theta):
    """c_θ = (1 − a_θ)/θ² = (θ − sin θ)/θ³, Eade Eq. (52)."""
    if theta < C_TAYLOR:
        return horner(C_SERIES, theta * theta)
    return (theta - math.sin(theta)) / (theta * theta * theta)


@helper_kernel
def e_theta(theta):
    """e_θ, the ω×² coefficient of D_exp⁻¹ (Eade Eqs. 55–57), valid for θ < 2π.

    Closed form 1/θ² − cos(θ/2)/(2θ sin(θ/2)) (= Eq. 57 with 1 − cos θ =
    2 sin²(θ/2)); unlike Eq. (56) it has no 0/0 at θ = π where a_θ = 0.
    """
    if theta < E_TAYLOR:
        return horner(E_SERIES, theta * theta)
    h = 0.5 * theta
    return 1.0 / (theta * theta) - math.cos(h) / (2.0 * theta * math.sin(h))


_TWO_PI_HI = 6.283185307179586
_TWO_PI_LO = 2.4492935982947064e-16
_SPLIT = 134217729.0  # 2^27 + 1, Dekker's splitter


@helper_kernel
def _two_prod(a, b):
    p = a * b
    t = _SPLIT * a
    ah = t - (t - a)
    al = a - ah
    t = _SPLIT * b
    bh = t - (t - b)
    bl = b - bh
    return p, ((ah * bh - p) + ah * bl + al * bh) + al * bl


@helper_kernel
def _two_sum(a, b):
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


@helper_kernel
def _dot2(x0, x1, x2, y0, y1, y2):
    """x·y as an unevaluated sum s + e (Ogita–Rump–Oishi Dot2): as accurate as if computed in
    twice the working precision."""
    s, e = _two_prod(x0, y0)
    p, f = _two_prod(x1, y1)
    s, g = _two_sum(s, p)
    e += f + g
    p, f = _two_prod(x2, y2)
    s, g = _two_sum(s, p)
    e += f + g
    return s, e


@helper_kernel
def dot3(x0, x1, x2, y0, y1, y2):
    """x·y with a compensated sum (:func:`_dot2`), then rounded. Needed where ωᵀv
    multiplies (2π/(2π − θ))² in SE(3) D_exp⁻¹."""
    s, e = _dot2(x0, x1, x2, y0, y1, y2)
    return s + e


@helper_kernel
def theta_dd(w0, w1, w2):
    """|ω| as an unevaluated sum hi + lo accurate to ~1e-32 relative (|ω| ≥ ~1e-140)."""
    s, e = _dot2(w0, w1, w2, w0, w1, w2)
    r = math.sqrt(s)
    rr, rl = _two_prod(r, r)
    lo = ((s - rr) - rl + e) / (2.0 * r)
    return r + lo, lo - ((r + lo) - r)


@helper_kernel
def e_omega(w0, w1, w2):
    """e_θ for θ = |ω| < 2π, accurate also as θ → 2π (see E_REFLECT).

    With δ = 2π − θ: cos(θ/2)/sin(θ/2) = −cos(δ/2)/sin(δ/2), so
    e_θ = 1/θ² + cos(δ/2)/(2θ sin(δ/2)) with δ from the double-double θ.
    """
    th = norm3(w0, w1, w2)
    if th <= E_REFLECT:
        return e_theta(th)
    hi, lo = theta_dd(w0, w1, w2)
    d = 0.5 * ((_TWO_PI_HI - hi) + (_TWO_PI_LO - lo))
    return 1.0 / (hi * hi) + math.cos(d) / (2.0 * hi * math.sin(d))


@helper_kernel
def ef_omega(w0, w1, w2):
    """(θ, e_θ, f_θ) for θ = |ω| < 2π, with f_θ = e_θ'/θ (derivative of Eq. 57's e_θ).

    f_θ = −2/θ⁴ + cot(θ/2)/(2θ³) + 1/(4θ² sin²(θ/2)); series Σ 2n e_n θ^(2n−2).
    One branch (EF_TAYLOR = π): series below, reflected closed forms above.
    """
    th = norm3(w0, w1, w2)
    if th <= EF_TAYLOR:
        t = th * th
        return th, horner4(EF_E_SERIES, t), horner4(EF_F_SERIES, t)
    hi, lo = theta_dd(w0, w1, w2)
    d = 0.5 * ((_TWO_PI_HI - hi) + (_TWO_PI_LO - lo))
    s = math.sin(d)
    cot = math.cos(d) / s  # = −cot(θ/2)
    t2 = hi * hi
    e = 1.0 / t2 + cot / (2.0 * hi)
    f = -2.0 / (t2 * t2) - cot / (2.0 * t2 * hi) + 1.0 / (4.0 * t2 * s * s)
    return hi, e, f


@helper_kernel
def qa_theta(theta):
    """(a_θ − 2 b_θ)/θ², the ω× coefficient of Q(ω), Eade Eq. (64)."""
    if theta < QA_TAYLOR:
        return horner(QA_SERIES, theta * theta)
    return (a_theta(theta) - 2.0 * b_theta(theta)) / (theta * theta)


@helper_kernel
def qb_theta(theta):
    """(b_θ − 3 c_θ)/θ², the ω×² coefficient of Q(ω), Eade Eq. (64)."""
    if theta < QB_TAYLOR:
        return horner(QB_SERIES, theta * theta)
    return (b_theta(theta) - 3.0 * c_theta(theta)) / (theta * theta)
