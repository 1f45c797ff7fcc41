"""Drop-in optimizers with our factors vs GTSAM's optimizers with GTSAM's factors.

For each dataset: the file's graph + GTSAM's g2o-example prior on the first
pose, started from the file's values; default params.  Per round, alternated:

* ``gtsam``: ``gtsam.<Optimizer>(graph with gtsam.BetweenFactorPose*, ...).optimize()``
* ``dropin``: ``lie_factors.optimizers.<Optimizer>(graph with lie_factors factors, ...).optimize()``

Timed: construction + ``optimize()`` (what a user runs), best of ``--rounds``.
Numba kernels are warmed before the clock (a fresh process loads them from
the on-disk cache).  Also prints iterations and final errors of both.

    python benchmarks/optimizers.py [--rounds 3] [--optimizers lm,gn,dogleg] [datasets...]
"""

from __future__ import annotations

import argparse
import os
import time

import gtsam
import numpy as np

from lie_factors import factors, g2o, optimizers
from lie_factors.optimizers import compat

DATA = os.environ.get("LIE_FACTORS_DATA", os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data"))
PRIOR_3D = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4]))
PRIOR_2D = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))

OPTIMIZERS = {
    "lm": ("LevenbergMarquardtOptimizer", gtsam.LevenbergMarquardtParams),
    "gn": ("GaussNewtonOptimizer", gtsam.GaussNewtonParams),
    "dogleg": ("DoglegOptimizer", gtsam.DoglegParams),
}


def graphs(path: str):
    """(native graph, graph with our factors, initial values) of a g2o file: its edges as
    GTSAM reads them, then GTSAM's g2o-example prior on the first pose at its file value."""
    summary = g2o.check_g2o(path)
    native, initial = g2o.read_with_gtsam(path, summary)
    group = summary.group
    first = min(initial.keys())
    prior = getattr(gtsam, f"PriorFactor{group}")
    native.add(prior(first, getattr(initial, f"at{group}")(first), PRIOR_3D if summary.is3d else PRIOR_2D))
    return native, compat.from_gtsam_graph(native), initial


def run(cls, graph, initial, params_type):
    t = time.perf_counter()
    opt = cls(graph, initial, params_type())
    opt.optimize()
    return time.perf_counter() - t, opt.iterations(), opt.error()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("datasets", nargs="*", default=["sphere2500", "city10000", "torus3D"])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--optimizers", default="lm")
    args = ap.parse_args(argv)
    print(f"load average: {os.getloadavg()}")
    print(f"{'dataset':12s} {'optimizer':6s} {'gtsam s':>8s} {'drop-in s':>9s} {'ratio':>6s} "
          f"{'iters g/d':>9s} {'final error gtsam':>18s} {'final error drop-in':>20s}")
    for name in args.datasets:
        path = name if os.path.exists(name) else os.path.join(DATA, f"{name}.g2o")
        native, ours, initial = graphs(path)
        factors.warm_up_constructed()
        for key in args.optimizers.split(","):
            cls_name, params_type = OPTIMIZERS[key]
            best = {"gtsam": (float("inf"),), "dropin": (float("inf"),)}
            for _ in range(args.rounds):
                for side, cls, graph in (("gtsam", getattr(gtsam, cls_name), native),
                                         ("dropin", getattr(optimizers, cls_name), ours)):
                    r = run(cls, graph, initial, params_type)
                    if r[0] < best[side][0]:
                        best[side] = r
            g, d = best["gtsam"], best["dropin"]
            print(f"{os.path.basename(name):12s} {key:6s} {g[0]:8.3f} {d[0]:9.3f} {d[0] / g[0]:6.2f} "
                  f"{g[1]:4d}/{d[1]:<4d} {g[2]:18.10g} {d[2]:20.10g}", flush=True)


if __name__ == "__main__":
    main()
