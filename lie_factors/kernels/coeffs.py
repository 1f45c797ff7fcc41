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

from lie_factors.kernels.jit import kernel

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

# Series in t = θ², coefficients exact rationals rounded once (comments).
# a: Σ (−1)^k t^k/(2k+1)!   c: Σ (−1)^k t^k/(2k+3)!
# e: Σ_{n≥1} |B_2n| t^(n−1)/(2n)!  (from (x/2) cot(x/2) = Σ (−1)^n B_2n x^2n/(2n)!)
# qa: Σ_{k≥1} (−1)^k 2k t^(k−1)/(2k+2)!   qb: Σ_{k≥1} (−1)^k 2k t^(k−1)/(2k+3)!
_A_SERIES = (
    1.0,  # 1
    -0.16666666666666666,  # -1/6
    0.008333333333333333,  # 1/120
    -0.0001984126984126984,  # -1/5040
    2.7557319223985893e-06,  # 1/362880
)
_C_SERIES = (
    0.16666666666666666,  # 1/6
    -0.008333333333333333,  # -1/120
    0.0001984126984126984,  # 1/5040
    -2.7557319223985893e-06,  # -1/362880
    2.505210838544172e-08,  # 1/39916800
    -1.6059043836821613e-10,  # -1/6227020800
    7.647163731819816e-13,  # 1/1307674368000
    -2.8114572543455206e-15,  # -1/355687428096000
    8.22063524662433e-18,  # 1/121645100408832000
    -1.9572941063391263e-20,  # -1/51090942171709440000
)
_E_SERIES = (
    0.08333333333333333,  # 1/12
    0.001388888888888889,  # 1/720
    3.306878306878307e-05,  # 1/30240
    8.267195767195768e-07,  # 1/1209600
    2.08767569878681e-08,  # 1/47900160
    5.284190138687493e-10,  # 691/1307674368000
    1.3382536530684679e-11,  # 1/74724249600
    3.3896802963225827e-13,  # 3617/10670622842880000
    8.586062056277845e-15,  # 43867/5109094217170944000
    2.174868698558062e-16,  # 174611/802857662698291200000
    5.5090028283602295e-18,  # 77683/14101100039391805440000
    1.3954464685812522e-19,  # 236364091/1693824136731743669452800000
    3.534707039629467e-21,  # 657931/186134520519971831808000000
    8.953517427037546e-23,  # 3392780147/37893265687455865519472640000000
    2.267952452337683e-24,  # 1723168255201/759790291646040068357842010112000000
    5.744790668872202e-26,  # 7709321041217/134196726836183700385281186201600000000
    1.455172475614865e-27,  # 151628697551/104199811425742637946218332815360000000
    3.6859949406653103e-29,  # 26315271553053477373/713925872841910517552409860896601407488000000000
    9.336734257095045e-31,  # 154210205991661/165165037094716140555791754978970828800000000
    2.36502241570063e-32,  # 261082718496449122051/11039333782344056345696120477635448049500160000000000
)
_QA_SERIES = (
    -0.08333333333333333,  # -1/12
    0.005555555555555556,  # 1/180
    -0.00014880952380952382,  # -1/6720
    2.204585537918871e-06,  # 1/453600
    -2.08767569878681e-08,  # -1/47900160
    1.376489471727567e-10,  # 1/7264857600
    -6.691268265342339e-13,  # -1/1494484992000
    2.499073114973796e-15,  # 1/400148356608000
    -7.398571721961897e-18,  # -1/135161222676480000
    1.7793582784901146e-20,  # 1/56200036388880384000
    -3.54582265641146e-23,  # -1/28202200078783610880000
    5.951031031739514e-26,  # 1/16803810880275234816000000
    -8.527712016381578e-29,  # -1/11726474792758225403904000000
)
_QB_SERIES = (
    -0.016666666666666666,  # -1/60
    0.0007936507936507937,  # 1/1260
    -1.6534391534391536e-05,  # -1/60480
    2.0041686708353376e-07,  # 1/4989600
    -1.6059043836821615e-09,  # -1/622702080
    9.17659647818378e-12,  # 1/108972864000
    -3.936040156083729e-14,  # -1/25406244864000
    1.3153016394598927e-16,  # 1/7602818775552000
    -3.523129391410427e-19,  # -1/2838385676206080000
    7.736340341261368e-22,  # 1/1292600836944248832000
    -1.4183290625645841e-24,  # -1/705055001969590272000000
    2.204085567310931e-27,  # 1/453702893767431340032000000
    -2.9405903504764064e-30,  # -1/340067768989988536713216000000
    3.4051501163498504e-33,  # 1/293672809077782957775912960000000
)

# Series in t = θ² for e_θ and f_θ = e_θ'/θ on [0, π] (ratio of terms → (θ/2π)² ≤ 1/4),
# padded with zeros to a multiple of 4 for the 4-way Horner.
_EF_E_SERIES = (
    0.08333333333333333,
    0.001388888888888889,
    3.306878306878307e-05,
    8.267195767195768e-07,
    2.08767569878681e-08,
    5.284190138687493e-10,
    1.3382536530684679e-11,
    3.3896802963225827e-13,
    8.586062056277845e-15,
    2.174868698558062e-16,
    5.5090028283602295e-18,
    1.3954464685812522e-19,
    3.534707039629467e-21,
    8.953517427037546e-23,
    2.267952452337683e-24,
    5.744790668872202e-26,
    1.455172475614865e-27,
    3.6859949406653103e-29,
    9.336734257095045e-31,
    2.36502241570063e-32,
    5.990671762482134e-34,
    1.5174548844682903e-35,
    3.843758125454189e-37,
    9.736353072646691e-39,
    2.466247044200681e-40,
    6.247076741820743e-42,
    1.5824030244644914e-43,
    4.008273685948936e-45,
    1.0153075855569557e-46,
    2.5718041582418717e-48,
    6.514456035233815e-50,
    1.6501309906896525e-51,
    4.179830628539476e-53,
    1.058763466770291e-54,
    2.6818791912607708e-56,
    6.793279351107421e-58,
)
_EF_F_SERIES = (
    0.002777777777777778,
    0.00013227513227513228,
    4.96031746031746e-06,
    1.670140559029448e-07,
    5.2841901386874934e-09,
    1.6059043836821613e-10,
    4.745552414851616e-12,
    1.3737699290044552e-13,
    3.914763657404511e-15,
    1.1018005656720459e-16,
    3.069982230878755e-18,
    8.483296895110721e-20,
    2.327914531029762e-21,
    6.350266866545513e-23,
    1.7234372006616606e-24,
    4.656551921967568e-26,
    1.2532382798262054e-27,
    3.3612243325542163e-29,
    8.987085179662393e-31,
    2.3962687049928537e-32,
    6.373310514766819e-34,
    1.6912535751998429e-35,
    4.478722413417478e-37,
    1.183798581216327e-38,
    3.1235383709103717e-40,
    8.228495727215355e-42,
    2.1644677904124254e-43,
    5.685722479118952e-45,
    1.4916464117802855e-46,
    3.908673621140289e-48,
    1.0230812142275845e-49,
    2.6750916022652644e-51,
    6.98783888068392e-53,
    1.823677850057324e-54,
    4.755295545775195e-56,
    1.2389455884010612e-57,
)


@kernel
def _horner(coeffs, t):
    p = 0.0
    for i in range(len(coeffs) - 1, -1, -1):
        p = p * t + coeffs[i]
    return p


@kernel
def _horner4(coeffs, t):
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


@kernel
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


@kernel
def a_theta(theta):
    """a_θ = sin θ/θ, Eade Eq. (50)."""
    if theta < A_TAYLOR:
        return _horner(_A_SERIES, theta * theta)
    return math.sin(theta) / theta


@kernel
def b_theta(theta):
    """b_θ = (1 − cos θ)/θ² = ½ (sin(θ/2)/(θ/2))², Eade Eq. (51).

    The half-angle form has no cancellation at any θ.
    """
    h = a_theta(0.5 * theta)
    return 0.5 * h * h


@kernel
def c_theta(theta):
    """c_θ = (1 − a_θ)/θ² = (θ − sin θ)/θ³, Eade Eq. (52)."""
    if theta < C_TAYLOR:
        return _horner(_C_SERIES, theta * theta)
    return (theta - math.sin(theta)) / (theta * theta * theta)


@kernel
def e_theta(theta):
    """e_θ, the ω×² coefficient of D_exp⁻¹ (Eade Eqs. 55–57), valid for θ < 2π.

    Closed form 1/θ² − cos(θ/2)/(2θ sin(θ/2)) (= Eq. 57 with 1 − cos θ =
    2 sin²(θ/2)); unlike Eq. (56) it has no 0/0 at θ = π where a_θ = 0.
    """
    if theta < E_TAYLOR:
        return _horner(_E_SERIES, theta * theta)
    h = 0.5 * theta
    return 1.0 / (theta * theta) - math.cos(h) / (2.0 * theta * math.sin(h))


_TWO_PI_HI = 6.283185307179586
_TWO_PI_LO = 2.4492935982947064e-16
_SPLIT = 134217729.0  # 2^27 + 1, Dekker's splitter


@kernel
def _two_prod(a, b):
    p = a * b
    t = _SPLIT * a
    ah = t - (t - a)
    al = a - ah
    t = _SPLIT * b
    bh = t - (t - b)
    bl = b - bh
    return p, ((ah * bh - p) + ah * bl + al * bh) + al * bl


@kernel
def _two_sum(a, b):
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


@kernel
def dot3(x0, x1, x2, y0, y1, y2):
    """x·y with a compensated sum (Ogita–Rump–Oishi Dot2): as accurate as if
    computed in twice the working precision, then rounded. Needed where ωᵀv
    multiplies (2π/(2π − θ))² in SE(3) D_exp⁻¹."""
    s, e = _two_prod(x0, y0)
    p, f = _two_prod(x1, y1)
    s, g = _two_sum(s, p)
    e += f + g
    p, f = _two_prod(x2, y2)
    s, g = _two_sum(s, p)
    e += f + g
    return s + e


@kernel
def theta_dd(w0, w1, w2):
    """|ω| as an unevaluated sum hi + lo accurate to ~1e-32 relative (|ω| ≥ ~1e-140)."""
    s, e = _two_prod(w0, w0)
    p, f = _two_prod(w1, w1)
    s, g = _two_sum(s, p)
    e += f + g
    p, f = _two_prod(w2, w2)
    s, g = _two_sum(s, p)
    e += f + g
    r = math.sqrt(s)
    rr, rl = _two_prod(r, r)
    lo = ((s - rr) - rl + e) / (2.0 * r)
    return r + lo, lo - ((r + lo) - r)


@kernel
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


@kernel
def ef_omega(w0, w1, w2):
    """(θ, e_θ, f_θ) for θ = |ω| < 2π, with f_θ = e_θ'/θ (derivative of Eq. 57's e_θ).

    f_θ = −2/θ⁴ + cot(θ/2)/(2θ³) + 1/(4θ² sin²(θ/2)); series Σ 2n e_n θ^(2n−2).
    One branch (EF_TAYLOR = π): series below, reflected closed forms above.
    """
    th = norm3(w0, w1, w2)
    if th <= EF_TAYLOR:
        t = th * th
        return th, _horner4(_EF_E_SERIES, t), _horner4(_EF_F_SERIES, t)
    hi, lo = theta_dd(w0, w1, w2)
    d = 0.5 * ((_TWO_PI_HI - hi) + (_TWO_PI_LO - lo))
    s = math.sin(d)
    cot = math.cos(d) / s  # = −cot(θ/2)
    t2 = hi * hi
    e = 1.0 / t2 + cot / (2.0 * hi)
    f = -2.0 / (t2 * t2) - cot / (2.0 * t2 * hi) + 1.0 / (4.0 * t2 * s * s)
    return hi, e, f


@kernel
def qa_theta(theta):
    """(a_θ − 2 b_θ)/θ², the ω× coefficient of Q(ω), Eade Eq. (64)."""
    if theta < QA_TAYLOR:
        return _horner(_QA_SERIES, theta * theta)
    return (a_theta(theta) - 2.0 * b_theta(theta)) / (theta * theta)


@kernel
def qb_theta(theta):
    """(b_θ − 3 c_θ)/θ², the ω×² coefficient of Q(ω), Eade Eq. (64)."""
    if theta < QB_TAYLOR:
        return _horner(_QB_SERIES, theta * theta)
    return (b_theta(theta) - 3.0 * c_theta(theta)) / (theta * theta)
