"""Kernel accuracy (the crosscheck table) and batched throughput.

    python benchmarks/kernels.py [--samples 5] [--n 100000]

Accuracy: ``lie_factors.crosscheck.run`` — ours and GTSAM's error against the
50-digit reference per function and θ band. Throughput: each group's batched
``exp``/``dexp``/``dlog`` on ``--n`` random tangent vectors (rotation angles
uniform in [0, π), translations ~N(0, 10²)), median of 9 calls after a warm-up
call, input validation and output allocation included.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from lie_factors import crosscheck, se2, se3, sim2, so3


def throughput(n: int) -> list[tuple[str, float]]:
    rng = np.random.default_rng(0)
    rows = []
    for name, G in (("so3", so3), ("se3", se3), ("se2", se2), ("sim2", sim2)):
        x = 10.0 * rng.normal(size=(n, G.DIM))
        r = crosscheck.rotation_slice(name)
        w = rng.normal(size=(n, r.stop - r.start))
        w *= (rng.uniform(0, np.pi, size=n) / np.linalg.norm(w, axis=1))[:, None]
        x[:, r] = w
        for fname in ("exp", "dexp", "dlog"):
            f = getattr(G, fname)
            f(x)
            samples = []
            for _ in range(9):
                t = time.perf_counter()
                f(x)
                samples.append(time.perf_counter() - t)
            rows.append((f"{name}.{fname}", statistics.median(samples)))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=5)
    ap.add_argument("--n", type=int, default=100_000)
    args = ap.parse_args(argv)
    rows = crosscheck.run(samples=args.samples, seed=0)
    print(f"## Accuracy ({args.samples} random points per band)\n")
    print(crosscheck.format_table(rows))
    print(f"\nworst lie_factors error: {max(r.ours for r in rows):.1e}\n")
    print(f"## Batched throughput ({args.n} tangent vectors, median of 9)\n")
    print("| function | ms | ns per element |\n|---|---|---|")
    for label, t in throughput(args.n):
        print(f"| {label} | {t * 1e3:.2f} | {t / args.n * 1e9:.0f} |")


if __name__ == "__main__":
    main()
