"""Kernel accuracy (the crosscheck table) and batched throughput.

    python benchmarks/kernels.py [--samples 5] [--n 100000] [--groups so3,se3,se2,sim2,sim3]

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

from lie_factors import crosscheck


def throughput(n: int, groups=crosscheck.GROUPS) -> list[tuple[str, float]]:
    rng = np.random.default_rng(0)
    rows = []
    for name in groups:
        G = crosscheck.KERNELS[name]
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
    ap.add_argument("--groups", default=",".join(crosscheck.GROUPS), help="comma-separated (default: all)")
    args = ap.parse_args(argv)
    groups = tuple(g for g in args.groups.split(",") if g)
    unknown = [g for g in groups if g not in crosscheck.KERNELS]
    if unknown:
        ap.error(f"unknown group(s) {', '.join(unknown)}; choose from {', '.join(crosscheck.GROUPS)}")
    rows = crosscheck.run(samples=args.samples, seed=0, groups=groups)
    print(f"## Accuracy ({args.samples} random points per band)\n")
    print(crosscheck.format_table(rows))
    print(f"\nworst lie_factors error: {max(r.ours for r in rows):.1e}\n")
    print(f"## Batched throughput ({args.n} tangent vectors, median of 9)\n")
    print("| function | ms | ns per element |\n|---|---|---|")
    for label, t in throughput(args.n, groups):
        print(f"| {label} | {t * 1e3:.2f} | {t / args.n * 1e9:.0f} |")


if __name__ == "__main__":
    main()
