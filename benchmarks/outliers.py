"""False loop closures: plain LM, robust losses and GNC-TLS, per backend, against the outlier-free optimum.

For each graph the script

1. optimizes the outlier-free graph with GTSAM's LM (the reference trajectory);
2. plants ``--fraction`` × (number of loop closures) random false loop
   closures (seeded; :func:`lie_factors.testing.outliers.plant_false_loop_closures`:
   random pose pairs ≥ 2 ids apart, uniformly random measurement, the noise
   model of a real loop closure);
3. runs every method on every backend from the same initial guess (``--start``) and prints
   one row each: iterations, seconds, position RMSE against the reference (and
   as a percentage of the reference trajectory's bounding-box diagonal), and
   for GNC the precision/recall of the rejected edges against the planted ones.

Methods: ``lm`` (plain LM), ``huber``/``cauchy``/``tukey``/``gm``/``dcs``
(``noiseModel.Robust`` with that loss, default parameter, on the loop
closures), ``gnc-tls`` (odometry and the prior as known inliers, thresholds
½·χ²_dim(0.99)).  Backends: ``native`` (GTSAM's factors, LM and
GncLMOptimizer), ``batch`` (lie_factors.batch).  Native GNC runs in a child
process and is abandoned after ``--native-timeout`` seconds (reported as such).
``custom`` is not run: GTSAM's CustomFactor pays a Values copy per callback
inside C++ optimizers (README), which makes GNC's ~30 LM solves impractical.

Starts (``--start``): ``auto`` (default) is what ``lie-factors posegraph``'s
``--init auto`` does under ``--gnc``/``--robust``: the odometry edges and the
prior composed (:func:`lie_factors.initialization.initialize` with the known
inliers); ``file`` the file's vertices (the chain: composed odometry);
``chordal`` the relaxation over every edge, false ones included (what
``--init auto`` is without ``--gnc``/``--robust``).

Usage::

    python benchmarks/outliers.py                                   # all graphs, 20 %
    python benchmarks/outliers.py --graphs intel chain1000 --methods lm gnc-tls
    python benchmarks/outliers.py --graphs intel --backends batch --start chordal

Timing: best of ``--repeat`` runs, native and batch alternated (on a shared
machine, run nothing else heavy meanwhile).
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing as mp
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import gtsam  # noqa: E402

from lie_factors.app import demo  # noqa: E402
from lie_factors.app.backends import build_graph  # noqa: E402
from lie_factors.app.load import Dataset, load  # noqa: E402
from lie_factors.app.plotting import positions as trajectory  # noqa: E402
from lie_factors.kernels.elements import matrices_from_values  # noqa: E402
from lie_factors.pose_graph import PoseGraph  # noqa: E402
from lie_factors.testing import outliers  # noqa: E402
from lie_factors.initialization import initialize  # noqa: E402
from lie_factors.batch import gnc as gncm  # noqa: E402
from lie_factors.batch.robust import LOSSES, RobustLoss, WeightedLevenbergMarquardt  # noqa: E402

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data")
GRAPHS = ("sphere2500", "intel", "city10000", "chain1000")
METHODS = ("lm", "huber", "cauchy", "tukey", "gm", "dcs", "gnc-tls")
STARTS = ("auto", "file", "chordal")


def load_graph(name: str) -> Dataset:
    """A dataset of data/ by name, or ``chainN``: the demo's SE(3) trajectory with N poses."""
    if name.startswith("chain"):
        n = int(name[5:])
        prob = demo.simulate(n, seed=0)
        graph = PoseGraph.from_gtsam(demo.between_graph(prob))
        graph = dataclasses.replace(graph, vertices=matrices_from_values(prob.initial, "Pose3", graph.keys))
        return Dataset(path="", name=f"SE(3) chain {n}", graph=graph)
    path = os.path.join(DATA, name + ".g2o")
    return load(path if os.path.exists(path) else name)


def with_edges(pg: Dataset, between) -> Dataset:
    """``pg`` with the between factors ``between`` (GTSAM's), starting where ``pg`` starts."""
    graph = dataclasses.replace(PoseGraph.from_gtsam(between, pg.group, pg.graph.keys), vertices=pg.graph.vertices)
    planted = Dataset(pg.path, pg.name, graph)
    planted.initial = pg.initial
    return planted


def lm_params():
    return gtsam.LevenbergMarquardtParams()


# --------------------------------------------------------------------------- #
# One run of a method on a backend → (values, iterations, seconds, rejected | None)
# --------------------------------------------------------------------------- #

def run_lm(pg, backend, loss):
    graph = build_graph(pg, "native" if backend == "native" else "dropin", loss)
    t = time.perf_counter()
    if backend == "native":
        opt = gtsam.LevenbergMarquardtOptimizer(graph, pg.initial, lm_params())
        values = opt.optimize()
        its = opt.iterations()
    else:
        res = WeightedLevenbergMarquardt(graph, pg.initial, lm_params()).optimize()
        values, its = res.values, res.iterations
    return values, int(its), time.perf_counter() - t, None, float(graph.error(values))


def gnc_params(graph, pg):
    closures = set(pg.graph.loop_closures().tolist())
    known = [k for k in range(graph.size()) if k not in closures]
    return gncm.GncParams(loss="tls", known_inliers=known, lm_params=lm_params())


def run_gnc(pg, backend):
    graph = build_graph(pg, "native" if backend == "native" else "dropin")
    params = gnc_params(graph, pg)
    t = time.perf_counter()
    if backend == "native":
        res = gncm.gtsam_gnc(graph, pg.initial, params)
        values = res.values
    else:
        res = gncm.gnc_optimize(gncm.BatchInner(graph, pg.initial, lm_params()), params)
        values = res.values.to_values()
    seconds = time.perf_counter() - t
    return values, res.iterations, seconds, res.outliers, res.cost


def _native_gnc_child(name, fraction, seed, start, conn):
    pg, planted, _, _ = prepare(name, fraction, seed, reference=False, start=start)
    values, its, seconds, rejected, cost = run_gnc(pg, "native")
    conn.send((positions(values, pg), its, seconds, rejected.tolist(), cost))
    conn.close()


def run_native_gnc_with_timeout(name, fraction, seed, start, timeout):
    """Native GNC in a child process (GTSAM's C++ loop cannot be interrupted); None if it times out."""
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_native_gnc_child, args=(name, fraction, seed, start, child))
    proc.start()
    if parent.poll(timeout):
        out = parent.recv()
        proc.join()
        return out
    proc.kill()
    proc.join()
    return None


# --------------------------------------------------------------------------- #
# Scoring
# --------------------------------------------------------------------------- #

def positions(values, pg) -> np.ndarray:
    return trajectory(values, pg.is3d)


def start_values(pg, how: str):
    """The initial values ``--start`` names (see the module docstring), and the method that made them."""
    if how == "file":
        return pg.initial, "file"
    graph = build_graph(pg, "native")
    inliers = np.setdiff1d(np.arange(pg.edges), pg.graph.loop_closures()) if how == "auto" else None
    s = initialize(graph, "auto" if how == "auto" else how, pg.initial, inliers=inliers)
    return s.values, s.method + (" of the odometry and the prior" if s.inliers_only else " of every edge")


def prepare(name, fraction, seed, reference=True, start="file"):
    pg = load_graph(name)
    ref = None
    if reference:
        graph = build_graph(pg, "native")
        ref = positions(gtsam.LevenbergMarquardtOptimizer(graph, pg.initial, lm_params()).optimize(), pg)
    n_lc = len(pg.graph.loop_closures())
    count = int(round(fraction * n_lc))
    between, planted = outliers.plant_false_loop_closures(pg.graph.factor_graph(), pg.graph.keys.tolist(), count,
                                                          seed, pg.is3d)
    planted_pg = with_edges(pg, between)
    planted_pg.initial, label = start_values(planted_pg, start)
    return planted_pg, planted, ref, label


def rmse(P, ref) -> float:
    return float(np.sqrt(np.mean(np.sum((P - ref) ** 2, axis=1))))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--graphs", nargs="+", default=list(GRAPHS),
                    help=f"datasets in data/ by name, or chainN (default: {' '.join(GRAPHS)})")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--backends", nargs="+", default=["native", "batch"], choices=["native", "batch"])
    ap.add_argument("--fraction", type=float, default=0.2,
                    help="false loop closures planted, as a fraction of the true ones (default 0.2)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--start", default="auto", choices=STARTS,
                    help="initial guess: auto = odometry and prior composed (the CLI's --init auto under "
                         "--gnc/--robust), file = the file's vertices, chordal = relaxation of every edge")
    ap.add_argument("--repeat", type=int, default=1, help="timing: best of this many runs (default 1)")
    ap.add_argument("--native-timeout", type=float, default=600.0,
                    help="seconds after which native GNC is abandoned (default 600)")
    args = ap.parse_args(argv)

    print(f"# outliers: {args.fraction:.0%} false loop closures (relative to the true ones), "
          f"seed {args.seed}, best of {args.repeat}")
    print("| graph | method | backend | iterations | seconds | RMSE [m] | RMSE / bbox diag | "
          "precision | recall | final error |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in args.graphs:
        pg, planted, ref, start = prepare(name, args.fraction, args.seed, start=args.start)
        print(f"# {pg.name}: start {start}", flush=True)
        diag = float(np.linalg.norm(ref.max(axis=0) - ref.min(axis=0)))
        label = f"{pg.name} ({pg.poses} poses, {len(planted)} false / " \
                f"{len(pg.graph.loop_closures()) - len(planted)} true LC)"
        for method in args.methods:
            # Repetitions alternate the backends, so both see the same machine load.
            best = {b: None for b in args.backends}
            for _ in range(args.repeat):
                for backend in args.backends:
                    if best[backend] == "timeout":
                        continue
                    if method == "gnc-tls" and backend == "native":
                        out = run_native_gnc_with_timeout(name, args.fraction, args.seed, args.start,
                                                          args.native_timeout)
                        if out is None:
                            best[backend] = "timeout"
                            continue
                        P, its, sec, rejected, err = out
                    else:
                        if method == "lm":
                            values, its, sec, rejected, err = run_lm(pg, backend, None)
                        elif method == "gnc-tls":
                            values, its, sec, rejected, err = run_gnc(pg, backend)
                        else:
                            values, its, sec, rejected, err = run_lm(pg, backend,
                                                                     RobustLoss(method, LOSSES[method][2]))
                        P = positions(values, pg)
                    if best[backend] is None or sec < best[backend][2]:
                        best[backend] = (P, its, sec, rejected, err)
            for backend in args.backends:
                if best[backend] == "timeout":
                    print(f"| {label} | {method} | {backend} | – | > {args.native_timeout:.0f} "
                          "(abandoned) | – | – | – | – | – |", flush=True)
                    continue
                P, its, sec, rejected, err = best[backend]
                e = rmse(P, ref)
                if rejected is not None:
                    c = outliers.classify(rejected, planted)
                    pr, rc = f"{c.precision:.3f}", f"{c.recall:.3f}"
                else:
                    pr = rc = "–"
                print(f"| {label} | {method} | {backend} | {its} | {sec:.2f} | {e:.4g} | "
                      f"{100 * e / diag:.3g} % | {pr} | {rc} | {err:.6g} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
