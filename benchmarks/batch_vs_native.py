"""Batch LM (lie_factors.batch) vs GTSAM's native C++ LM, side by side in one run.

    python benchmarks/batch_vs_native.py [--output FILE.md]
        [--repeats 2] [--datasets sphere2500,torus3D,city10000,chain20k] [--quick]

For each dataset: the native graph (``gtsam.readG2o`` + a prior on the first
pose, as GTSAM's examples) optimized by ``gtsam.LevenbergMarquardtOptimizer``,
and the same graph with every BetweenFactor/PriorFactor re-created as a
lie_factors factor (same measured, same noise model) optimized by
``lie_factors.batch.optimize``.  Default LevenbergMarquardtParams for both.
Times are wall seconds of the whole optimization (optimizer construction
included on both sides), the minimum over ``--repeats`` interleaved runs; the
numba JIT is warmed up on a small graph first and reported separately.

Also: where the batch time goes (linearize / build GaussianFactorGraph /
eliminate / retract / error / setup / values), the per-iteration per-factor
time on generated SE(3) chains of 1k, 10k, 100k factors, and se3.dlog on
100k tangent vectors.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import platform
import sys
import time

import gtsam
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from lie_factors import batch, factors, se3  # noqa: E402

DATA = os.environ.get("LIE_FACTORS_DATA", "/work/shared/data")
DATASETS = {"sphere2500": True, "torus3D": True, "city10000": False}


def prior_noise(is3d):
    if is3d:
        return gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4]))
    return gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))


def load_g2o(name):
    is3d = DATASETS[name]
    graph, initial = gtsam.readG2o(os.path.join(DATA, name + ".g2o"), is3d)
    return graph, initial, is3d


def with_prior(between: gtsam.NonlinearFactorGraph, initial, is3d):
    """(native graph, lie_factors graph) = between factors + prior on the first key."""
    native, lie = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    LB = factors.BetweenFactorPose3 if is3d else factors.BetweenFactorPose2
    for i in range(between.size()):
        f = between.at(i)
        k1, k2 = f.keys()
        native.add(f)
        lie.add(LB(k1, k2, f.measured(), f.noiseModel()))
    first = min(initial.keys())
    if is3d:
        p = initial.atPose3(first)
        native.add(gtsam.PriorFactorPose3(first, p, prior_noise(True)))
        lie.add(factors.PriorFactorPose3(first, p, prior_noise(True)))
    else:
        p = initial.atPose2(first)
        native.add(gtsam.PriorFactorPose2(first, p, prior_noise(False)))
        lie.add(factors.PriorFactorPose2(first, p, prior_noise(False)))
    return native, lie


def se3_chain(n_factors: int, seed: int = 0):
    """SE(3) odometry chain with loop closures (~1 closure per 10 poses, 20–100 poses back).

    Returns (between graph of native factors, initial from composed noisy odometry).
    """
    rng = np.random.default_rng(seed)
    n_poses = max(3, int(round(n_factors / 1.1)))
    truth = [gtsam.Pose3()]
    for i in range(1, n_poses):
        step = np.concatenate([rng.normal(scale=0.05, size=3), [1.0, 0.0, 0.0] + rng.normal(scale=0.1, size=3)])
        truth.append(truth[-1].compose(gtsam.Pose3.Expmap(step)))
    sig = np.array([0.01, 0.01, 0.01, 0.05, 0.05, 0.05])
    nm = gtsam.noiseModel.Diagonal.Sigmas(sig)
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    initial.insert(0, truth[0])
    est = truth[0]
    edges = [(i, i + 1) for i in range(n_poses - 1)]
    while len(edges) < n_factors:
        i = int(rng.integers(101, n_poses)) if n_poses > 101 else int(rng.integers(1, n_poses))
        j = max(0, i - int(rng.integers(20, 101)))
        if i != j:
            edges.append((j, i))
    for a, b in edges:
        z = truth[a].between(truth[b]).compose(gtsam.Pose3.Expmap(rng.normal(size=6) * sig))
        graph.add(gtsam.BetweenFactorPose3(a, b, z, nm))
        if b == a + 1:
            est = est.compose(z)
            initial.insert(b, est)
    return graph, initial


def time_native(graph, initial):
    params = gtsam.LevenbergMarquardtParams()
    t = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    values = opt.optimize()
    seconds = time.perf_counter() - t
    return seconds, int(opt.iterations()), float(graph.error(values))


def time_batch(graph, initial):
    t = time.perf_counter()
    res = batch.optimize(graph, initial, gtsam.LevenbergMarquardtParams())
    seconds = time.perf_counter() - t
    return seconds, res


def warm_up():
    t = time.perf_counter()
    for is3d in (True, False):
        g, v = se3_chain(30) if is3d else (None, None)
        if not is3d:
            g = gtsam.NonlinearFactorGraph()
            v = gtsam.Values()
            nm = gtsam.noiseModel.Unit.Create(3)
            for i in range(5):
                v.insert(i, gtsam.Pose2(i, 0.1, 0.0))
                if i:
                    g.add(gtsam.BetweenFactorPose2(i - 1, i, gtsam.Pose2(1, 0, 0), nm))
        _, lie = with_prior(g, v, is3d)
        batch.optimize(lie, v)
    return time.perf_counter() - t


def run_dataset(name, repeats):
    if name == "chain20k":
        between, initial = se3_chain(20000, seed=1)
        is3d = True
    else:
        between, initial, is3d = load_g2o(name)
    native, lie = with_prior(between, initial, is3d)
    best_n, best_b, res = np.inf, np.inf, None
    for _ in range(repeats):
        tn, it_n, err_n = time_native(native, initial)
        tb, r = time_batch(lie, initial)
        best_n = min(best_n, tn)
        if tb < best_b:
            best_b, res = tb, r
    err_b_native_graph = float(native.error(res.values))
    return dict(dataset=name, poses=int(initial.size()), factors=int(native.size()),
                it_native=it_n, it_batch=res.iterations, err_native=err_n, err_batch=res.final_error,
                err_batch_on_native=err_b_native_graph, t_native=best_n, t_batch=best_b,
                ratio=best_b / best_n, timings=res.timings, inner=res.inner_iterations)


def scaling(sizes, iterations=5):
    rows = []
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    params.setRelativeErrorTol(0.0)
    params.setAbsoluteErrorTol(0.0)
    for n in sizes:
        between, initial = se3_chain(n, seed=2)
        native, lie = with_prior(between, initial, True)
        t = time.perf_counter()
        res = batch.optimize(lie, initial, params)
        total = time.perf_counter() - t
        loop = sum(res.timings[k] for k in ("linearize", "assemble", "factorize", "retract", "error"))
        inner = max(res.inner_iterations, 1)
        tn = time.perf_counter()
        opt = gtsam.LevenbergMarquardtOptimizer(native, initial, params)
        opt.optimize()
        tn = time.perf_counter() - tn
        rows.append(dict(factors=int(lie.size()), poses=int(initial.size()), iterations=res.iterations,
                         inner=inner, total=total, per_it_factor_us=loop / inner / lie.size() * 1e6,
                         lin_us=res.timings["linearize"] / inner / lie.size() * 1e6,
                         build_us=res.timings["assemble"] / inner / lie.size() * 1e6,
                         elim_us=res.timings["factorize"] / inner / lie.size() * 1e6,
                         native_total=tn))
    return rows


def dlog_timing(n=100_000, repeats=7):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(n, 6))
    se3.dlog(x[:10])  # compile
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        se3.dlog(x)
        ts.append(time.perf_counter() - t)
    return min(ts), float(np.median(ts))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--output", default="", help="also write the tables to this markdown file")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--datasets", default="sphere2500,torus3D,city10000,chain20k")
    ap.add_argument("--scaling", default="1000,10000,100000")
    ap.add_argument("--quick", action="store_true", help="sphere2500 and 1k/10k scaling only")
    args = ap.parse_args(argv)
    if args.quick:
        args.datasets, args.scaling = "sphere2500", "1000,10000"
    jit = warm_up()
    lines = [f"# Batch LM vs GTSAM native LM\n",
             f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; "
             f"gtsam {importlib.metadata.version('gtsam')}, numpy {np.__version__}. "
             f"Default LevenbergMarquardtParams; seconds = min over {args.repeats} interleaved runs, "
             f"whole optimization incl. optimizer construction; numba JIT warm-up {jit:.2f} s excluded.\n",
             "| dataset | poses | factors | iterations native/batch | final error native | final error batch "
             "| rel. diff | seconds native | seconds batch | ratio batch/native |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    results = []
    for name in [d for d in args.datasets.split(",") if d]:
        r = run_dataset(name, args.repeats)
        results.append(r)
        rel = abs(r["err_batch"] - r["err_native"]) / abs(r["err_native"])
        lines.append(f"| {name} | {r['poses']} | {r['factors']} | {r['it_native']}/{r['it_batch']} | "
                     f"{r['err_native']:.10g} | {r['err_batch']:.10g} | {rel:.1e} | {r['t_native']:.3f} | "
                     f"{r['t_batch']:.3f} | {r['ratio']:.2f} |")
        print(lines[-1], flush=True)
    lines += ["", "## Where the batch time goes (seconds, best run)", "",
              "| dataset | inner its | setup (extract graph) | create JacobianFactors (once) | linearize (numba) "
              "| build / update GFG | eliminate (GTSAM) | retract | error + linear error | values | other |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        t = r["timings"]
        lines.append(f"| {r['dataset']} | {r['inner']} | {t['setup']:.3f} | {t.get('create', 0):.3f} | {t['linearize']:.3f} | "
                     f"{t['build']:.3f} | {t['eliminate']:.3f} | {t['retract']:.3f} | {t['error']:.3f} | "
                     f"{t.get('values', 0):.3f} | {t['other']:.3f} |")
    lines += ["", "## Scaling: generated SE(3) chains with loop closures, 5 LM iterations", "",
              "| factors | poses | inner its | µs / iteration / factor | linearize | build | eliminate "
              "| batch total s | native total s |",
              "|---|---|---|---|---|---|---|---|---|"]
    for row in scaling([int(s) for s in args.scaling.split(",") if s]):
        lines.append(f"| {row['factors']} | {row['poses']} | {row['inner']} | {row['per_it_factor_us']:.2f} | "
                     f"{row['lin_us']:.2f} | {row['build_us']:.2f} | {row['elim_us']:.2f} | "
                     f"{row['total']:.2f} | {row['native_total']:.2f} |")
        print(lines[-1], flush=True)
    best, med = dlog_timing()
    lines += ["", f"## Kernel throughput", "",
              f"se3.dlog on 100 000 tangent vectors: {best * 1e3:.2f} ms (min of 7), "
              f"{med * 1e3:.2f} ms median (target ≤ 10 ms).", ""]
    text = "\n".join(lines)
    print(text)
    if args.output:
        os.makedirs(os.path.dirname(os.path.abspath(args.output)), exist_ok=True)
        with open(args.output, "w") as fh:
            fh.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
