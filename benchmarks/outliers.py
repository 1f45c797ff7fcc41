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

``--suite`` compares what ``lie-factors posegraph FILE --gnc tls`` runs
(consistency stage, GNC, final check) with GTSAM's ``GncOptimizer`` on
``--graphs``, with false closures of ``--kinds`` from ``--generator``
(``corrupt``: :func:`lie_factors.corrupt`'s uniform, local, group and near;
``testing``: the uniform and clustered ones of the earlier tables), at
``--fractions`` and ``--seeds``.  It prints a row per run, then the worst and
the median of each cell over the seeds not in ``--tuning-seeds`` (the seeds
the pipeline was developed on: default 0).  Besides precision and recall of the rejected edges, it reports
how many planted closures happen to fit the clean optimum (χ² ≤ χ²_n(0.95)
under their own noise model) and precision and recall with those left out of
the count (riSAM's rule: such a closure is not an outlier).  GTSAM's results
are stored in ``--native-cache``; ``--reuse-native`` reads them instead of
running GTSAM again (its seconds, from the earlier run, are marked ``*``).
``--sweep RESULTS`` runs the suite's cases through :func:`lie_factors.sweep`
(Dask: a LocalCluster of ``--workers``, or ``--scheduler ADDRESS``), a row per case in RESULTS
that a rerun resumes, and prints the same tables from the rows (one run per case; GTSAM's
``GncOptimizer`` as ``lf.optimize(..., backend="native", gnc="tls", consistency=False)``,
abandoned after ``--native-timeout``).
``--clean`` runs the suite's graphs without false closures (``--gnc tls``
against plain LM); ``--tails`` prints the true closures' leave-one-out
statistics at each clean optimum against χ² (the final check's tail model).

Usage::

    python benchmarks/outliers.py                                   # all graphs, 20 %
    python benchmarks/outliers.py --graphs intel chain1000 --methods lm gnc-tls
    python benchmarks/outliers.py --graphs intel --backends batch --start chordal
    python benchmarks/outliers.py --suite --graphs intel CSAIL --seeds 0 1 --repeat 2
    python benchmarks/outliers.py --suite --graphs intel manhattan --kinds uniform group --fractions 0.2 --seeds 1 2 3
    python benchmarks/outliers.py --suite --generator testing --kinds uniform clustered --seeds 0
    python benchmarks/outliers.py --suite --graphs intel CSAIL --kinds uniform group --seeds 1 2 --sweep suite.csv
    python benchmarks/outliers.py --tails --graphs intel CSAIL manhattan city10000 sphere2500

Timing: best of ``--repeat`` runs, native and batch alternated (on a shared
machine, run nothing else heavy meanwhile).
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing as mp
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import gtsam  # noqa: E402

from lie_factors.app import demo  # noqa: E402
from lie_factors.backends import build_graph  # noqa: E402
from lie_factors.g2o import read_pose_graph  # noqa: E402
from lie_factors.app.plotting import positions as trajectory  # noqa: E402
from lie_factors.interop import matrices_from_values  # noqa: E402
from lie_factors.posegraph.graph import PoseGraph  # noqa: E402
from lie_factors.testing import outliers  # noqa: E402
from lie_factors.initialization import initialize  # noqa: E402
from lie_factors.robust import gnc as gncm  # noqa: E402
from lie_factors.robust import inner  # noqa: E402
from lie_factors.robust.losses import LOSSES, RobustLoss  # noqa: E402
from lie_factors.robust.weighted import WeightedLevenbergMarquardt  # noqa: E402
from lie_factors.sweeps.metrics import consistent_planted, diagonal, map_error_percent, rmse, stage_counts  # noqa: E402

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data")
GRAPHS = ("sphere2500", "intel", "city10000", "chain1000")
METHODS = ("lm", "huber", "cauchy", "tukey", "gm", "dcs", "gnc-tls")
STARTS = ("auto", "file", "chordal")


def load_graph(name: str) -> PoseGraph:
    """A dataset of data/ by name, ``chainN``: the demo's SE(3) trajectory with N poses, or
    ``helixN``: ``generate_posegraph.py``'s SE(3) helix with N poses (written to the temp dir)."""
    if name.startswith("helix"):
        import generate_posegraph

        n = int(name[5:])
        path = os.path.join(tempfile.gettempdir(), f"lie_factors_outliers_helix{n}.g2o")
        if not os.path.exists(path):
            generate_posegraph.write_g2o(path, *generate_posegraph.generate(n, lap=500))
        return read_pose_graph(path)
    if name.startswith("chain"):
        n = int(name[5:])
        prob = demo.simulate(n, seed=0)
        graph = PoseGraph.from_gtsam(demo.between_graph(prob))
        graph = dataclasses.replace(graph, vertices=matrices_from_values(prob.initial, "Pose3", graph.keys))
        return dataclasses.replace(graph, name=f"SE(3) chain {n}")
    path = os.path.join(DATA, name + ".g2o")
    return read_pose_graph(path if os.path.exists(path) else name)


def with_edges(pg: PoseGraph, between) -> PoseGraph:
    """``pg`` with the between factors ``between`` (GTSAM's), starting where ``pg`` starts."""
    graph = dataclasses.replace(PoseGraph.from_gtsam(between, pg.group, pg.keys), vertices=pg.vertices)
    planted = dataclasses.replace(graph, name=pg.name, path=pg.path)
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
    closures = set(pg.loop_closures().tolist())
    known = [k for k in range(graph.size()) if k not in closures]
    return gncm.GncSettings(loss="tls", known_inliers=known, lm_params=lm_params())


def run_gnc(pg, backend):
    graph = build_graph(pg, "native" if backend == "native" else "dropin")
    params = gnc_params(graph, pg)
    t = time.perf_counter()
    if backend == "native":
        res = inner.gtsam_gnc(graph, pg.initial, params)
        values = res.values
    else:
        res = gncm.gnc_optimize(inner.BatchInner(graph, pg.initial, lm_params()), params)
        values = res.values.to_values()
    seconds = time.perf_counter() - t
    return values, res.iterations, seconds, res.outliers, res.cost


def _native_gnc_child(name, fraction, seed, start, conn, kind="uniform", pg=None):
    if pg is None:
        pg, planted, _, _ = prepare(name, fraction, seed, reference=False, start=start, kind=kind)
    values, its, seconds, rejected, cost = run_gnc(pg, "native")
    conn.send((positions(values, pg), its, seconds, rejected.tolist(), cost))
    conn.close()


def run_native_gnc_with_timeout(name, fraction, seed, start, timeout, kind="uniform", pg=None):
    """Native GNC in a child process (GTSAM's C++ loop cannot be interrupted); None if it times out.
    ``pg``: the planted graph with its start (else planted again in the child)."""
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_native_gnc_child, args=(name, fraction, seed, start, child, kind, pg))
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
    inliers = np.setdiff1d(np.arange(pg.edge_count), pg.loop_closures()) if how == "auto" else None
    s = initialize(graph, "auto" if how == "auto" else how, pg.initial, inliers=inliers)
    return s.values, s.method + (" of the odometry and the prior" if s.inliers_only else " of every edge")


def reference_values(pg):
    """The outlier-free optimum: the default command's solver (chordal start, batch LM)."""
    import lie_factors as lf

    return lf.optimize(pg).values


def reference_positions(pg) -> np.ndarray:
    """The outlier-free optimum's positions."""
    return positions(reference_values(pg), pg)


#: The generators of ``--generator``: ``corrupt`` is :func:`lie_factors.corrupt` (kinds uniform, local,
#: group, near); ``testing`` is :mod:`lie_factors.testing.outliers` (uniform: translations in ±10 m;
#: clustered: runs of 3–10), what the earlier tables of docs/benchmarks.md planted.
GENERATORS = {"corrupt": ("uniform", "local", "group", "near"), "testing": ("uniform", "clustered")}


def plant(pg, fraction, seed, kind="uniform", generator="testing", reference=None):
    """``pg``'s between graph with false loop closures of ``kind`` from ``generator`` and their slots;
    ``reference``: the clean optimum's poses (P, m, m), which ``corrupt``'s group and near runs need."""
    if kind not in GENERATORS[generator]:
        raise SystemExit(f"outliers.py: --generator {generator} has no kind {kind!r} "
                         f"(choose from {', '.join(GENERATORS[generator])})")
    if generator == "corrupt":
        from lie_factors.corruption import plant as corrupt_plant

        c = corrupt_plant(pg, fraction=fraction, kind=kind, seed=seed, reference=reference)
        return c.graph.factor_graph(), c.planted
    n_lc = len(pg.loop_closures())
    count = int(round(fraction * n_lc))
    planter = (outliers.plant_false_loop_closures if kind == "uniform"
               else outliers.plant_clustered_false_loop_closures)
    return planter(pg.factor_graph(), pg.keys.tolist(), count, seed, pg.is3d)


def prepare(name, fraction, seed, reference=True, start="file", kind="uniform"):
    pg = load_graph(name)
    ref = reference_positions(pg) if reference else None
    between, planted = plant(pg, fraction, seed, kind)
    planted_pg = with_edges(pg, between)
    planted_pg.initial, label = start_values(planted_pg, start)
    return planted_pg, planted, ref, label


# --------------------------------------------------------------------------- #
# The suite: lie-factors' --gnc (consistency stage, GNC, final check) against GTSAM's GncOptimizer
# --------------------------------------------------------------------------- #

SUITE_GRAPHS = ("intel", "CSAIL", "MIT", "manhattan", "city10000", "kitti_00", "sphere2500", "parking-garage",
                "torus3D", "helix10000")


def _timed_out(b) -> bool:
    return isinstance(b[0], str)


def run_ours(planted_pg):
    """What ``lie-factors posegraph FILE --gnc tls`` runs (batch backend, consistency stage on):
    (positions, seconds, rejected edges, rejected_by, robust_status)."""
    import lie_factors as lf

    result = lf.optimize(planted_pg, gnc="tls")
    return (positions(result.values, planted_pg), result.seconds, result.outliers.tolist(),
            {str(k): v for k, v in result.rejected_by.items()}, result.robust_status)


NATIVE_CACHE = os.path.join(tempfile.gettempdir(), "lie_factors_outliers_native")


def _cache_path(cache, name, fraction, kind, seed):
    """``kind`` is the generator's: ``corrupt:group``, or ``uniform``/``clustered`` for ``testing``."""
    return os.path.join(cache, f"{os.path.basename(name)}-{fraction:g}-{kind.replace(':', '-')}-{seed}.npz")


def load_native(cache, name, fraction, kind, seed):
    """A stored GTSAM GncOptimizer result: (positions, seconds, rejected) or "timeout" (after the
    stored timeout); None if there is none."""
    path = _cache_path(cache, name, fraction, kind, seed)
    if not os.path.exists(path):
        return None
    d = np.load(path)
    if bool(d["timeout"]):
        return ("timeout", float(d["seconds"]))
    return (d["positions"], float(d["seconds"]), d["rejected"])


def store_native(cache, name, fraction, kind, seed, out, timeout):
    os.makedirs(cache, exist_ok=True)
    path = _cache_path(cache, name, fraction, kind, seed)
    if out is None:
        np.savez(path, timeout=True, seconds=timeout, positions=np.zeros(0), rejected=np.zeros(0, np.int64))
    else:
        np.savez(path, timeout=False, seconds=out[1], positions=out[0], rejected=np.asarray(out[2], np.int64))


def _suite_case(args, name, base, ref_values, fraction, kind, seed):
    """One cell of the suite at one seed: {method: (positions, seconds, rejected, rejected_by, robust_status) or
    "timeout"}, the planted slots, those that fit the clean optimum, and the cache key's kind."""
    ckind = kind if args.generator == "testing" else f"corrupt:{kind}"
    X = matrices_from_values(ref_values, base.group, base.keys)
    between, planted = plant(base, fraction, seed, kind, args.generator, reference=X)
    consistent = consistent_planted(between, planted, ref_values, base.info.dim)
    pg = with_edges(base, between)
    pg.initial, _ = start_values(pg, "auto")
    best = {"ours": None, "gtsam": None}
    cached = load_native(args.native_cache, name, fraction, ckind, seed) if args.reuse_native else None
    if cached is not None:
        best["gtsam"] = ("timeout", cached[1]) if _timed_out(cached) else (cached[0], cached[1], cached[2], None, None)
    for _ in range(args.repeat):
        P, sec, rejected, by, status = run_ours(pg)
        if best["ours"] is None or sec < best["ours"][1]:
            best["ours"] = (P, sec, rejected, by, status)
        if not args.no_native and cached is None and not (best["gtsam"] and _timed_out(best["gtsam"])):
            out = run_native_gnc_with_timeout(name, fraction, seed, "auto", args.native_timeout, kind, pg=pg)
            if out is None:
                best["gtsam"] = ("timeout", args.native_timeout)
            elif best["gtsam"] is None or out[2] < best["gtsam"][1]:
                best["gtsam"] = (out[0], out[2], out[3], None, None)
    if cached is None and best["gtsam"] is not None:
        store_native(args.native_cache, name, fraction, ckind, seed,
                     None if _timed_out(best["gtsam"]) else best["gtsam"], args.native_timeout)
    return best, planted, consistent, cached is not None


def _summary(records, tuning) -> None:
    """Worst and median per graph, fraction, kind and method over the seeds not in ``tuning``
    (:func:`lie_factors.sweeps.summary.summary` of the records as a sweep's rows)."""
    from lie_factors.sweeps.summary import summary

    print()
    print(summary(records, tuning), flush=True)


def _record(graph, fraction, kind, seed, method, timeout, **figures) -> dict:
    """A run of the suite as a sweep's row (:data:`lie_factors.sweeps.results.COLUMNS`)."""
    return {"graph": graph, "fraction": fraction, "kind": kind, "seed": seed, "method": method,
            "status": "timeout" if timeout else "ok", **figures}


def suite(args) -> int:
    fractions = args.fractions or [0.2, 0.5]
    kinds = args.kinds or list(GENERATORS[args.generator])
    if args.sweep is not None:
        return suite_on_sweep(args, fractions, kinds)
    if args.scheduler is not None or args.workers is not None:
        raise SystemExit("outliers.py: --scheduler and --workers go with --sweep RESULTS")
    tuning = set(args.tuning_seeds)
    print(f"# outliers suite: generator {args.generator}, kinds {kinds}, fractions {fractions}, seeds {args.seeds} "
          f"(tuning seeds {sorted(tuning)}: shown, left out of the summary), best of {args.repeat} (ours and "
          f"GTSAM's GncOptimizer alternated), GTSAM abandoned after {args.native_timeout:.0f} s"
          + (f"; GTSAM's results read from {args.native_cache} where stored (seconds marked *)"
             if args.reuse_native else ""))
    print("| graph | false | kind | seed | method | precision | recall | map error / diag | seconds | "
          "rejected by | planted consistent | precision, recall (riSAM) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    records = []
    flagged: dict[bool, list] = {True: [], False: []}  # map > 1 % off → was it "uncertain"
    for name in args.graphs:
        base = load_graph(name)
        ref_values = reference_values(base)
        ref = positions(ref_values, base)
        for fraction in fractions:
            for kind in kinds:
                for seed in args.seeds:
                    best, planted, consistent, cached = _suite_case(args, name, base, ref_values, fraction, kind,
                                                                    seed)
                    label = f"{base.name} | {fraction:.0%} ({len(planted)}) | {kind} | {seed}"
                    star = "*" if cached else ""
                    for method in ("gtsam", "ours"):
                        b = best[method]
                        if b is None:
                            continue
                        title = "GTSAM GNC" if method == "gtsam" else "lie-factors"
                        if _timed_out(b):
                            records.append(_record(base.name, fraction, kind, seed, title, True, seconds=b[1]))
                            print(f"| {label} | GTSAM GNC | – | – | – | > {b[1]:.0f}{star} | – | – | – |", flush=True)
                            continue
                        P, sec, rejected, by, status = b
                        c = outliers.classify(rejected, planted)
                        # riSAM: a planted closure that fits the clean optimum counts neither way
                        keep = np.setdiff1d(planted, consistent)
                        c2 = outliers.classify(np.setdiff1d(rejected, consistent), keep)
                        stages = "–" if by is None else stage_counts(by)
                        err = map_error_percent(P, ref)
                        if status is not None:
                            stages += f"; {status['status']}"
                            if seed not in tuning:
                                flagged[err > 1.0].append(status["status"] == "uncertain")
                        records.append(_record(base.name, fraction, kind, seed, title, False, precision=c.precision,
                                               recall=c.recall, map_error=err, seconds=sec))
                        print(f"| {label} | {title} | {c.precision:.3f} | {c.recall:.3f} | {err:.3g} % | "
                              f"{sec:.2f}{star if method == 'gtsam' else ''} | {stages} | {len(consistent)} | "
                              f"{c2.precision:.3f}, {c2.recall:.3f} |", flush=True)
    _summary(records, tuning)
    print(f"\nours, seeds not in the tuning seeds: \"uncertain\" on {sum(flagged[True])} of {len(flagged[True])} "
          f"cases whose map ends > 1 % off, on {sum(flagged[False])} of {len(flagged[False])} within 1 %")
    return 0


#: The suite's methods as a sweep's: name → (title in the tables, the keywords of lf.optimize, or of
#: lf.replay for the online rejection). GTSAM's is its
#: GncOptimizer on its own factors (backend native, no consistency stage).
SWEEP_METHODS = {"gtsam-gnc": ("GTSAM GNC", 'backend = "native"\ngnc = "tls"\nconsistency = false'),
                 "lie-factors": ("lie-factors", 'gnc = "tls"'),
                 "lie-factors-online": ("lie-factors online", 'run = "replay"\ngnc = "tls"')}


def graph_path(name: str) -> str:
    """The g2o file of a suite graph's name (what :func:`load_graph` reads), for the sweep's spec:
    data/NAME.g2o, ``helixN`` written to the temp dir, or a GTSAM example's name."""
    if name.startswith("chain"):
        raise SystemExit("outliers.py: --sweep runs graphs from files; chainN is built in memory")
    if name.startswith("helix"):
        load_graph(name)  # writes the file
        return os.path.join(tempfile.gettempdir(), f"lie_factors_outliers_{name}.g2o")
    path = os.path.join(DATA, name + ".g2o")
    return path if os.path.exists(path) else name


def sweep_spec(args, fractions, kinds) -> str:
    """The suite as a sweep's spec (TOML): its graphs, kinds, fractions, seeds and both methods, GTSAM's
    abandoned after ``--native-timeout`` seconds (every case is, in the sweep)."""
    import json

    graphs = "\n".join(f"{json.dumps(n)} = {json.dumps(graph_path(n))}" for n in args.graphs)
    methods = [m for m in SWEEP_METHODS if not (args.no_native and m == "gtsam-gnc")]
    return (f"timeout = {args.native_timeout}\n[graphs]\n{graphs}\n[corruption]\nkinds = {json.dumps(kinds)}\n"
            f"fractions = {json.dumps(fractions)}\nseeds = {json.dumps(args.seeds)}\n"
            + "".join(f"[methods.{m}]\n{SWEEP_METHODS[m][1]}\n" for m in methods))


def suite_on_sweep(args, fractions, kinds) -> int:
    """The suite's cases as one sweep (:func:`lie_factors.sweep`): on a LocalCluster of ``--workers``
    or the cluster of ``--scheduler``, the rows in ``--sweep`` (a rerun resumes), then the suite's tables
    from them. One run per case (no ``--repeat``), GTSAM run (not read from ``--native-cache``)."""
    import lie_factors as lf
    from lie_factors.sweeps.spec import parse_spec

    if args.generator != "corrupt" or args.reuse_native or args.repeat != 1:
        raise SystemExit("outliers.py: --sweep plants with lf.corrupt (--generator corrupt), runs each case "
                         "once and GTSAM every time (no --repeat, --reuse-native)")
    spec = parse_spec(sweep_spec(args, fractions, kinds), os.path.join(DATA, "outliers-suite.toml"))
    rows = lf.sweep(spec, args.sweep, scheduler=args.scheduler, workers=args.workers, progress=True)
    order = {c: k for k, c in enumerate(sorted({r["case"] for r in rows}))}
    titles = {m: t for m, (t, _) in SWEEP_METHODS.items()}
    print("| graph | false | kind | seed | method | precision | recall | map error / diag | seconds | "
          "rejected by | planted consistent | precision, recall (riSAM) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    records = []
    for r in sorted(rows, key=lambda r: order[r["case"]]):
        title = titles.get(r["method"], r["method"])
        label = f"{r['graph']} | {r['fraction']:.0%} ({r['planted'] if r['planted'] is not None else '?'}) | " \
                f"{r['kind']} | {r['seed']}"
        records.append({**r, "method": title})
        if r["status"] != "ok":
            print(f"| {label} | {title} | – | – | – | {r['status']}: {r['error']} | – | – | – |")
            continue
        stages = r["rejected_by"] or "–"
        print(f"| {label} | {title} | {r['precision']:.3f} | {r['recall']:.3f} | {r['map_error']:.3g} % | "
              f"{r['seconds']:.2f} | {stages if title != 'GTSAM GNC' else '–'} | {r['planted_consistent']} | "
              f"{r['precision_consistent']:.3f}, {r['recall_consistent']:.3f} |")
    _summary(records, set(args.tuning_seeds))
    return 0


def tails(args) -> int:
    """The true closures' leave-one-out statistics at each graph's clean optimum, against χ²."""
    from lie_factors.robust.leave_out import leave_out_chi2
    from lie_factors.robust.statistics import chi2_inlier_threshold
    from lie_factors.interop import matrices_from_values

    print("# leave-one-out statistic T of every loop closure at the clean optimum (batch LM, chordal start)")
    print("| graph | loop closures | median T / median χ²_n | T quantile 0.99 / median | largest T / median |")
    print("|---|---|---|---|---|")
    for name in args.graphs:
        base = load_graph(name)
        pg = base.with_first_prior()
        values = reference_values(base)
        X = matrices_from_values(values, base.group, base.keys)
        lc = pg.loop_closures()
        T = leave_out_chi2(pg, X, np.ones(len(pg.edge_keys) + len(pg.prior_keys)), [lc[k:k + 1] for k in range(lc.size)])
        med = float(np.nanmedian(T))
        print(f"| {base.name} | {lc.size} | {med / (2 * chi2_inlier_threshold(pg.info.dim, 0.5)):.2g} | "
              f"{np.nanquantile(T, 0.99) / med:.1f} | {np.nanmax(T) / med:.1f} |", flush=True)
    return 0


def clean(args) -> int:
    """Every suite graph without planted closures: lie-factors' --gnc tls against plain LM."""
    import lie_factors as lf
    from lie_factors.backends import build_graph

    print("# the suite's graphs without false loop closures: --gnc tls (batch) against plain LM (batch)")
    print("| graph | loop closures | rejected (by stage) | GNC final error | LM final error | relative difference |")
    print("|---|---|---|---|---|---|")
    for name in args.graphs:
        base = load_graph(name)
        plain = lf.optimize(base)
        result = lf.optimize(base, gnc="tls")
        graph = build_graph(base, "native")
        e_gnc, e_lm = float(graph.error(result.values)), float(graph.error(plain.values))
        stages = stage_counts({str(k): v for k, v in result.rejected_by.items()})
        print(f"| {base.name} | {len(base.loop_closures())} | {len(result.outliers)}"
              f"{f' ({stages})' if stages else ''} | {e_gnc:.8g} | {e_lm:.8g} | {abs(e_gnc - e_lm) / e_lm:.1e} |",
              flush=True)
    return 0


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
    ap.add_argument("--suite", action="store_true",
                    help="the consistency suite: lie-factors' --gnc tls against GTSAM's GncOptimizer on "
                         f"every graph (default {' '.join(SUITE_GRAPHS)}), at --fractions, --kinds, --seeds")
    ap.add_argument("--fractions", nargs="+", type=float, help="with --suite (default 0.2 0.5)")
    ap.add_argument("--generator", default="corrupt", choices=sorted(GENERATORS),
                    help="with --suite: corrupt = lf.corrupt (kinds uniform, local, group, near; default), "
                         "testing = lie_factors.testing.outliers (uniform, clustered), the earlier tables'")
    ap.add_argument("--kinds", nargs="+", choices=sorted({k for ks in GENERATORS.values() for k in ks}),
                    help="with --suite: the kinds to plant (default: every kind of --generator)")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    ap.add_argument("--tuning-seeds", nargs="*", type=int, default=[0],
                    help="with --suite: the seeds the pipeline was developed on (default 0): their rows are "
                         "printed but left out of the worst/median summary")
    ap.add_argument("--no-native", action="store_true", help="with --suite: skip GTSAM's GncOptimizer")
    ap.add_argument("--clean", action="store_true",
                    help="the suite's graphs without false closures: --gnc tls against plain LM")
    ap.add_argument("--tails", action="store_true",
                    help="the true closures' leave-one-out statistics at each clean optimum, against χ²")
    ap.add_argument("--native-cache", default=NATIVE_CACHE,
                    help=f"with --suite: where GTSAM's results are stored (default {NATIVE_CACHE})")
    ap.add_argument("--reuse-native", action="store_true",
                    help="with --suite: read GTSAM's results from --native-cache where stored instead of "
                         "running it (its seconds are then from an earlier run: marked *)")
    ap.add_argument("--sweep", metavar="RESULTS",
                    help="with --suite: run its cases as one sweep (lf.sweep, Dask), a row per case in RESULTS "
                         "(.csv or .parquet; a rerun resumes), then print the tables from the rows")
    ap.add_argument("--scheduler", metavar="ADDRESS",
                    help="with --sweep: a running Dask scheduler (default: a LocalCluster on this machine)")
    ap.add_argument("--workers", type=int, help="with --sweep: the LocalCluster's worker processes "
                                                "(default: one per core)")
    args = ap.parse_args(argv)
    if args.tails:
        if args.graphs == list(GRAPHS):
            args.graphs = list(SUITE_GRAPHS)
        return tails(args)
    if args.clean:
        if args.graphs == list(GRAPHS):
            args.graphs = list(SUITE_GRAPHS)
        return clean(args)
    if args.suite:
        if args.graphs == list(GRAPHS):
            args.graphs = list(SUITE_GRAPHS)
        return suite(args)

    print(f"# outliers: {args.fraction:.0%} false loop closures (relative to the true ones), "
          f"seed {args.seed}, best of {args.repeat}")
    print("| graph | method | backend | iterations | seconds | RMSE [m] | RMSE / bbox diag | "
          "precision | recall | final error |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in args.graphs:
        pg, planted, ref, start = prepare(name, args.fraction, args.seed, start=args.start)
        print(f"# {pg.name}: start {start}", flush=True)
        diag = diagonal(ref)
        label = f"{pg.name} ({pg.pose_count} poses, {len(planted)} false / " \
                f"{len(pg.loop_closures()) - len(planted)} true LC)"
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
