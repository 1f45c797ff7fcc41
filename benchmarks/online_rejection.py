"""The online rejection's cost against the clean replay: ``lf.replay(graph, gnc="tls")`` on graphs
with planted false closures, beside ``lf.replay`` of the same graph without them, in one process,
alternated, best of ``--repeat``.

For each case: the updates' total and p99 (each update: the known inliers, the tests, the smoother
taking the decision, reading the new pose back), the end's settling (every decision tested again
at the solution), the whole replay, each as a ratio to the clean replay's; and how good the final
map is (precision, recall, map error against the clean optimum and against the clean replay, in %
of the clean optimum's diagonal). ``--during K``: instead, the map during the run, every K-th
update, against the clean replay's at the same update (the share of updates within 1 % of the
clean optimum's diagonal, and the worst).  ``--rerun``: instead, the online leg's reference, Kimera-RPGO's
strategy run with GTSAM's own ``GncLMOptimizer``: the same replay, and at each update that brings a
loop closure GNC again on the whole graph so far (odometry and the prior known inliers, TLS, GTSAM's
thresholds), from the previous estimate with the new poses composed along the odometry; its total
GNC seconds against the online replay's update seconds, and both runs' precision, recall and map
(a reference run past ``--rerun-limit`` seconds stops, and its row says so).  ``--commands``:
instead, what a user runs, each command in a fresh process, alternated, best of ``--repeat``: the
clean ``posegraph FILE --incremental``, then ``--incremental --gnc tls`` and the batch ``--gnc tls``
on the graph ``lie-factors corrupt`` writes (each graph, kind, fraction and seed).

    python benchmarks/online_rejection.py --graphs intel smallGrid3D --kinds uniform group \\
        --fractions 0.2 --seeds 4 5 6 [--during 10 | --rerun | --commands]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

import lie_factors as lf  # noqa: E402
from lie_factors import corruption  # noqa: E402
from lie_factors.sweeps import metrics  # noqa: E402
from lie_factors.testing.outliers import classify  # noqa: E402

DATA = os.path.join(os.path.dirname(HERE), "data")


def timed(run):
    """(the run's result, its whole wall-clock seconds)."""
    t = time.perf_counter()
    r = run()
    return r, time.perf_counter() - t


def recording(every: int, robust: str | None):
    """A smoother that keeps the positions of every pose so far at each ``every``-th update (when
    the replay reads the new pose back): the map during the run."""
    from lie_factors.incremental import Smoother

    class Recording(Smoother):
        def __init__(self):
            super().__init__(robust=robust)
            self.seen: list = []
            self.maps: dict = {}

        def estimate_matrix(self, key):
            self.seen.append(int(key))
            if len(self.seen) % every == 0:
                self.maps[len(self.seen)] = metrics.positions(self.estimate_matrices(self.seen))
            return super().estimate_matrix(key)

    return Recording()


def during(pg, corrupted, diagonal: float, every: int) -> tuple[float, float]:
    """(fraction of the sampled updates whose map is within 1 % of the clean replay's at the same
    update, the worst such map error in % of ``diagonal``)."""
    from lie_factors.incremental.replay import replay_arrays

    clean, robust = recording(every, None), recording(every, "tls")
    replay_arrays(pg, clean)
    replay_arrays(corrupted, robust, gnc="tls")
    errors = np.array([100 * metrics.rmse(robust.maps[n], clean.maps[n]) / diagonal for n in sorted(clean.maps)])
    return float(np.mean(errors <= 1.0)), float(errors.max())


def rerun_reference(pg, limit: float):
    """Kimera-RPGO's strategy with GTSAM's GNC on the corrupted pose graph ``pg``: (estimate as
    (P, m, m), rejected edge indices, GNC seconds in all, GNC runs, finished within ``limit``)."""
    import gtsam

    from lie_factors.backends import build_graph
    from lie_factors.interop import to_gtsam
    from lie_factors.robust.gnc import GncSettings
    from lie_factors.robust.inner import gtsam_gnc

    full = build_graph(pg, "native")  # edge k is factor k; then the first pose's prior
    closures = set(pg.loop_closures().tolist())
    by_pose: dict = {}
    for k in range(full.size()):
        by_pose.setdefault(max(full.at(k).keys()), []).append(k)
    odometry = {int(b): k for k, (a, b) in enumerate(pg.edge_keys.tolist()) if b == a + 1}
    at = getattr(gtsam.Values, "atPose3" if pg.is3d else "atPose2")
    graph, slots, values = gtsam.NonlinearFactorGraph(), [], gtsam.Values()
    rejected, seconds, runs = [], 0.0, 0
    start = pg.start_poses
    for i, key in enumerate(pg.keys.tolist()):
        mine = by_pose.get(key, [])
        for k in mine:
            graph.add(full.at(k))
            slots.append(k)
        k = odometry.get(key)
        X = at(values, key - 1).matrix() @ pg.measured[k] if k is not None and values.exists(key - 1) else start[i]
        values.insert(key, to_gtsam(pg.group, X))
        if any(k in closures for k in mine):
            known = [q for q, k in enumerate(slots) if k not in closures]
            t = time.perf_counter()
            res = gtsam_gnc(graph, values, GncSettings(loss="tls", known_inliers=known,
                                                       lm_params=gtsam.LevenbergMarquardtParams()))
            seconds += time.perf_counter() - t
            runs += 1
            values = res.values
            rejected = [slots[q] for q in np.asarray(res.outliers).tolist()]
            if seconds > limit:
                break
    done = values.size() == len(pg.keys)
    X = np.array([at(values, k).matrix() for k in pg.keys.tolist() if values.exists(k)])
    return X, rejected, seconds, runs, done


def cases(args, warm):
    """Every case of ``args`` (graphs × kinds × fractions × seeds): (graph name, clean pose graph,
    its optimum, the optimum's positions, kind, fraction, seed, the planted corruption); ``warm(pg)``
    runs once per graph before its first case (compiled and loaded before any clock)."""
    for name in args.graphs:
        pg = lf.read_g2o(os.path.join(DATA, name + ".g2o"))
        clean = lf.optimize(pg)
        ref = metrics.positions(clean.poses)
        warm(pg)
        for kind in args.kinds:
            for fraction in args.fractions:
                for seed in args.seeds:
                    c = corruption.plant(pg, fraction=fraction, kind=kind, seed=seed, reference=clean.poses)
                    yield name, pg, clean, ref, kind, fraction, seed, c


def main_rerun(args) -> int:
    print("| graph | kind | false | seed | reference: GNC runs | reference GNC s | ours: update s | ours / reference "
          "| precision ref / ours | recall ref / ours | map ref / ours |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, pg, clean, ref, kind, fraction, seed, c in cases(args, lambda pg: lf.replay(pg, gnc="tls")):
        ours = min((lf.replay(c.graph, gnc="tls") for _ in range(args.repeat)),
                   key=lambda r: r.update_seconds)
        X, rejected, seconds, runs, done = rerun_reference(c.graph, args.rerun_limit)
        kr, ko = classify(rejected, c.planted), classify(ours.outliers, c.planted)
        map_ref = (f"{metrics.map_error_percent(metrics.positions(X), ref):.3g} %" if done
                   else f"stopped at {len(X)} of {len(pg.keys)} poses")
        map_ours = metrics.map_error_percent(metrics.positions(ours.poses), ref)
        stopped = "" if done else " (stopped)"
        print(f"| {name} | {kind} | {fraction:.0%} | {seed} | {runs} | {seconds:.2f}{stopped} "
              f"| {ours.update_seconds:.2f} | {ours.update_seconds / seconds:.3f}× "
              f"| {kr.precision:.3f} / {ko.precision:.3f} | {kr.recall:.3f} / {ko.recall:.3f} "
              f"| {map_ref} / {map_ours:.3g} % |", flush=True)
    print(f"\nload average at the end: {os.getloadavg()[0]:.2f}")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--graphs", nargs="+", default=["intel", "CSAIL", "MIT", "smallGrid3D"])
    ap.add_argument("--kinds", nargs="+", default=["uniform", "local", "group"])
    ap.add_argument("--fractions", nargs="+", type=float, default=[0.2])
    ap.add_argument("--seeds", nargs="+", type=int, default=[4, 5, 6])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--during", type=int, metavar="K",
                    help="instead of the timings: the map during the run against the clean replay's, at every "
                         "K-th update")
    ap.add_argument("--rerun", action="store_true",
                    help="instead: GTSAM's GNC re-run on the whole graph at each closure update (Kimera-RPGO's "
                         "strategy) against the online replay")
    ap.add_argument("--rerun-limit", type=float, default=600.0, metavar="SECONDS",
                    help="stop a reference run once its GNC seconds pass this")
    ap.add_argument("--commands", action="store_true",
                    help="instead: the whole CLI commands, each in a fresh process, against the clean one")
    args = ap.parse_args(argv)
    if args.during:
        return main_during(args)
    if args.commands:
        return main_commands(args)
    if args.rerun:
        return main_rerun(args)
    print("| graph | kind | false | seed | precision | recall | map vs clean optimum | map vs clean replay "
          "| updates / clean | p99 / clean | settle s | whole / clean | status |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, pg, clean, ref, kind, fraction, seed, c in cases(args, lf.replay):
        base, base_whole, robust, robust_whole = None, np.inf, None, np.inf
        for _ in range(args.repeat):  # alternated; the best update time and whole time of each
            r, w = timed(lambda: lf.replay(pg))
            if base is None or r.update_seconds < base.update_seconds:
                base = r
            base_whole = min(base_whole, w)
            r, w = timed(lambda: lf.replay(c.graph, gnc="tls"))
            if robust is None or r.update_seconds < robust.update_seconds:
                robust = r
            robust_whole = min(robust_whole, w)
        k = classify(robust.outliers, c.planted)
        P = metrics.positions(robust.poses)
        settle = robust.seconds - float(np.sum(robust.times))
        print(f"| {name} | {kind} | {fraction:.0%} | {seed} | {k.precision:.3f} | {k.recall:.3f} | "
              f"{metrics.map_error_percent(P, ref):.3g} % | "
              f"{100 * metrics.rmse(P, metrics.positions(base.poses)) / metrics.diagonal(ref):.3g} % | "
              f"{robust.update_seconds / base.update_seconds:.1f}× | "
              f"{robust.update_p99 / base.update_p99:.1f}× | {settle:.2f} | "
              f"{robust_whole / base_whole:.1f}× | {robust.robust_status['status']} |", flush=True)
    print(f"\nload average at the end: {os.getloadavg()[0]:.2f}")
    return 0


def _cli_seconds(*argv) -> float:
    """Wall seconds of ``lie-factors ARGV --quiet`` in a fresh process (it must succeed)."""
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "lie_factors.app.cli", *argv, "--quiet"], check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t


def main_commands(args) -> int:
    print("| graph | kind | false | seed | clean `--incremental` s | `--incremental --gnc tls` s | ratio "
          "| batch `--gnc tls` s |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.graphs:
            clean = os.path.join(DATA, name + ".g2o")
            for kind in args.kinds:
                for fraction in args.fractions:
                    for seed in args.seeds:
                        bad = os.path.join(tmp, "bad.g2o")
                        subprocess.run([sys.executable, "-m", "lie_factors.app.cli", "corrupt", clean, bad,
                                        "--fraction", str(fraction), "--kind", kind, "--seed", str(seed)],
                                       check=True, stdout=subprocess.DEVNULL)
                        best = [np.inf] * 3
                        for _ in range(args.repeat):  # alternated
                            for i, argv in enumerate((("posegraph", clean, "--incremental"),
                                                      ("posegraph", bad, "--incremental", "--gnc", "tls"),
                                                      ("posegraph", bad, "--gnc", "tls"))):
                                best[i] = min(best[i], _cli_seconds(*argv))
                        print(f"| {name} | {kind} | {fraction:.0%} | {seed} | {best[0]:.2f} | {best[1]:.2f} "
                              f"| {best[1] / best[0]:.1f}× | {best[2]:.2f} |", flush=True)
    print(f"\nload average at the end: {os.getloadavg()[0]:.2f}")
    return 0


def main_during(args) -> int:
    print("| graph | kind | false | seed | updates within 1 % of the clean replay's | worst map error during the run |")
    print("|---|---|---|---|---|---|")
    for name, pg, clean, ref, kind, fraction, seed, c in cases(args, lambda pg: None):
        diagonal = metrics.diagonal(ref)
        within, worst = during(pg, c.graph, diagonal, args.during)
        print(f"| {name} | {kind} | {fraction:.0%} | {seed} | {within:.1%} | {worst:.3g} % |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
