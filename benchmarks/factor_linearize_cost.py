"""Cost of ``graph.linearize(values)`` with lie_factors' BetweenFactorPose3.

On GTSAM's sphere2500 (``gtsam.findExampleDataFile("sphere2500.txt")``, edges
only, initialized by composing measurements along a spanning tree) the same
graph is linearized with

* GTSAM's native BetweenFactorPose3,
* CustomFactors whose callback does nothing but return zeros and identities,
* lie_factors.factors.BetweenFactorPose3,

and the ratio ours / empty-callback is reported (target ≤ 2). Also the cost of
one LM optimization with custom factors driven by GTSAM's C++ optimizer, which
pays GTSAM's per-callback copy of the whole Values (the known limitation).

Usage: python benchmarks/factor_linearize_cost.py [--repeats 7] [--lm]
"""

from __future__ import annotations

import argparse
import statistics
import time

import gtsam
import numpy as np

from lie_factors import factors
from lie_factors.g2o import read_pose_graph


def _empty(this, values, H):
    if H is not None:
        H[0] = np.eye(6)
        H[1] = np.eye(6)
    return np.zeros(6)


def timed_linearize(graph, values, repeats):
    graph.linearize(values)  # warm-up (numba dispatch, allocations)
    samples = []
    for _ in range(repeats):
        t = time.perf_counter()
        graph.linearize(values)
        samples.append(time.perf_counter() - t)
    return statistics.median(samples)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--lm", action="store_true", help="also time one LM run per backend (slow: ~10 s)")
    args = parser.parse_args(argv)

    pg = read_pose_graph("sphere2500.txt")
    between = pg.factor_graph()
    native, empty, ours = (gtsam.NonlinearFactorGraph() for _ in range(3))
    for i in range(between.size()):
        f = between.at(i)
        k1, k2 = f.keys()
        native.add(f)
        empty.add(gtsam.CustomFactor(f.noiseModel(), [k1, k2], _empty))
        ours.add(factors.BetweenFactorPose3(k1, k2, f.measured(), f.noiseModel()))
    n = native.size()
    t_native = timed_linearize(native, pg.initial, args.repeats)
    t_empty = timed_linearize(empty, pg.initial, args.repeats)
    t_ours = timed_linearize(ours, pg.initial, args.repeats)
    print(f"sphere2500.txt: {pg.pose_count} poses, {n} BetweenFactorPose3, median of {args.repeats}")
    print("| graph | linearize (ms) | per factor (µs) |")
    print("|---|---|---|")
    for label, t in (("native BetweenFactorPose3", t_native), ("CustomFactor, empty callback", t_empty),
                     ("lie_factors BetweenFactorPose3", t_ours)):
        print(f"| {label} | {t * 1e3:.1f} | {t / n * 1e6:.2f} |")
    print(f"\nratio lie_factors / empty callback: {t_ours / t_empty:.2f} (target ≤ 2)")
    print(f"ratio lie_factors / native: {t_ours / t_native:.1f}")

    if args.lm:
        print("\n| LM driven by GTSAM's C++ optimizer | seconds | iterations | final error |")
        print("|---|---|---|---|")
        prior = gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)
        for label, graph, prior_factor in (("native", native, gtsam.PriorFactorPose3),
                                           ("lie_factors", ours, factors.PriorFactorPose3)):
            g = gtsam.NonlinearFactorGraph(graph)
            g.add(prior_factor(int(pg.keys[0]), pg.initial.atPose3(int(pg.keys[0])), prior))
            t = time.perf_counter()
            opt = gtsam.LevenbergMarquardtOptimizer(g, pg.initial, gtsam.LevenbergMarquardtParams())
            result = opt.optimize()
            print(f"| {label} | {time.perf_counter() - t:.2f} | {opt.iterations()} | {g.error(result):.6f} |")


if __name__ == "__main__":
    main()
