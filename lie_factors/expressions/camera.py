"""The compiled projections of the vocabulary: the pinhole (a camera-frame point to its normalized
image point) and each calibration's ``uncalibrate`` (a normalized point to pixels), and GTSAM's
stereo camera, each with its local Jacobians (a vector input moves as p + δ; see
:mod:`lie_factors.expressions.kernels`).  Each is GTSAM's formula, term for term, so that values
agree to rounding; the derivations are in docs/factors.md.

Calibrations are held as :data:`lie_factors.expressions.types.CALIBRATIONS` lists them:
Cal3_S2 [fx, fy, s, u0, v0], Cal3Bundler [f, k1, k2, u0, v0] (tangent [f, k1, k2]), Cal3DS2
[fx, fy, s, u0, v0, k1, k2, p1, p2], Cal3Fisheye [fx, fy, s, u0, v0, k1, k2, k3, k4],
Cal3_S2Stereo [fx, fy, s, u0, v0, b].  A projection of a point not in front of the camera
(depth ≤ 0) returns False (GTSAM throws its CheiralityException there).
"""

from __future__ import annotations

import math

import numpy as np

from ..kernels.jit import helper_kernel

#: GTSAM's ``Cal3Fisheye::Scaling``: atan(r)/r at r above this, its series 1 − r²/3 + r⁴/5 below.
FISHEYE_SERIES = 1e-8


@helper_kernel
def pinhole(q, out, Dq, jac):
    """out = (x/z, y/z) of a point in the camera frame (z forward, GTSAM's PinholeCamera);
    Dq = [[1/z, 0, −x/z²], [0, 1/z, −y/z²]].  False where z ≤ 0."""
    z = q[2]
    u = q[0] / z
    v = q[1] / z
    out[0] = u
    out[1] = v
    if jac:
        Dq[0, 0] = 1.0 / z
        Dq[0, 1] = 0.0
        Dq[0, 2] = -u / z
        Dq[1, 0] = 0.0
        Dq[1, 1] = 1.0 / z
        Dq[1, 2] = -v / z
    return z > 0.0


@helper_kernel
def pixel_jacobians(K, d, DK, Dpn, Dd):
    """The last step of every calibration with a skew, pixels (fx·dx + s·dy + u0, fy·dy + v0) of
    the distorted point d = (dx, dy): DK's columns for [fx, fy, s, u0, v0] (the first five) and
    Dpn = [[fx, s], [0, fy]]·Dd, Dd the distortion's Jacobian (2, 2)."""
    for j in range(DK.shape[1]):
        DK[0, j] = 0.0
        DK[1, j] = 0.0
    DK[0, 0] = d[0]
    DK[0, 2] = d[1]
    DK[0, 3] = 1.0
    DK[1, 1] = d[1]
    DK[1, 4] = 1.0
    for j in range(2):
        Dpn[0, j] = K[0] * Dd[0, j] + K[2] * Dd[1, j]
        Dpn[1, j] = K[1] * Dd[1, j]


@helper_kernel
def pixels(K, d, out):
    """out = (fx·dx + s·dy + u0, fy·dy + v0)."""
    out[0] = K[0] * d[0] + K[2] * d[1] + K[3]
    out[1] = K[1] * d[1] + K[4]


@helper_kernel
def uncalibrate_s2(K, pn, out, DK, Dpn, jac):
    """Cal3_S2 K = [fx, fy, s, u0, v0]: out = (fx·u + s·v + u0, fy·v + v0) of pn = (u, v);
    DK = [[u, 0, v, 1, 0], [0, v, 0, 0, 1]], Dpn = [[fx, s], [0, fy]]."""
    u, v = pn[0], pn[1]
    out[0] = K[0] * u + K[2] * v + K[3]
    out[1] = K[1] * v + K[4]
    if jac:
        for j in range(5):
            DK[0, j] = 0.0
            DK[1, j] = 0.0
        DK[0, 0] = u
        DK[0, 2] = v
        DK[0, 3] = 1.0
        DK[1, 1] = v
        DK[1, 4] = 1.0
        Dpn[0, 0] = K[0]
        Dpn[0, 1] = K[2]
        Dpn[1, 0] = 0.0
        Dpn[1, 1] = K[1]


@helper_kernel
def uncalibrate_bundler(K, pn, out, DK, Dpn, jac):
    """Cal3Bundler K = [f, k1, k2, u0, v0] (GTSAM's ``Cal3Bundler::uncalibrate``): out = f·g·pn +
    (u0, v0), g = 1 + k1 r² + k2 r⁴, r² = |pn|²;  DK (tangent [f, k1, k2]) = [g·pn, f·r²·pn,
    f·r⁴·pn], Dpn = f·(g·I + 2(k1 + 2 k2 r²)·pn·pnᵀ)."""
    f, k1, k2 = K[0], K[1], K[2]
    u, v = pn[0], pn[1]
    r2 = u * u + v * v
    g = 1.0 + (k1 + k2 * r2) * r2
    out[0] = K[3] + f * g * u
    out[1] = K[4] + f * g * v
    if jac:
        DK[0, 0] = g * u
        DK[1, 0] = g * v
        DK[0, 1] = f * r2 * u
        DK[1, 1] = f * r2 * v
        DK[0, 2] = f * r2 * r2 * u
        DK[1, 2] = f * r2 * r2 * v
        h = 2.0 * (k1 + 2.0 * k2 * r2)
        Dpn[0, 0] = f * (g + h * u * u)
        Dpn[0, 1] = f * h * u * v
        Dpn[1, 0] = f * h * u * v
        Dpn[1, 1] = f * (g + h * v * v)


@helper_kernel
def uncalibrate_ds2(K, pn, out, DK, Dpn, jac):
    """Cal3DS2 K = [fx, fy, s, u0, v0, k1, k2, p1, p2] (GTSAM's ``Cal3DS2_Base::uncalibrate``):
    the distorted point d = g·pn + t, g = 1 + k1 r² + k2 r⁴, t = (2 p1 xy + p2 (r² + 2x²),
    2 p2 xy + p1 (r² + 2y²)), then pixels.  DK = [∂pixels/∂[fx…v0] | Kₛ·[[x r², x r⁴, 2xy,
    r² + 2x²], [y r², y r⁴, r² + 2y², 2xy]]] and Dpn = Kₛ·∂d/∂pn, Kₛ = [[fx, s], [0, fy]]."""
    k1, k2, p1, p2 = K[5], K[6], K[7], K[8]
    x, y = pn[0], pn[1]
    xy, xx, yy = x * y, x * x, y * y
    rr = xx + yy
    r4 = rr * rr
    g = 1.0 + k1 * rr + k2 * r4
    d = np.empty(2)
    d[0] = g * x + 2.0 * p1 * xy + p2 * (rr + 2.0 * xx)
    d[1] = g * y + 2.0 * p2 * xy + p1 * (rr + 2.0 * yy)
    pixels(K, d, out)
    if not jac:
        return
    dgdx = k1 * 2.0 * x + k2 * 2.0 * rr * 2.0 * x
    dgdy = k1 * 2.0 * y + k2 * 2.0 * rr * 2.0 * y
    Dd = np.empty((2, 2))
    Dd[0, 0] = g + x * dgdx + 2.0 * p1 * y + p2 * (2.0 * x + 4.0 * x)
    Dd[0, 1] = x * dgdy + 2.0 * p1 * x + p2 * 2.0 * y
    Dd[1, 0] = y * dgdx + 2.0 * p2 * y + p1 * 2.0 * x
    Dd[1, 1] = g + y * dgdy + 2.0 * p2 * x + p1 * (2.0 * y + 4.0 * y)
    pixel_jacobians(K, d, DK, Dpn, Dd)
    D2 = np.empty((2, 4))
    D2[0, 0], D2[0, 1], D2[0, 2], D2[0, 3] = x * rr, x * r4, 2.0 * xy, rr + 2.0 * xx
    D2[1, 0], D2[1, 1], D2[1, 2], D2[1, 3] = y * rr, y * r4, rr + 2.0 * yy, 2.0 * xy
    for j in range(4):
        DK[0, 5 + j] = K[0] * D2[0, j] + K[2] * D2[1, j]
        DK[1, 5 + j] = K[1] * D2[1, j]


@helper_kernel
def uncalibrate_fisheye(K, pn, out, DK, Dpn, jac):
    """Cal3Fisheye K = [fx, fy, s, u0, v0, k1, k2, k3, k4] (GTSAM's ``Cal3Fisheye::uncalibrate``,
    the equidistant model): θ = atan(r), r = |pn|, θ_d = θ·(1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸),
    the distorted point d = c·pn with c = θ_d/r = (atan(r)/r)·P(θ) (atan(r)/r by its series
    below :data:`FISHEYE_SERIES`), then pixels.  DK = [∂pixels/∂[fx…v0] | Kₛ·(atan(r)/r)·
    [x θ², x θ⁴, x θ⁶, x θ⁸; y …]]; Dpn = Kₛ·(c·I + (θ_d' − c)·pn·pnᵀ/r²), θ_d' = dθ_d/dr =
    (1 + 3k1 θ² + 5k2 θ⁴ + 7k3 θ⁶ + 9k4 θ⁸)/(1 + r²), and Dpn = Kₛ at r = 0 (where c → 1)."""
    k1, k2, k3, k4 = K[5], K[6], K[7], K[8]
    xi, yi = pn[0], pn[1]
    r2 = xi * xi + yi * yi
    r = math.sqrt(r2)
    t = math.atan2(r, 1.0)
    t2 = t * t
    t4 = t2 * t2
    t6 = t2 * t4
    t8 = t4 * t4
    if r > FISHEYE_SERIES:
        scaling = math.atan(r) / r
    else:
        scaling = 1.0 - r2 / 3.0 + r2 * r2 / 5.0
    c = scaling * (1.0 + k1 * t2 + k2 * t4 + k3 * t6 + k4 * t8)
    d = np.empty(2)
    d[0] = c * xi
    d[1] = c * yi
    pixels(K, d, out)
    if not jac:
        return
    Dd = np.empty((2, 2))
    if r2 == 0.0:
        Dd[0, 0], Dd[0, 1], Dd[1, 0], Dd[1, 1] = 1.0, 0.0, 0.0, 1.0
    else:
        dtd = (1.0 + 3.0 * k1 * t2 + 5.0 * k2 * t4 + 7.0 * k3 * t6 + 9.0 * k4 * t8) / (r2 + 1.0)
        cx, cy = xi / r, yi / r
        Dd[0, 0] = dtd * cx * cx + c * (1.0 - cx * cx)
        Dd[0, 1] = (dtd - c) * cx * cy
        Dd[1, 0] = Dd[0, 1]
        Dd[1, 1] = dtd * cy * cy + c * (1.0 - cy * cy)
    pixel_jacobians(K, d, DK, Dpn, Dd)
    T = np.empty(4)
    T[0], T[1], T[2], T[3] = t2, t4, t6, t8
    for j in range(4):
        DK[0, 5 + j] = scaling * T[j] * (K[0] * xi + K[2] * yi)
        DK[1, 5 + j] = scaling * T[j] * K[1] * yi


@helper_kernel
def stereo(K, q, out, DK, Dq, jac):
    """Cal3_S2Stereo K = [fx, fy, s, u0, v0, b] (GTSAM's ``StereoCamera::project2``, which uses no
    skew): out = (u0 + fx·x/z, u0 + fx·(x − b)/z, v0 + fy·y/z) of the camera-frame point q;
    Dq = [[fx/z, 0, −fx·x/z²], [fx/z, 0, −fx·(x − b)/z²], [0, fy/z, −fy·y/z²]],
    DK = [[x/z, 0, 0, 1, 0, 0], [(x − b)/z, 0, 0, 1, 0, −fx/z], [0, y/z, 0, 0, 1, 0]].
    False where z ≤ 0."""
    fx, fy, u0, v0, b = K[0], K[1], K[3], K[4], K[5]
    x, y, z = q[0], q[1], q[2]
    d = 1.0 / z
    out[0] = u0 + fx * x * d
    out[1] = u0 + fx * (x - b) * d
    out[2] = v0 + fy * y * d
    if jac:
        for i in range(3):
            for j in range(6):
                DK[i, j] = 0.0
        DK[0, 0] = x * d
        DK[0, 3] = 1.0
        DK[1, 0] = (x - b) * d
        DK[1, 3] = 1.0
        DK[1, 5] = -fx * d
        DK[2, 1] = y * d
        DK[2, 4] = 1.0
        Dq[0, 0], Dq[0, 1], Dq[0, 2] = fx * d, 0.0, -fx * x * d * d
        Dq[1, 0], Dq[1, 1], Dq[1, 2] = fx * d, 0.0, -fx * (x - b) * d * d
        Dq[2, 0], Dq[2, 1], Dq[2, 2] = 0.0, fy * d, -fy * y * d * d
    return z > 0.0
