"""Sim(3) kernels against their SE(3) counterparts, batched.

    python benchmarks/sim3_vs_se3.py [N] [REPEATS]

For each of exp, log, dexp, dlog: the public batched call on N elements (default 200 000),
sim3 and se3 alternated, best of REPEATS (default 5) each; prints the times and the ratio
sim3/se3. Three input sets: x ~ N(0, 1) per component (θ ≈ 1.6, |λ| ≈ 0.8: the spectral and
closed-form branches), 0.1·N(0, 1) (between-pose increments: mostly the z series band) and
0.02·N(0, 1). The tangent vectors are the same for both groups (se3 takes the first 6
components; the SE(3) translation is sim3's u).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from lie_factors import se3, sim3


def _best(f, arg, repeats):
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        f(arg)
        best = min(best, time.perf_counter() - t)
    return best


def main(n=200_000, repeats=5):
    rng = np.random.default_rng(0)
    base = rng.standard_normal((n, 7))
    print(f"{n} elements, best of {repeats}, sim3 and se3 alternated")
    print(f"{'input':>10} {'kernel':>6} {'sim3 ms':>9} {'se3 ms':>9} {'ratio':>6}")
    for scale in (1.0, 0.1, 0.02):
        x7 = scale * base
        x6 = np.ascontiguousarray(x7[:, :6])
        X7 = sim3.exp(x7)
        X6 = se3.exp(x6)
        for name in ("exp", "log", "dexp", "dlog"):
            a7, a6 = (X7, X6) if name == "log" else (x7, x6)
            f7, f6 = getattr(sim3, name), getattr(se3, name)
            f7(a7[:10]), f6(a6[:10])  # compile outside the timing
            t7 = t6 = float("inf")
            for _ in range(repeats):
                t7 = min(t7, _best(f7, a7, 1))
                t6 = min(t6, _best(f6, a6, 1))
            print(f"{scale:>8}·N {name:>6} {1e3 * t7:9.2f} {1e3 * t6:9.2f} {t7 / t6:6.2f}")


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:]]
    main(*args)
