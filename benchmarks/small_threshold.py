"""Where the small path stops paying: one compiled solve against the general loop on the shipped graphs.

    python benchmarks/small_threshold.py [--repeat 3] [--graphs smallGrid3D intel smallGrid3D:60 ...]

Each graph of ``data/`` (read with ``lf.read_g2o``, a prior on its first pose, the default command's start, GTSAM's default LM params) is solved by the batch solver's small path (its limit of
unknowns lifted for the measurement) and by its general loop (CHOLMOD), in one process after
one untimed run of each, alternated, best of ``--repeat``: the iterations (equal) and the
seconds of ``batch.optimize`` on the same problem.  ``NAME:k`` is the graph's first k poses and
the edges among them: sizes between the shipped graphs'.  What decides
``batch.small.MAX_UNKNOWNS``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GRAPHS = ["tinyGrid3D", "smallGrid3D", "intel", "MIT", "CSAIL", "parking-garage", "manhattan", "sphere2500",
          "smallGrid3D:20", "smallGrid3D:40", "smallGrid3D:60", "smallGrid3D:80", "smallGrid3D:100",
          "sphere2500:50", "sphere2500:100", "sphere2500:200", "sphere2500:300"]


def _prefix(pg, name: str):
    """The graph's first k poses and the edges among them, for ``NAME:k`` (else the graph)."""
    import dataclasses

    import numpy as np

    if ":" not in name:
        return pg
    k = int(name.partition(":")[2])
    keep = np.flatnonzero((pg.edge_keys < k).all(axis=1))
    pg = pg.with_edges(keep)
    return dataclasses.replace(pg, keys=pg.keys[:k], vertices=None if pg.vertices is None else pg.vertices[:k])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--graphs", nargs="+", default=GRAPHS)
    args = parser.parse_args()
    import lie_factors as lf
    from lie_factors.batch import small
    from lie_factors.batch.graph import Problem
    from lie_factors.batch.optimizer import BatchLevenbergMarquardt

    small.MAX_UNKNOWNS = 10**9
    print(f"load before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("| graph | unknowns | iterations | small path s | general loop s | small / general |")
    print("|---|---:|---:|---:|---:|---:|")
    for name in args.graphs:
        pg = _prefix(lf.read_g2o(str(ROOT / "data" / f"{name.partition(':')[0]}.g2o")), name).with_first_prior()
        X = lf.optimize(pg, max_iterations=0).poses  # the default command's start

        def run(solver):
            opt = BatchLevenbergMarquardt(Problem.from_pose_graph(pg, X), None, linear_solver=solver)
            return opt.optimize(values=False)

        runs = {"auto": run("auto"), "cholmod": run("cholmod")}
        assert runs["auto"].linear_solver == "small"
        best = {"auto": float("inf"), "cholmod": float("inf")}
        for _ in range(args.repeat):
            for solver in best:
                t = time.perf_counter()
                run(solver)
                best[solver] = min(best[solver], time.perf_counter() - t)
        n = len(pg.keys) * pg.info.dim
        its = f"{runs['auto'].iterations} / {runs['cholmod'].iterations}"
        print(f"| {name} | {n} | {its} | {best['auto']:.4f} | {best['cholmod']:.4f} | "
              f"{best['auto'] / best['cholmod']:.2f} |", flush=True)
    print(f"load after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
