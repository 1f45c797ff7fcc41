"""Batch LM (lie_factors.batch) vs GTSAM's native C++ LM, side by side in one process.

    python benchmarks/batch_vs_native.py [--output FILE.md] [--repeats 3]
        [--datasets sphere2500,torus3D,...] [--scaling 1000,10000,100000] [--quick]

For each dataset: the graph as ``lie-factors posegraph`` builds it (the file's
edges + a prior on the first pose), once with GTSAM's factors, optimized by
``gtsam.LevenbergMarquardtOptimizer``, once with lie_factors factors,
optimized by ``lie_factors.batch.optimize`` (default linear solver: CHOLMOD).
Default LevenbergMarquardtParams for both.  Seconds are wall seconds of the
whole optimization (optimizer construction included on both sides), the
minimum over ``--repeats`` runs in which native, batch with 2 numba threads
and batch with 1 numba thread alternate.  The numba JIT is warmed up first.

Also printed: where the batch time goes per iteration (linearize / assemble /
factorize / solve / retract / error), time per iteration per factor on
generated SE(3) chains of 1k … 100k factors, and (``--rss``) the peak RSS of
``lie-factors posegraph torus3D.g2o`` with ``--backend native`` and ``batch``.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import platform
import subprocess
import sys
import time

import gtsam
import numba
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from lie_factors import batch, factors
from lie_factors.backends import build_graph  # noqa: E402
from lie_factors.g2o import read_pose_graph as load_dataset  # noqa: E402
from lie_factors.posegraph.graph import PRIOR_VARIANCES  # noqa: E402

DATA = os.environ.get("LIE_FACTORS_DATA", os.path.join(ROOT, "data"))
DEFAULT = "sphere2500,torus3D,city10000,intel,kitti_00,parking-garage,se3chain6k,se3chain20k,se2chain20k"
SPLIT = ("linearize", "assemble", "factorize", "solve", "retract", "error")


def chain(n_factors: int, is3d: bool, seed: int = 0):
    """Odometry chain with loop closures (~1 closure per 10 poses, 20–100 poses back), native factors.

    Returns (graph with a prior on pose 0, initial from composed noisy odometry).
    """
    rng = np.random.default_rng(seed)
    n_poses = max(3, int(round(n_factors / 1.1)))
    P = gtsam.Pose3 if is3d else gtsam.Pose2
    d = 6 if is3d else 3
    sig = np.array([0.01, 0.01, 0.01, 0.05, 0.05, 0.05]) if is3d else np.array([0.05, 0.05, 0.01])
    truth = [P()]
    for _ in range(1, n_poses):
        if is3d:
            step = np.concatenate([rng.normal(scale=0.05, size=3), [1.0, 0.0, 0.0] + rng.normal(scale=0.1, size=3)])
        else:
            step = np.array([1.0, 0.0, 0.0]) + rng.normal(scale=[0.1, 0.1, 0.05])
        truth.append(truth[-1].compose(P.Expmap(step)))
    nm = gtsam.noiseModel.Diagonal.Sigmas(sig)
    Between = gtsam.BetweenFactorPose3 if is3d else gtsam.BetweenFactorPose2
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    initial.insert(0, truth[0])
    est = truth[0]
    edges = [(i, i + 1) for i in range(n_poses - 1)]
    while len(edges) < n_factors - 1:
        i = int(rng.integers(101, n_poses)) if n_poses > 101 else int(rng.integers(1, n_poses))
        j = max(0, i - int(rng.integers(20, 101)))
        if i != j:
            edges.append((j, i))
    for a, b in edges:
        z = truth[a].between(truth[b]).compose(P.Expmap(rng.normal(size=d) * sig))
        graph.add(Between(a, b, z, nm))
        if b == a + 1:
            est = est.compose(z)
            initial.insert(b, est)
    prior = gtsam.noiseModel.Diagonal.Variances(PRIOR_VARIANCES["Pose3" if is3d else "Pose2"])
    graph.add((gtsam.PriorFactorPose3 if is3d else gtsam.PriorFactorPose2)(0, truth[0], prior))
    return graph, initial


def as_lie(native: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
    """The same graph with every Between/Prior factor re-created as a lie_factors factor."""
    lie = gtsam.NonlinearFactorGraph()
    for i in range(native.size()):
        f = native.at(i)
        name = type(f).__name__
        if name.startswith("BetweenFactor"):
            k1, k2 = f.keys()
            lie.add(getattr(factors, name)(k1, k2, f.measured(), f.noiseModel()))
        else:
            lie.add(getattr(factors, name)(f.keys()[0], f.prior(), f.noiseModel()))
    return lie


def load(name):
    """(native graph, lie graph, initial)."""
    if name.startswith(("se3chain", "se2chain")):
        n = int(name[8:].replace("k", "000"))
        native, initial = chain(n, name.startswith("se3"), seed=1)
        return native, as_lie(native), initial
    pg = load_dataset(os.path.join(DATA, name + ".g2o"))
    return build_graph(pg, "native"), build_graph(pg, "batch"), pg.initial


def time_native(graph, initial):
    t = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams())
    values = opt.optimize()
    return time.perf_counter() - t, int(opt.iterations()), float(graph.error(values))


def time_batch(graph, initial, threads):
    numba.set_num_threads(threads)
    try:
        t = time.perf_counter()
        res = batch.optimize(graph, initial, gtsam.LevenbergMarquardtParams())
        return time.perf_counter() - t, res
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)


def warm_up():
    t = time.perf_counter()
    for name in ("se3chain1k", "se2chain1k"):
        native, lie, initial = load(name)
        batch.optimize(lie, initial)
        time_batch(lie, initial, 1)
    return time.perf_counter() - t


def run_dataset(name, repeats):
    native, lie, initial = load(name)
    threads = numba.config.NUMBA_NUM_THREADS
    best = dict(native=np.inf, batch=np.inf, batch1=np.inf)
    res = None
    for _ in range(repeats):
        tn, it_n, err_n = time_native(native, initial)
        best["native"] = min(best["native"], tn)
        tb, r = time_batch(lie, initial, threads)
        if tb < best["batch"]:
            best["batch"], res = tb, r
        tb1, _ = time_batch(lie, initial, 1)
        best["batch1"] = min(best["batch1"], tb1)
    return dict(dataset=name, poses=int(initial.size()), factors=int(native.size()), it_native=it_n,
                it_batch=res.iterations, inner=res.inner_iterations, err_native=err_n,
                err_batch=res.final_error, err_batch_on_native=float(native.error(res.values)),
                t_native=best["native"], t_batch=best["batch"], t_batch1=best["batch1"],
                timings=res.timings, solver=res.linear_solver)


def scaling(sizes):
    """µs per inner iteration per factor on generated SE(3) chains (5 LM iterations)."""
    rows = []
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(5)
    params.setRelativeErrorTol(0.0)
    params.setAbsoluteErrorTol(0.0)
    for n in sizes:
        native, initial = chain(n, True, seed=2)
        lie = as_lie(native)
        best = None
        for _ in range(2):
            res = batch.optimize(lie, initial, params)
            loop = sum(res.timings[k] for k in SPLIT)
            if best is None or loop < best[0]:
                best = (loop, res)
        loop, res = best
        inner = max(res.inner_iterations, 1)
        per = {k: res.timings[k] / inner / lie.size() * 1e6 for k in SPLIT}
        rows.append(dict(factors=int(lie.size()), inner=inner, per_it_factor_us=loop / inner / lie.size() * 1e6,
                         **per))
    return rows


def peak_rss(backend, dataset="torus3D", *extra):
    """Peak RSS (MiB) of ``lie-factors posegraph DATASET --backend BACKEND [extra]`` in a fresh process."""
    # VmHWM, not getrusage's ru_maxrss: Linux carries ru_maxrss across fork + exec, so a
    # child of this (large) benchmark process would report the parent's peak.
    code = ("import sys; from lie_factors.app import cli; rc = cli.main(sys.argv[1:]); "
            "hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')][0]; "
            "print(hwm.split()[1], file=sys.stderr); sys.exit(rc)")
    env = dict(os.environ, PYTHONPATH=ROOT)
    p = subprocess.run([sys.executable, "-c", code, "posegraph", os.path.join(DATA, dataset + ".g2o"),
                        "--backend", backend, "--json", *extra], capture_output=True, text=True, env=env)
    if p.returncode != 0:
        raise RuntimeError(p.stderr)
    return int(p.stderr.strip().splitlines()[-1]) / 1024.0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--output", default="", help="also write the tables to this markdown file")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--datasets", default=DEFAULT)
    ap.add_argument("--scaling", default="1000,10000,100000")
    ap.add_argument("--rss", action="store_true", help="peak RSS of the CLI on torus3D, native vs batch")
    ap.add_argument("--quick", action="store_true", help="sphere2500 and 1k/10k scaling only")
    args = ap.parse_args(argv)
    if args.quick:
        args.datasets, args.scaling = "sphere2500", "1000,10000"
    jit = warm_up()
    threads = numba.config.NUMBA_NUM_THREADS
    lines = [f"Machine: {platform.machine()}, {os.cpu_count()} CPUs (shared with other jobs); "
             f"gtsam {importlib.metadata.version('gtsam')}, cvxopt {importlib.metadata.version('cvxopt')}, "
             f"numba {numba.__version__} ({threads} threads). Default LevenbergMarquardtParams; seconds = min "
             f"over {args.repeats} runs alternating native / batch / batch on 1 numba thread, whole "
             f"optimization incl. optimizer construction; numba warm-up {jit:.2f} s excluded.", "",
             "| dataset | poses | factors | iterations native/batch | final error native | final error batch "
             "| rel. diff | seconds native | seconds batch | batch/native | batch 1 thread | 1 thread/native |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    results = []
    for name in [d for d in args.datasets.split(",") if d]:
        r = run_dataset(name, args.repeats)
        results.append(r)
        rel = abs(r["err_batch"] - r["err_native"]) / abs(r["err_native"])
        lines.append(f"| {name} | {r['poses']} | {r['factors']} | {r['it_native']}/{r['it_batch']} | "
                     f"{r['err_native']:.10g} | {r['err_batch']:.10g} | {rel:.1e} | {r['t_native']:.3f} | "
                     f"{r['t_batch']:.3f} | {r['t_batch'] / r['t_native']:.2f} | {r['t_batch1']:.3f} | "
                     f"{r['t_batch1'] / r['t_native']:.2f} |")
        print(lines[-1], flush=True)
    lines += ["", "Where the batch time goes (best 2-thread run; ms per inner iteration, i.e. per "
              "linearization or λ tried; setup = reading the graph + pattern + symbolic analysis, once):", "",
              "| dataset | linear solver | inner its | setup s | linearize | assemble | factorize | solve | retract "
              "| error | values s |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        t = r["timings"]
        inner = max(r["inner"], 1)
        per = " | ".join(f"{t[k] / inner * 1e3:.1f}" for k in SPLIT)
        lines.append(f"| {r['dataset']} | {r['solver']} | {r['inner']} | {t['setup']:.3f} | {per} | {t['values']:.3f} |")
    if args.scaling:
        lines += ["", "Scaling: generated SE(3) chains with loop closures, 5 LM iterations "
                  "(µs per inner iteration per factor):", "",
                  "| factors | inner its | total | " + " | ".join(SPLIT) + " |",
                  "|---|---|---|" + "---|" * len(SPLIT)]
        for row in scaling([int(s) for s in args.scaling.split(",") if s]):
            lines.append(f"| {row['factors']} | {row['inner']} | {row['per_it_factor_us']:.2f} | "
                         + " | ".join(f"{row[k]:.2f}" for k in SPLIT) + " |")
            print(lines[-1], flush=True)
    if args.rss:
        peak_rss("batch")  # numba compiles here if the cache is cold: not part of either figure
        lines.append("")
        # The default --init auto runs GTSAM's chordal initialization first, in both backends.
        for extra in ((), ("--init", "file")):
            rn, rb = peak_rss("native", "torus3D", *extra), peak_rss("batch", "torus3D", *extra)
            lines.append(f"Peak RSS of `lie-factors posegraph torus3D.g2o --json {' '.join(extra)}`: "
                         f"native {rn:.0f} MiB, batch {rb:.0f} MiB (ratio {rb / rn:.2f}).")
    text = "\n".join(lines)
    print(text)
    if args.output:
        with open(args.output, "w") as fh:
            fh.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
