"""Online replay through ISAM2, three ways:

- ``native``: GTSAM's own factors in ``gtsam.ISAM2``;
- ``plain``: lie_factors' factors in plain ``gtsam.ISAM2`` (every callback gets a copy of
  the whole Values: quadratic; cut off after ``--plain-limit`` seconds, and then compared
  with the other legs' time for the same number of updates);
- ``dropin``: lie_factors' factors in :class:`lie_factors.optimizers.ISAM2`.

Each replay is :func:`lie_factors.app.incremental.replay` (what ``lie-factors posegraph FILE
--incremental`` runs: poses in id order, one per update, GTSAM's default ISAM2Params).
The legs alternate (repeat ▸ dataset ▸ leg) and each reports its best of ``--repeat``.
Datasets: files (``--data-dir``) and ``helix``: a generated 10k-pose SE(3) helix that
revisits a place every 100 poses, odometry between consecutive poses and, at every 10th
pose, a loop closure to the pose 100 back; noise σ 0.01 rad / 0.05 m (seeded); its ATE
(RMSE of the positions against the ground truth, no alignment: the prior holds pose 0 at
the truth) is reported.

    python benchmarks/incremental.py [--data-dir DIR] [--datasets intel city10000 sphere2500 helix]
        [--legs native plain dropin] [--repeat 2] [--plain-limit 60] [--helix-poses 10000] [--cli]

``--cli`` instead times what a user runs: ``lie-factors posegraph FILE --incremental --backend
native|dropin --json`` in a fresh process each (wall seconds of the whole command, and its
update_seconds), alternating, best of ``--repeat``.
"""

from __future__ import annotations

import argparse
import math
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import gtsam  # noqa: E402
import numpy as np  # noqa: E402

from lie_factors import g2o
from lie_factors.app import incremental  # noqa: E402
from lie_factors.app.backends import build_graph  # noqa: E402
from lie_factors.app.load import load as load_dataset  # noqa: E402

DEFAULT_DATASETS = ["intel", "city10000", "sphere2500", "helix"]
LEGS = ("native", "plain", "dropin")
SIGMA_ROT, SIGMA_TRANS = 0.01, 0.05


def helix(poses: int, seed: int = 0, per_turn: int = 100, radius: float = 10.0, rise: float = 0.05):
    """The generated graph: (native graph, dead-reckoned initial Values, true Pose3 list)."""
    rng = np.random.default_rng(seed)
    truth = []
    for i in range(poses):
        a = 2 * math.pi * i / per_turn
        # Facing along the tangent; climbing `rise` per turn so the places repeat almost exactly.
        R = gtsam.Rot3.Yaw(a + math.pi / 2)
        truth.append(gtsam.Pose3(R, np.array([radius * math.cos(a), radius * math.sin(a), rise * i / per_turn])))
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([SIGMA_ROT] * 3 + [SIGMA_TRANS] * 3))
    sigmas = np.array([SIGMA_ROT] * 3 + [SIGMA_TRANS] * 3)

    def measure(i, j):
        return truth[i].between(truth[j]).compose(gtsam.Pose3.Expmap(rng.normal(size=6) * sigmas))

    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    initial.insert(0, truth[0])
    for i in range(1, poses):
        m = measure(i - 1, i)
        graph.add(gtsam.BetweenFactorPose3(i - 1, i, m, noise))
        initial.insert(i, initial.atPose3(i - 1).compose(m))
        if i % 10 == 0 and i >= per_turn:
            graph.add(gtsam.BetweenFactorPose3(i - per_turn, i, measure(i - per_turn, i), noise))
    return graph, initial, truth


def load(name: str, data_dir: str, tmp: str, helix_poses: int):
    """(Dataset, truth or None)."""
    if name == "helix":
        graph, initial, truth = helix(helix_poses)
        path = os.path.join(tmp, f"helix{helix_poses}.g2o")
        g2o.write_g2o(path, graph, initial)
        return load_dataset(path), truth
    for candidate in (os.path.join(data_dir, name + ".g2o"), os.path.join(data_dir, name), name):
        if os.path.isfile(candidate):
            return load_dataset(candidate), None
    return load_dataset(name), None


def ate(values: gtsam.Values, truth) -> float:
    err = [values.atPose3(i).translation() - T.translation() for i, T in enumerate(truth)]
    return float(np.sqrt(np.mean(np.sum(np.square(err), axis=1))))


def run_leg(pg, leg: str, graphs: dict, plain_limit: float):
    if leg == "native":
        return incremental.replay(pg, "native", graph=graphs["native"])
    if leg == "plain":
        return incremental.replay(pg, "dropin", graph=graphs["dropin"], isam_class=gtsam.ISAM2,
                                  max_seconds=plain_limit)
    return incremental.replay(pg, "dropin", graph=graphs["dropin"])


def cli_rows(datasets, data_dir: str, tmp: str, helix_poses: int, repeat: int) -> None:
    exe = os.path.join(os.path.dirname(sys.executable), "lie-factors")
    paths = {}
    for name in datasets:
        pg, _ = load(name, data_dir, tmp, helix_poses)
        paths[name] = pg.path
    best: dict = {}
    for _ in range(repeat):
        for name in datasets:
            for backend in ("native", "dropin"):
                t0 = time.perf_counter()
                out = subprocess.run([exe, "posegraph", paths[name], "--incremental", "--backend", backend,
                                      "--json", "--quiet"], check=True, capture_output=True, text=True).stdout
                wall = time.perf_counter() - t0
                d = json.loads(out.strip().splitlines()[-1])
                key = (name, backend)
                if key not in best or wall < best[key][0]:
                    best[key] = (wall, d)
    print("| graph | backend | command wall s | update_seconds | p99 ms | final error | wall × native |")
    print("|---|---|---|---|---|---|---|")
    for name in datasets:
        for backend in ("native", "dropin"):
            wall, d = best[(name, backend)]
            print(f"| {d['dataset']} | {backend} | {wall:.2f} | {d['update_seconds']:.3f} | "
                  f"{d['update_p99'] * 1e3:.2f} | {d['final_error']:.10g} | "
                  f"{wall / best[(name, 'native')][0]:.2f} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", default=str(ROOT / "data"), help="directory of the g2o files")
    ap.add_argument("--datasets", nargs="+", default=DEFAULT_DATASETS)
    ap.add_argument("--legs", nargs="+", default=list(LEGS), choices=LEGS)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--plain-limit", type=float, default=60.0)
    ap.add_argument("--helix-poses", type=int, default=10000)
    ap.add_argument("--cli", action="store_true", help="time the whole CLI command instead")
    args = ap.parse_args(argv)
    if args.cli:
        with tempfile.TemporaryDirectory() as tmp:
            cli_rows(args.datasets, args.data_dir, tmp, args.helix_poses, args.repeat)
        return 0

    with tempfile.TemporaryDirectory() as tmp:
        loaded = {}
        for name in args.datasets:
            pg, truth = load(name, args.data_dir, tmp, args.helix_poses)
            graphs = {"native": build_graph(pg, "native"), "dropin": build_graph(pg, "dropin")}
            loaded[name] = (pg, truth, graphs)
        best: dict = {}
        for r in range(args.repeat):
            for name in args.datasets:
                pg, truth, graphs = loaded[name]
                for leg in args.legs:
                    res = run_leg(pg, leg, graphs, args.plain_limit)
                    print(f"# repeat {r + 1} {name} {leg}: {res.updates} updates {res.update_seconds:.3f} s",
                          file=sys.stderr, flush=True)
                    key = (name, leg)
                    if key not in best or res.update_seconds < best[key].update_seconds:
                        best[key] = res
        print("| graph | poses | factors | leg | updates | total s | p50 ms | p99 ms | final error | ATE m "
              "| × native |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for name in args.datasets:
            pg, truth, graphs = loaded[name]
            native = best.get((name, "native"))
            for leg in args.legs:
                res = best[(name, leg)]
                done = res.updates
                ratio = ""
                if native is not None:
                    ref = float(native.times[:done].sum())
                    ratio = f"{res.update_seconds / ref:.2f}" + ("" if done == native.updates else
                                                                 f" (first {done} updates)")
                a = f"{ate(res.values, truth):.4f}" if truth is not None and done == pg.poses else ""
                err = "" if math.isnan(res.final_error) else f"{res.final_error:.10g}"
                print(f"| {pg.name} | {pg.poses} | {res.factors} | {leg} | {done} | {res.update_seconds:.3f} "
                      f"| {res.update_p50 * 1e3:.3f} | {res.update_p99 * 1e3:.3f} | {err} | {a} | {ratio} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
