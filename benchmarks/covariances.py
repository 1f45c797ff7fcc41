"""Every pose's marginal covariance: lie_factors (``Result.covariances()``: the batch solver's factor,
selected inversion) against ``gtsam.Marginals`` plus ``marginalCovariance`` for every key; and the
memory of the covariances of a large graph against the optimizer's own peak.

    python benchmarks/covariances.py [--datasets city10000 intel sphere2500] [--repeat 5]
    python benchmarks/covariances.py --memory 100000 [--seed 0]

Timing: each graph optimized once by the default command; then, in one process, the two
computations alternated ``--repeat`` times at the same estimate, best of each, and the largest
relative difference ‖C − C_gtsam‖_F / ‖C_gtsam‖_F over the keys (GTSAM on the graph of
lie_factors' factors, whose Jacobians the batch solver's are); ``path solves``: the alternative,
one sparse solve per pose (:func:`path_solves`).  ``first call`` is the same
``result.covariances()`` once, in a fresh process after the optimization, as a user's script
meets it (loading the compiled kernels from the cache included).

Memory (``--memory N``): a generated SE(3) helix of N poses (benchmarks/generate_posegraph.py,
``--seed``) in a fresh process: the peak resident size through reading and the default
optimization, then the peak reset (Linux ``clear_refs``) and the peak through
``result.covariances()`` alone, the estimate and the result still held.
Prints markdown rows for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
ENV = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))

FIRST_CALL = """
import json, sys, time
import lie_factors as lf
result = lf.optimize(lf.read_g2o(sys.argv[1]))
t = time.perf_counter()
result.covariances()
print(json.dumps({"first": time.perf_counter() - t}))
"""

MEMORY = """
import json, sys, time
import lie_factors as lf
from lie_factors.util.memory import usage
result = lf.optimize(lf.read_g2o(sys.argv[1]))
optimizer_peak = usage()[1]
with open("/proc/self/clear_refs", "w") as fh:
    fh.write("5")  # the peak resident size starts again from the present one
held = usage()[0]
t = time.perf_counter()
covs = result.covariances()
seconds = time.perf_counter() - t
print(json.dumps({"optimizer_peak": optimizer_peak, "held": held, "covariance_peak": usage()[1],
                  "seconds": seconds, "optimize_seconds": result.seconds, "poses": len(covs)}))
"""


def _run(script: str, *args) -> dict:
    p = subprocess.run([sys.executable, "-c", script, *args], env=ENV, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"failed: {p.stderr.strip()[-800:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def path_solves(posed, poses):
    """The alternative to selected inversion: each pose's block of H⁻¹ from its own sparse solve,
    L⁻¹ along the pose's path to the root of the elimination tree (the kernel of the
    leave-out test, lie_factors.robust.leave_out.group_gram, threads as numba gives it)."""
    import numpy as np

    from lie_factors.batch.graph import Problem
    from lie_factors.batch.system import LinearSystem
    from lie_factors.robust.leave_out import group_gram
    from lie_factors.sparse.cholmod import Cholesky

    problem = Problem.from_pose_graph(posed, poses)
    system = LinearSystem(problem)
    system.linearize_assemble()
    p = system.pattern
    factor = Cholesky(p.colptr, p.rowind)
    factor.factorize(system.data)
    row_of = np.empty(p.n, dtype=np.int64)
    row_of[p.scalar_order] = np.arange(p.n)
    V, d = len(problem.var_dims), int(problem.var_dims[0])
    unit = np.broadcast_to(np.eye(d), (V, d, d)).copy()
    o = problem.var_offsets
    return np.array(group_gram(factor, row_of, o, o, unit, np.zeros_like(unit), [[v] for v in range(V)]))


def timing(names: list[str], repeat: int) -> None:
    import gtsam
    import numpy as np

    import lie_factors as lf
    from lie_factors import factors

    print("| graph | poses | lie_factors s (best of %d) | gtsam.Marginals s | ratio | first call s (fresh process) "
          "| path solves s | max rel. difference |\n|---|---|---|---|---|---|---|---|" % repeat)
    for name in names:
        path = os.path.join(ROOT, "data", f"{name}.g2o")
        pg = lf.read_g2o(path)
        result = lf.optimize(pg)
        posed, keys, values = pg.with_first_prior(), result.keys, result.values
        graph = posed.factor_graph(factors)
        ours, theirs, paths = [], [], []
        for _ in range(repeat):
            t = time.perf_counter()
            covs = lf.Marginals.of_pose_graph(posed, result.poses).covariances(keys)  # what Result.covariances runs
            ours.append(time.perf_counter() - t)
            t = time.perf_counter()
            m = gtsam.Marginals(graph, values)
            ref = np.array([m.marginalCovariance(int(k)) for k in keys])
            theirs.append(time.perf_counter() - t)
            t = time.perf_counter()
            path_solves(posed, result.poses)
            paths.append(time.perf_counter() - t)
        diff = float(np.max(np.linalg.norm(covs - ref, axis=(1, 2)) / np.linalg.norm(ref, axis=(1, 2))))
        first = _run(FIRST_CALL, path)["first"]
        print(f"| {name} | {len(keys)} | {min(ours):.3f} | {min(theirs):.3f} | {min(ours) / min(theirs):.3f} | "
              f"{first:.3f} | {min(paths):.3f} | {diff:.1e} |", flush=True)


def memory(poses: int, seed: int) -> None:
    sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
    from generate_posegraph import generate, write_g2o

    from lie_factors.util.memory import size

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, f"helix{poses}.g2o")
        write_g2o(path, *generate(poses, seed=seed))
        r = _run(MEMORY, path)
    print("| graph | optimizer peak | held after | covariances peak | ratio | covariances s | optimization s |\n"
          "|---|---|---|---|---|---|---|")
    print(f"| helix {poses} (seed {seed}) | {size(r['optimizer_peak'])} | {size(r['held'])} | "
          f"{size(r['covariance_peak'])} | {r['covariance_peak'] / r['optimizer_peak']:.2f} | {r['seconds']:.2f} | "
          f"{r['optimize_seconds']:.2f} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", nargs="+", default=["city10000", "intel", "sphere2500"])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--memory", type=int, metavar="POSES", help="the memory figure on a helix of POSES poses instead")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.2f}")
    if a.memory:
        memory(a.memory, a.seed)
    else:
        timing(a.datasets, a.repeat)
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
