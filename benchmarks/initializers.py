"""GTSAM's initializers vs ours (lie_factors.initialization.chordal / lago: the same results on arrays), side by side.

    python benchmarks/initializers.py --repeat 3

Per graph (its pose graph and the prior ``lie-factors posegraph`` puts on the first
pose), alternating within each repetition, best of ``--repeat``:

* ``gtsam``: ``InitializePose3.initialize`` (3-D), ``lago.initialize`` (2-D,
  diagonal noise), or ``InitializePose3.initialize`` on the planar Pose3 graph
  (2-D with full covariances, lie_factors' rule) — run on a large-stack thread
  (lie_factors.util.stack), on GTSAM's own factor graph built beforehand;
* ``arrays``: ours, :func:`lie_factors.initialization.chordal.initialize` /
  :func:`lie_factors.initialization.lago.initialize_pose2`, on the pose graph;
* ``initialize()``: :func:`lie_factors.initialization.initialize` on the pose graph
  (as the CLI calls it) with ``engine="gtsam"`` (GTSAM's graph built inside, what
  ``--backend native`` runs) and with ours (the default backend's).

Also max relative difference of the two answers (max|Δ| / max(1, max|ref|)).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import gtsam  # noqa: E402

from lie_factors import initialization as LI  # noqa: E402
from lie_factors.util import stack  # noqa: E402
from lie_factors.g2o import read_pose_graph  # noqa: E402
from lie_factors.initialization import chordal, lago  # noqa: E402
from lie_factors.initialization.planar import planar_pose3  # noqa: E402
from lie_factors.interop import matrices_from_values  # noqa: E402
from lie_factors.posegraph.graph import PoseGraph  # noqa: E402

DATA = os.environ.get("LIE_FACTORS_DATA", os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data"))
DEFAULT = ["sphere2500", "torus3D", "city10000", "intel", "kitti_00"]


def _xytheta(X):
    return np.stack([X[:, 0, 2], X[:, 1, 2], np.arctan2(X[:, 1, 0], X[:, 0, 0])], axis=1)


def best(fn, repeat):
    out, t = None, float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        t = min(t, time.perf_counter() - t0)
    return out, t


def run(name, repeat):
    path = name if os.path.exists(name) else os.path.join(DATA, name + ".g2o")
    pg = read_pose_graph(path).with_first_prior()  # the edges, then the prior on the first pose
    n = len(pg.keys)
    diagonal = bool(np.all(np.abs(pg.information - np.einsum("kii->ki", pg.information)[:, :, None] * np.eye(3))
                           <= lago.GTSAM_DIAGONAL_TOL)) if not pg.is3d else False
    if pg.is3d:
        method, init_method = "chordal (InitializePose3)", "chordal"
        graph = pg.factor_graph()
        g_call = lambda: stack.call(gtsam.InitializePose3.initialize, graph)  # noqa: E731
        a_call = lambda: chordal.initialize(pg)  # noqa: E731
        as_arr = lambda v: matrices_from_values(v, "Pose3", pg.keys)  # noqa: E731
    elif diagonal:
        method, init_method = "lago", "lago"
        graph = pg.factor_graph()
        g_call = lambda: stack.call(gtsam.lago.initialize, graph, True)  # noqa: E731
        a_call = lambda: _xytheta(lago.initialize_pose2(pg))  # noqa: E731
        as_arr = lambda v: _xytheta(matrices_from_values(v, "Pose2", pg.keys))  # noqa: E731
    else:
        method, init_method = "chordal, planar Pose3", "chordal"
        graph = planar_pose3(pg).factor_graph()
        g_call = lambda: stack.call(gtsam.InitializePose3.initialize, graph)  # noqa: E731
        a_call = lambda: _xytheta(chordal.initialize(pg))  # noqa: E731
        as_arr = lambda v: (lambda T: np.stack([T[:, 0, 3], T[:, 1, 3], np.arctan2(T[:, 1, 0], T[:, 0, 0])], 1))(  # noqa: E731
            matrices_from_values(v, "Pose3", pg.keys))
    tg = ta = tig = tia = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        ref = g_call()
        tg = min(tg, time.perf_counter() - t0)
        t0 = time.perf_counter()
        ours = a_call()
        ta = min(ta, time.perf_counter() - t0)
        t0 = time.perf_counter()
        LI.initialize(pg, init_method)
        tia = min(tia, time.perf_counter() - t0)
        t0 = time.perf_counter()
        LI.initialize(pg, init_method, engine="gtsam")
        tig = min(tig, time.perf_counter() - t0)
    refa = as_arr(ref)
    d = ours - refa
    if not pg.is3d:
        d[:, 2] = np.arctan2(np.sin(d[:, 2]), np.cos(d[:, 2]))
    rel = np.max(np.abs(d)) / max(1.0, np.max(np.abs(refa)))
    return dict(graph=os.path.basename(path).removesuffix(".g2o"), poses=n,
                factors=len(pg.edge_keys) + len(pg.prior_keys), method=method, gtsam=tg, arrays=ta,
                init_gtsam=tig, init_arrays=tia, rel=rel)


def generated(n: int) -> None:
    """Our chordal initializer alone on generate_posegraph's n-pose helix (arrays straight from the
    generator, no file): seconds and peak RSS."""
    import resource

    from generate_posegraph import SIGMAS, generate

    i, j, Z, _ = generate(n)
    info = np.broadcast_to(np.diag(1 / SIGMAS ** 2), (i.size, 6, 6)).copy()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    t0 = time.perf_counter()
    chordal.initialize(PoseGraph("Pose3", np.arange(n), np.stack([i, j], axis=1), Z, info, None, None))
    seconds = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    print(f"generated helix: {n} poses, {i.size} edges: chordal.initialize {seconds:.1f} s, "
          f"peak RSS {before:.2f} GB before, {after:.2f} GB after")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("graphs", nargs="*", default=DEFAULT, help="names in $LIE_FACTORS_DATA or g2o paths")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--generated", type=int, default=0,
                    help="instead: the array initializer alone on a generated helix of this many poses")
    a = ap.parse_args(argv)
    if a.generated:
        generated(a.generated)
        return 0
    print("| graph | poses | factors | method | GTSAM (s) | ours (s) | ratio | initialize(): engine gtsam → "
          "ours (s) | max rel. difference |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in a.graphs:
        r = run(name, a.repeat)
        print(f"| {r['graph']} | {r['poses']} | {r['factors']} | {r['method']} | {r['gtsam']:.3f} | "
              f"{r['arrays']:.3f} | {r['arrays'] / r['gtsam']:.2f}× | {r['init_gtsam']:.3f} → "
              f"{r['init_arrays']:.3f} | {r['rel']:.1e} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
