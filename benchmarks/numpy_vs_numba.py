"""Is numba worth its fixed start-up on a small graph?

    python benchmarks/numpy_vs_numba.py [DATASET.g2o]   (default sphere2500, SE(3), 4 949 edges)

The alternative to numba: numpy-vectorized batch kernels, no JIT.  Measured
here on the work one LM iteration repeats most, the linearization of every
Between factor (error e = Log(M⁻¹·X1⁻¹·X2), both Jacobians, whitening):

* numba: ``lie_factors.batch.loops`` ``_factor_range`` (the library's kernel), warm;
* numpy: the same quantities with numpy stacks — Log and the inverse right
  Jacobian of SE(3) written in numpy below (the closed forms GTSAM uses),
  H2 = J_r⁻¹(e), H1 = −J_r⁻¹(e)·Ad(X2⁻¹X1) (GTSAM's ``between`` Jacobians, equal
  to the kernel's: the script prints how closely), then R·H and R·e;

and numba's fixed costs in a fresh process: ``import numba``, the first cached
kernel load (numba's registries), every further kernel the default command
loads.  Best of 5 for the warm timings.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
DATA = os.environ.get("LIE_FACTORS_DATA", os.path.join(ROOT, "data"))

FRESH = r"""
import time, sys
t0 = time.perf_counter(); import numba; t1 = time.perf_counter()
import numpy as np
from lie_factors import factors
from lie_factors.kernels import dispatch as _dispatch
from lie_factors.batch import loops
t2 = time.perf_counter()
M = np.eye(4)[None].repeat(2, 0)
loops.GroupLoops(factors.GROUPS["Pose3"]).setup(M)           # first cached kernel
t3 = time.perf_counter()
print(f"{t1 - t0:.3f} {t2 - t1:.3f} {t3 - t2:.3f}")
"""


# --------------------------------------------------------------------------- #
# The numpy side: SE(3) Log and its inverse right Jacobian on stacks
# --------------------------------------------------------------------------- #

def _skew(w: np.ndarray) -> np.ndarray:
    W = np.zeros(w.shape[:-1] + (3, 3))
    W[..., 0, 1], W[..., 0, 2], W[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    W[..., 1, 0], W[..., 2, 0], W[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    return W


def _rot_log(R: np.ndarray) -> np.ndarray:
    """(K, 3, 3) → (K, 3): ω with Exp(ω) = R, |ω| ≤ π.

    θ = atan2(|s|, c) with s = vee(R − Rᵀ)/2 = sin θ·a and c = (tr R − 1)/2;
    ω = θ/sin θ · s while c ≥ 0; for c < 0 (θ > π/2) the axis from the
    symmetric part (R + Rᵀ)/2 − c I = (1 − c) a aᵀ, its sign from s, since s
    loses the axis near π.
    """
    s = 0.5 * np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    c = 0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0)
    sn = np.linalg.norm(s, axis=1)
    th = np.arctan2(sn, c)
    out = np.empty_like(s)
    small = sn < 1e-8  # θ/sin θ = 1 + θ²/6 to double precision below here
    f = np.where(small, 1.0 + th * th / 6.0, th / np.where(sn > 0, sn, 1.0))
    out[:] = f[:, None] * s
    big = c < 0.0
    if np.any(big):
        Rb, cb, sb, tb = R[big], c[big], s[big], th[big]
        S = 0.5 * (Rb + np.swapaxes(Rb, 1, 2)) - cb[:, None, None] * np.eye(3)
        S /= (1.0 - cb)[:, None, None]  # = a aᵀ
        k = np.argmax(np.diagonal(S, axis1=1, axis2=2), axis=1)
        rows = np.arange(k.size)
        col = S[rows, :, k]  # a a_k
        a = col / np.sqrt(col[rows, k])[:, None]
        sign = np.where(np.einsum("ki,ki->k", a, sb) < 0.0, -1.0, 1.0)
        out[big] = (sign * tb)[:, None] * a
    return out


def _pose3_log(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Log of (R, t) stacks (K, 3, 3), (K, 3) → (K, 6) [ω, v] with v = V(ω)⁻¹ t.

    V⁻¹ = I − ½ W + (1 − (θ/2) cot(θ/2))/θ² · W², W = ω× (series below θ = 1e-2).
    """
    w = _rot_log(R)
    th = np.linalg.norm(w, axis=1)
    small = th < 1e-2
    ts = np.where(small, 1.0, th)
    t2 = th * th
    half = 0.5 * ts
    d = np.where(small, 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0,
                 (1.0 - half * np.cos(half) / np.sin(half)) / (ts * ts))
    wt = np.cross(w, t)
    v = t - 0.5 * wt + d[:, None] * np.cross(w, wt)
    return np.concatenate([w, v], axis=1)


def _pose3_logmap_derivative(x: np.ndarray) -> np.ndarray:
    """GTSAM's ``Pose3::LogmapDerivative`` for stacks x (K, 6) [ω, v] → (K, 6, 6): the inverse right Jacobian.

    J_r(x)⁻¹ = [[J⁻¹, 0], [−J⁻¹ Q J⁻¹, J⁻¹]] with J⁻¹ = I + ½ W + d W² (W = ω×,
    d as in :func:`_pose3_log`) the inverse right Jacobian of SO(3) and
    Q = Q_l(−ω, −v), Q_l the lower-left block of SE(3)'s left Jacobian
    (Barfoot, State Estimation for Robotics, Eq. 7.86; ours is [ω, v] ordered):
    Q_l = ½ V + a (W V + V W + W V W) + b (W² V + V W² − 3 W V W)
          + c (W V W² + W² V W),  V = v×,
    a = (θ − sin θ)/θ³, b = (θ² + 2 cos θ − 2)/(2θ⁴), c = (2θ − 3 sin θ + θ cos θ)/(2θ⁵)
    (series below θ = 0.1).
    """
    w, v = -x[:, :3], -x[:, 3:]
    th = np.linalg.norm(w, axis=1)
    t2 = th * th
    small = th < 0.1
    ts = np.where(small, 1.0, th)
    sn, cs = np.sin(ts), np.cos(ts)
    a = np.where(small, 1 / 6 - t2 / 120 + t2 ** 2 / 5040 - t2 ** 3 / 362880, (ts - sn) / ts ** 3)
    b = np.where(small, 1 / 24 - t2 / 720 + t2 ** 2 / 40320 - t2 ** 3 / 3628800,
                 (ts * ts + 2 * cs - 2) / (2 * ts ** 4))
    c = np.where(small, 1 / 120 - t2 / 2520 + t2 ** 2 / 120960 - t2 ** 3 / 9979200,
                 (2 * ts - 3 * sn + ts * cs) / (2 * ts ** 5))
    W, Vx = _skew(w), _skew(v)
    W2 = W @ W
    WV, VW, WVW = W @ Vx, Vx @ W, W @ Vx @ W
    Q = (0.5 * Vx + a[:, None, None] * (WV + VW + WVW)
         + b[:, None, None] * (W @ WV + VW @ W - 3 * WVW)
         + c[:, None, None] * (WVW @ W + W @ WVW))
    th_r = np.linalg.norm(x[:, :3], axis=1)
    half = 0.5 * np.where(th_r < 1e-2, 1.0, th_r)
    d = np.where(th_r < 1e-2, 1 / 12 + th_r ** 2 / 720 + th_r ** 4 / 30240,
                 (1 - half * np.cos(half) / np.sin(half)) / (4 * half * half))
    Wr = _skew(x[:, :3])
    Jinv = np.eye(3) + 0.5 * Wr + d[:, None, None] * (Wr @ Wr)
    out = np.zeros((x.shape[0], 6, 6))
    out[:, :3, :3] = out[:, 3:, 3:] = Jinv
    out[:, 3:, :3] = -Jinv @ Q @ Jinv
    return out


def best(f, n=5):
    out = []
    for _ in range(n):
        t = time.perf_counter()
        f()
        out.append(time.perf_counter() - t)
    return min(out)


def main():
    path = sys.argv[1] if len(sys.argv) > 1 else os.path.join(DATA, "sphere2500.g2o")
    from lie_factors.g2o import read_pose_graph
    from lie_factors.batch import Problem

    pg = read_pose_graph(path)
    assert pg.group == "Pose3"
    prob = Problem.from_pose_graph(pg.with_first_prior(), pg.start_poses)
    g = next(g for g in prob.groups if g.kind == "between")
    X = prob.blocks["Pose3"].X
    t_numba = best(lambda: g.linearize(X))

    Minv, R, i1, i2 = g.C, g.R, g.i1, g.i2

    def numpy_lin():
        X1inv = np.linalg.inv(X[i1])
        E = Minv @ X1inv @ X[i2]
        e = _pose3_log(E[:, :3, :3], E[:, :3, 3])
        Jr = _pose3_logmap_derivative(e)
        D = np.linalg.inv(X[i2]) @ X[i1]  # X1 → X1·Exp(δ): E → E·Exp(−Ad(X2⁻¹X1) δ)
        Ad = np.zeros((len(E), 6, 6))  # Ad(D) = [[R, 0], [t× R, R]] in [ω, v]
        Ad[:, :3, :3] = Ad[:, 3:, 3:] = D[:, :3, :3]
        Ad[:, 3:, :3] = _skew(D[:, :3, 3]) @ D[:, :3, :3]
        A1 = R @ (-Jr @ Ad)
        A2 = R @ Jr
        b = np.einsum("kab,kb->ka", R, e)
        return A1, A2, b, e

    t_numpy = best(numpy_lin)
    A1, A2, b, e = numpy_lin()
    g.linearize(X)
    agree = max(float(np.abs(A2 - g.A2).max() / np.abs(g.A2).max()), float(np.abs(A1 - g.A1).max() / np.abs(g.A1).max()))
    # The scalar path (a GTSAM CustomFactor callback evaluates one factor): one element each.
    from lie_factors.kernels import dispatch as _dispatch
    from lie_factors import factors
    one = (Minv[:1], X[i1[:1]], X[i2[:1]], R[:1])

    def numpy_one():
        E = one[0] @ np.linalg.inv(one[1]) @ one[2]
        ee = _pose3_log(E[:, :3, :3], E[:, :3, 3])
        return _pose3_logmap_derivative(ee)

    I4 = np.asfortranarray(X[i1[0]])
    J4 = np.asfortranarray(X[i2[0]])
    out = (np.empty(6), np.empty((6, 6)), np.empty((6, 6)))
    factors.between(_dispatch.SE3, Minv[0], g.Ad[0], I4, J4, *out)
    t_np1 = best(lambda: [numpy_one() for _ in range(200)]) / 200
    t_nb1 = best(lambda: [factors.between(_dispatch.SE3, Minv[0], g.Ad[0], I4, J4, *out)
                          for _ in range(2000)]) / 2000
    env = dict(os.environ, PYTHONPATH=ROOT)
    fresh = [subprocess.run([sys.executable, "-c", FRESH], capture_output=True, text=True, env=env,
                            check=True).stdout.split() for _ in range(3)]
    imp, mods, first = (min(float(f[k]) for f in fresh) for k in range(3))
    with open("/proc/loadavg") as fh:
        load = " ".join(fh.read().split()[:3])
    E = len(i1)
    print(f"{os.path.basename(path)}: {E} Between factors, load {load}")
    print(f"  linearize, numba (warm):  {t_numba * 1e3:7.2f} ms  ({t_numba / E * 1e6:.2f} µs/factor)")
    print(f"  linearize, numpy:         {t_numpy * 1e3:7.2f} ms  ({t_numpy / E * 1e6:.2f} µs/factor, "
          f"{t_numpy / t_numba:.1f}× numba; Jacobians agree to {agree:.1e})")
    print(f"  one factor (scalar path): numba factors.between {t_nb1 * 1e6:.1f} µs, "
          f"numpy (Log + J_r⁻¹ only) {t_np1 * 1e6:.1f} µs")
    print(f"  numba fixed, fresh process (best of 3): import numba {imp:.3f} s, lie_factors kernels' "
          f"modules {mods:.3f} s, first cached kernel {first:.3f} s")


if __name__ == "__main__":
    main()
