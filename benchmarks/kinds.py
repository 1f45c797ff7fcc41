"""Factor kinds (``lf.factor``): compile and load, one callback, and whole optimizations on GTSAM's
landmark and bundle-adjustment data against GTSAM's C++ factors.

    python benchmarks/kinds.py [--only compile|callback|optimize] [--repeat 3]

* ``compile``: fresh processes on one empty numba cache: the first kind (the package's kernels
  it calls compiled too), then a new kind (another residual: only its own kernel compiles), then
  that kind again (loaded from the cache; measured after a cached package kernel has run, so
  numba's own first-call cost is not counted).
* ``callback``: one ``factor.linearize(values)`` (GTSAM's call of a CustomFactor's callback,
  with pybind11's fixed cost), and one construction, best of 7 timeit runs, for our
  hand-written ``BetweenFactorPose3``, the ready factors, and GTSAM's C++ factors for scale.
* ``optimize``: on ``cityTrees_reduced_1k.g2o``, ``victoriaPark_reduced_1k.g2o``,
  ``known_landmark_localization_*.g2o``, ``victoria_park.txt`` (``lf.read_g2o``: GTSAM's landmark
  measurements become the ready factors) and the BAL files ``dubrovnik-*-pre.txt``
  (:mod:`lie_factors.expressions.bal`): ``lf.optimize`` (the batch solver, our factors), the
  drop-in LM on our factors (GTSAM's algorithm, our callbacks), and GTSAM's
  ``LevenbergMarquardtOptimizer`` on GTSAM's factors, from the same start, alternated, best of
  ``--repeat``; each side's final error, and the relative difference of ours from GTSAM's.
  Kernels are compiled before the clocks (a warm-up run).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
import timeit
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

COMPILE = r"""
import sys, time
import numpy as np
import lie_factors as lf
from lie_factors import se3
from lie_factors.expressions import ops
salt = float(sys.argv[1])
T = se3.exp(np.full(6, 0.1))
se3.log(T)  # a cached package kernel: numba's first-call cost, before the clock
t0 = time.perf_counter()
kind = lf.factor("Pose3", "Point3", measured="Point2", K="Cal3_S2")(
    lambda x, p, z, K: ops.project(x, p, K) - salt * z)
t1 = time.perf_counter()
import gtsam
v = gtsam.Values(); v.insert(1, gtsam.Pose3()); v.insert(2, np.array([0.1, 0.2, 3.0]))
f = kind(1, 2, np.zeros(2), gtsam.noiseModel.Unit.Create(2), K=np.array([500., 500., 0., 320., 240.]))
f.linearize(v)
t2 = time.perf_counter()
print(t1 - t0, t2 - t1)
"""


def compile_table(repeat: int) -> None:
    rows = {"first kind (its package kernels compiled too)": [], "a new kind": [], "that kind again (cache)": []}
    for r in range(repeat):
        with tempfile.TemporaryDirectory() as cache:
            env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=str(ROOT))

            def run(salt):
                out = subprocess.run([sys.executable, "-c", COMPILE, str(salt)], env=env, capture_output=True,
                                     text=True, check=True).stdout.split()
                return float(out[0]), float(out[1])

            rows["first kind (its package kernels compiled too)"].append(run(1.0 + r))
            rows["a new kind"].append(run(2.0 + r))
            rows["that kind again (cache)"].append(run(2.0 + r))
    print(f"A projection kind, fresh processes on one empty numba cache, best of {repeat}:\n")
    print("| | definition (trace, source) s | first evaluation s |\n|---|---|---|")
    for name, runs in rows.items():
        print(f"| {name} | {min(d for d, _ in runs):.3f} | {min(e for _, e in runs):.3f} |")


def callback_table() -> None:
    import gtsam

    from lie_factors.expressions import ready
    from lie_factors.factors import BetweenFactorPose3

    rng = np.random.default_rng(0)
    v = gtsam.Values()
    x3 = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3))
    v.insert(1, x3)
    v.insert(2, gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3)))
    p3 = x3.transformFrom(np.array([0.1, 0.2, 4.0]))
    v.insert(3, p3)
    v.insert(4, gtsam.Pose2(1.0, 2.0, 0.3))
    v.insert(5, np.array([3.0, 1.0]))
    K = gtsam.Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)
    n2, n3, n6 = (gtsam.noiseModel.Unit.Create(d) for d in (2, 3, 6))
    Z = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3))
    U3 = gtsam.Unit3(np.array([0, 0, 1.0]))
    z2, g3 = np.array([300.0, 200.0]), np.array([1.0, 2.0, 3.0])
    makers = {  # (ours, GTSAM's C++ factor), each a constructor call
        "BetweenFactorPose3 (hand-written)": (lambda: BetweenFactorPose3(1, 2, Z, n6),
                                              lambda: gtsam.BetweenFactorPose3(1, 2, Z, n6)),
        "BearingRangeFactor2D": (lambda: ready.BearingRangeFactor2D(4, 5, gtsam.Rot2(0.2), 2.0, n2),
                                 lambda: gtsam.BearingRangeFactor2D(4, 5, gtsam.Rot2(0.2), 2.0, n2)),
        "BearingRangeFactor3D": (lambda: ready.BearingRangeFactor3D(1, 3, U3, 4.0, n3),
                                 lambda: gtsam.BearingRangeFactor3D(1, 3, U3, 4.0, n3)),
        "GenericProjectionFactorCal3_S2": (lambda: ready.GenericProjectionFactorCal3_S2(z2, n2, 1, 3, K),
                                           lambda: gtsam.GenericProjectionFactorCal3_S2(z2, n2, 1, 3, K)),
        "GPSFactor": (lambda: ready.GPSFactor(1, g3, n3), lambda: gtsam.GPSFactor(1, g3, n3)),
    }
    pairs = {name: (ours(), theirs()) for name, (ours, theirs) in makers.items()}
    for ours, _ in pairs.values():
        ours.linearize(v)  # compile or load first
    N = 20000
    best, made = {}, {}
    for name, (ours, theirs) in pairs.items():
        best[name] = [min(timeit.repeat(lambda f=f: f.linearize(v), number=N, repeat=7)) / N * 1e6 for f in (ours, theirs)]
        made[name] = [min(timeit.repeat(make, number=N, repeat=7)) / N * 1e6 for make in makers[name]]
    base = best["BetweenFactorPose3 (hand-written)"][0]
    print("One `factor.linearize(values)` (GTSAM's call of the callback) and one construction, µs, "
          "best of 7 × 20 000:\n")
    print("| factor | ours µs | × our BetweenFactorPose3 | GTSAM's C++ µs | construction ours µs | GTSAM's µs |\n"
          "|---|---|---|---|---|---|")
    for name, (a, b) in best.items():
        print(f"| {name} | {a:.2f} | {a / base:.2f} | {b:.2f} | {made[name][0]:.2f} | {made[name][1]:.2f} |")


def _g2o_problems():
    import gtsam

    import lie_factors as lf

    names = ["cityTrees_reduced_1k.g2o", "victoriaPark_reduced_1k.g2o", "known_landmark_localization_20.g2o",
             "victoria_park.txt"]
    for name in names:
        pg = lf.read_g2o(gtsam.findExampleDataFile(name))
        yield name, pg


def optimize_table(repeat: int) -> None:
    import gtsam

    import lie_factors as lf
    from lie_factors import factors
    from lie_factors.expressions import bal

    rows = []
    params = gtsam.LevenbergMarquardtParams()
    for name, pg in _g2o_problems():
        start = lf.optimize(pg, max_iterations=0).start  # every side from the default command's start
        posed = pg.with_first_prior()
        rows.append(_race(name, posed.factor_graph(factors), posed.factor_graph(), start, repeat, params))
    for name in ("dubrovnik-3-7-pre.txt", "dubrovnik-3-7-18-pre.txt", "dubrovnik-1-1-pre.txt"):
        scene = gtsam.SfmData.FromBalFile(gtsam.findExampleDataFile(name))
        ours_graph, ours_initial = bal.graph_of(scene)
        native_graph, native_initial = bal.gtsam_graph_of(scene)
        rows.append(_race(name, ours_graph, native_graph, (ours_initial, native_initial), repeat, params))
    print(f"Whole optimizations (GTSAM's default LM parameters), in-process, kernels compiled before the "
          f"clocks, sides alternated, best of {repeat}:\n")
    print("| graph | factors | lf.optimize s | drop-in LM s | GTSAM LM (C++ factors) s | lf.optimize × GTSAM | "
          "drop-in × GTSAM | final error ours (GTSAM) | relative difference |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print("| {name} | {factors} | {ours:.3f} | {dropin:.3f} | {native:.3f} | {ratio:.2f} | {dratio:.2f} | "
              "{e_ours:.9g} ({e_native:.9g}) | {diff:.1e} |".format(**r))


def _race(name, ours_graph, native_graph, initial, repeat, params):
    import gtsam

    import lie_factors as lf
    from lie_factors.optimizers import LevenbergMarquardtOptimizer

    ours_initial, native_initial = initial if isinstance(initial, tuple) else (initial, initial)
    lf.optimize(ours_graph, ours_initial, params)  # compile (or load) before any clock
    LevenbergMarquardtOptimizer(ours_graph, ours_initial, params).optimize()
    best = {"ours": np.inf, "dropin": np.inf, "native": np.inf}
    out = {}
    for r in range(repeat):
        sides = ["ours", "dropin", "native"] if r % 2 == 0 else ["native", "dropin", "ours"]
        for side in sides:
            t = time.perf_counter()
            if side == "ours":
                out[side] = lf.optimize(ours_graph, ours_initial, params).values
            elif side == "dropin":
                out[side] = LevenbergMarquardtOptimizer(ours_graph, ours_initial, params).optimize()
            else:
                out[side] = gtsam.LevenbergMarquardtOptimizer(native_graph, native_initial, params).optimize()
            best[side] = min(best[side], time.perf_counter() - t)
    e_ours, e_native = ours_graph.error(out["ours"]), native_graph.error(out["native"])
    return dict(name=name, factors=int(ours_graph.size()), ours=best["ours"], dropin=best["dropin"],
                native=best["native"], ratio=best["ours"] / best["native"], dratio=best["dropin"] / best["native"],
                e_ours=e_ours, e_native=e_native, diff=abs(e_ours - e_native) / max(abs(e_native), 1e-300))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("compile", "callback", "optimize"), default=None)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    os.system("uptime")
    for name, run in (("compile", lambda: compile_table(args.repeat)), ("callback", callback_table),
                      ("optimize", lambda: optimize_table(args.repeat))):
        if args.only in (None, name):
            print(f"\n### {name}\n")
            run()
    os.system("uptime")
    return 0


if __name__ == "__main__":
    sys.exit(main())
