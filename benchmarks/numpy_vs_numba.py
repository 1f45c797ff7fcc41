"""Is numba worth its fixed start-up on a small graph?

    python benchmarks/numpy_vs_numba.py [DATASET.g2o]   (default sphere2500, SE(3), 4 949 edges)

The alternative to numba: numpy-vectorized batch kernels, no JIT.  Measured
here on the work one LM iteration repeats most, the linearization of every
Between factor (error e = Log(M⁻¹·X1⁻¹·X2), both Jacobians, whitening):

* numba: ``lie_factors.batch.loops`` ``_between_lin`` (the library's kernel), warm;
* numpy: the same quantities with numpy stacks — Log and the inverse right
  Jacobian of SE(3) from ``lie_factors.initialization.relaxation`` (numpy, written for the
  initializer), H2 = J_r⁻¹(e), H1 = −J_r⁻¹(e)·Ad(X2⁻¹X1) (GTSAM's ``between``
  Jacobians, equal to the kernel's: the script prints how closely), then R·H and R·e;

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


def best(f, n=5):
    out = []
    for _ in range(n):
        t = time.perf_counter()
        f()
        out.append(time.perf_counter() - t)
    return min(out)


def main():
    path = sys.argv[1] if len(sys.argv) > 1 else os.path.join(DATA, "sphere2500.g2o")
    from lie_factors.app import run as P
    from lie_factors.initialization import relaxation as rx
    from lie_factors.batch import Problem

    pg = P.load(path)
    a = pg.arrays
    assert a.group == "Pose3"
    prior = (pg.first_key, P._first_element(pg), P.prior_noise(True).R())
    prob = Problem.from_arrays("Pose3", a.keys, a.vertices, a.edge_keys, a.measured, a.information, [prior])
    g = next(g for g in prob.groups if g.kind == "between")
    X = prob.blocks["Pose3"].X
    t_numba = best(lambda: g.linearize(X))

    Minv, R, i1, i2 = g.C, g.R, g.i1, g.i2

    def numpy_lin():
        X1inv = np.linalg.inv(X[i1])
        E = Minv @ X1inv @ X[i2]
        e = rx._pose3_log(E[:, :3, :3], E[:, :3, 3])
        Jr = rx._pose3_logmap_derivative(e)
        D = np.linalg.inv(X[i2]) @ X[i1]  # X1 → X1·Exp(δ): E → E·Exp(−Ad(X2⁻¹X1) δ)
        Ad = np.zeros((len(E), 6, 6))  # Ad(D) = [[R, 0], [t× R, R]] in [ω, v]
        Ad[:, :3, :3] = Ad[:, 3:, 3:] = D[:, :3, :3]
        Ad[:, 3:, :3] = rx._skew(D[:, :3, 3]) @ D[:, :3, :3]
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
        ee = rx._pose3_log(E[:, :3, :3], E[:, :3, 3])
        return rx._pose3_logmap_derivative(ee)

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
