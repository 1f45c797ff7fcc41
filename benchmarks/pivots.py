"""How far graphs that determine their variables stay from the pivot rule's threshold
(``lie_factors.sparse.pivots``: a pivot not above 1e-13 of its diagonal entry is refused).

    python benchmarks/pivots.py [--datasets intel city10000 sphere2500 manhattan kitti_00 torus3D parking-garage]

Each pose graph (``data/NAME.g2o``, else GTSAM's example file of that name; those found), with
the prior a run puts on its first pose, at its optimum (``lf.optimize``): the information
matrix H there, factored as the marginals factor it (CHOLMOD, supernodal, the batch solver's
order).  Prints a markdown row per graph:

* ``min pivot/diagonal``: the smallest pivot of that factorization over its diagonal entry of
  H, and its margin, that ratio over 1e-13;
* ``any order``: the smallest 1/(H_pp·(H⁻¹)_pp) over the scalars p (H⁻¹ from the marginals),
  and its margin.  The pivot of p in any elimination order is at least 1/(H⁻¹)_pp, so no order
  (the smoother's, another fill-reducing one) takes a pivot/diagonal below this.

A graph within 100 times of the threshold would be a reason to look at the rule again.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

DATASETS = ("intel", "city10000", "sphere2500", "manhattan", "kitti_00", "torus3D", "parking-garage")


def _path(name: str) -> str | None:
    """``data/NAME.g2o``, else GTSAM's example file ``NAME``, else None."""
    local = os.path.join(ROOT, "data", f"{name}.g2o")
    if os.path.exists(local):
        return local
    import gtsam

    try:
        return gtsam.findExampleDataFile(name)
    except (RuntimeError, IndexError):
        return None


def margins(path: str) -> dict:
    """The two ratios of the module docstring for the graph at ``path``, and its scalar count."""
    import lie_factors as lf
    from lie_factors.batch.graph import Problem
    from lie_factors.batch.system import LinearSystem
    from lie_factors.sparse import cholmod

    pg = lf.read_g2o(path)
    result = lf.optimize(pg)
    posed = pg.with_first_prior()
    system = LinearSystem(Problem.from_pose_graph(posed, result.poses))
    system.linearize_assemble()
    p = system.pattern
    factor = cholmod.Cholesky(p.colptr, p.rowind, natural=True, supernodal=True)
    factor.factorize(system.data)
    pivots, diagonal, _ = factor.pivots(system.data)
    covariances = result.covariances()  # (P, n, n), keys' order: the δ order of the pose graph's problem
    inverse_diagonal = np.einsum("kii->ki", covariances).reshape(-1)
    any_order = 1.0 / (system.hessian_diagonal() * inverse_diagonal)
    return {"n": p.n, "pivot": float(np.min(pivots / diagonal)), "any": float(np.min(any_order))}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", nargs="+", default=list(DATASETS))
    args = parser.parse_args(argv)
    from lie_factors.sparse.pivots import PIVOT_TOLERANCE

    print("| graph | scalars | min pivot/diagonal | margin | any order | margin |")
    print("|---|---:|---:|---:|---:|---:|")
    for name in args.datasets:
        path = _path(name)
        if path is None:
            print(f"| {name} | not found | | | | |")
            continue
        m = margins(path)
        print(f"| {name} | {m['n']} | {m['pivot']:.3g} | {m['pivot'] / PIVOT_TOLERANCE:.2g} | "
              f"{m['any']:.3g} | {m['any'] / PIVOT_TOLERANCE:.2g} |", flush=True)


if __name__ == "__main__":
    main()
