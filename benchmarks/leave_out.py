"""The final check's statistics (``lie_factors.robust.leave_out.leave_out_chi2``): the groups in the
graph on paths, by selected inversion, and as the rule chooses, at one graph state per benchmark
graph.

    python benchmarks/leave_out.py [--graphs intel CSAIL manhattan smallGrid3D sphere2500 torus3D]
        [--kind group] [--fraction 0.2] [--seed 4] [--repeat 3]

The state: the clean optimum of the graph (the default command), with ``lf.corrupt``'s false
closures of ``--kind``, ``--fraction``, ``--seed`` planted out of the graph (weight 0); the
groups: every closure alone, in the graph and out of it, and every group of two or more
(:func:`lie_factors.robust.rejection.closure_groups`), as a round of the final check tests them.
The three ways alternate ``--repeat`` times in one process after a first call of each (the
kernels loaded), best of each.  ``max rel``: the largest relative difference between the
statistics of the two ways.  Prints markdown rows for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import numpy as np  # noqa: E402

import lie_factors as lf  # noqa: E402
from lie_factors import corruption  # noqa: E402
from lie_factors.robust import leave_out  # noqa: E402
from lie_factors.robust.rejection import closure_groups  # noqa: E402

RULE = leave_out._selected_inverse_is_cheaper


def state(name: str, kind: str, fraction: float, seed: int):
    """(graph, poses, weights, groups) of one benchmark graph (module docstring)."""
    pg = lf.read_g2o(os.path.join(ROOT, "data", name + ".g2o"))
    X = np.asarray(lf.optimize(pg).poses)
    c = corruption.plant(pg, fraction=fraction, kind=kind, seed=seed, reference=X)
    g = c.graph if len(c.graph.prior_keys) else c.graph.with_first_prior()
    lc = g.loop_closures()
    w = np.ones(len(g.edge_keys) + len(g.prior_keys))
    w[c.planted] = 0.0
    accepted, rejected = np.setdiff1d(lc, c.planted), np.asarray(c.planted)
    groups = [accepted[k:k + 1] for k in range(accepted.size)] + [rejected[k:k + 1] for k in range(rejected.size)]
    groups += [G for G in closure_groups(g, accepted) if len(G) > 1]
    groups += [G for G in closure_groups(g, rejected) if len(G) > 1]
    return g, X, w, groups, accepted.size


def timed(way, args) -> tuple[float, np.ndarray]:
    leave_out._selected_inverse_is_cheaper = way
    t = time.perf_counter()
    T = leave_out.leave_out_chi2(*args)
    return time.perf_counter() - t, T


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--graphs", nargs="+", default=["intel", "CSAIL", "manhattan", "smallGrid3D", "sphere2500",
                                                    "torus3D"])
    ap.add_argument("--kind", default="group")
    ap.add_argument("--fraction", type=float, default=0.2)
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    chosen: list = []

    def rule(*a):
        chosen.append(RULE(*a))
        return chosen[-1]

    ways = {"paths": lambda *a: False, "selected inversion": lambda *a: True, "rule": rule}
    print("| graph | groups (closures in the graph) | paths s | selected inversion s | rule s (its choice) | max rel |")
    print("|---|---|---|---|---|---|")
    for name in args.graphs:
        g, X, w, groups, inside = state(name, args.kind, args.fraction, args.seed)
        call = (g, X, w, groups)
        best = {k: np.inf for k in ways}
        out = {}
        for k, way in ways.items():  # the first call of each loads its kernels
            out[k] = timed(way, call)[1]
        for _ in range(args.repeat):
            for k, way in ways.items():
                best[k] = min(best[k], timed(way, call)[0])
        a, b = out["paths"], out["selected inversion"]
        ok = np.isfinite(a) & np.isfinite(b)
        rel = float(np.max(np.abs(a[ok] - b[ok]) / np.abs(a[ok]))) if ok.any() else float("nan")
        pick = "selected inversion" if chosen[-1] else "paths"
        print(f"| {name} | {len(groups)} ({inside}) | {best['paths']:.3f} | {best['selected inversion']:.3f} | "
              f"{best['rule']:.3f} ({pick}) | {rel:.1e} |", flush=True)
    leave_out._selected_inverse_is_cheaper = RULE
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
