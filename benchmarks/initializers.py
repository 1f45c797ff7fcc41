"""GTSAM's initializers vs lie_factors.initialization.relaxation (the same results on arrays), side by side.

    python benchmarks/initializers.py --repeat 3

Per graph, alternating the two within each repetition, best of ``--repeat``:

* ``gtsam``: ``InitializePose3.initialize`` (3-D), ``lago.initialize`` (2-D,
  diagonal noise), or ``InitializePose3.initialize`` on the planar Pose3 graph
  (2-D with full covariances, lie_factors' rule) — run on a large-stack thread
  (lie_factors.stack), on GTSAM's own factor graph built beforehand;
* ``arrays``: :func:`lie_factors.initialization.relaxation.initialize_pose3` / ``lago_pose2`` /
  ``chordal_pose2`` on the arrays (indices, measurements, information);
* ``initialize()``: :func:`lie_factors.initialization.initialize` on the graph
  (factor objects in, Values out, as the CLI calls it), with the arrays inside
  vs with GTSAM's initializer inside (cvxopt hidden).

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

from lie_factors import g2o  # noqa: E402
from lie_factors import initialization as LI  # noqa: E402
from lie_factors.initialization import relaxation as rx  # noqa: E402
from lie_factors.initialization.arrays import _xytheta as xytheta  # noqa: E402
from lie_factors import stack  # noqa: E402
from lie_factors.app.run import build_graph, load  # noqa: E402

DATA = os.environ.get("LIE_FACTORS_DATA", os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data"))
DEFAULT = ["sphere2500", "torus3D", "city10000", "intel", "kitti_00"]


def arrays_of(path):
    """(keys, i, j, measured, information) of a g2o file's pose graph, as the relaxations take them:
    indices into the sorted keys, measured 4×4 (3-D) or [x, y, θ] (2-D, converted here so that
    the timings hold the initializer alone), information in GTSAM's tangent order."""
    a = g2o.read_arrays(g2o.check_g2o(path))
    i, j = (np.searchsorted(a.keys, a.edge_keys[:, c]) for c in (0, 1))
    return a.keys, i, j, a.measured if a.is3d else xytheta(a.measured), a.information


def best(fn, repeat):
    out, t = None, float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        t = min(t, time.perf_counter() - t0)
    return out, t


def run(name, repeat):
    path = name if os.path.exists(name) else os.path.join(DATA, name + ".g2o")
    pg = load(path)
    graph = build_graph(pg, "native")  # the edges, then the prior on the first pose (at the identity here)
    keys, I, J, Z, INFO = arrays_of(path)
    n = len(keys)
    pf = graph.at(graph.size() - 1)  # build_graph's prior on the first pose
    first = pf.prior()
    prior = np.array([first.matrix() if pg.is3d else [first.x(), first.y(), first.theta()]])
    pinfo = (lambda R: (R.T @ R)[None])(pf.noiseModel().R())
    pidx = np.array([list(keys).index(pf.keys()[0])])
    diagonal = all(isinstance(graph.at(k).noiseModel(), gtsam.noiseModel.Diagonal) for k in range(graph.size()))
    if pg.is3d:
        method = "chordal (InitializePose3)"
        g_call = lambda: stack.call(gtsam.InitializePose3.initialize, graph)  # noqa: E731
        a_call = lambda: rx.initialize_pose3(n, I, J, Z, INFO, pidx, prior, pinfo)  # noqa: E731
        as_arr = lambda v: np.array([v.atPose3(int(k)).matrix() for k in keys])  # noqa: E731
        init_method = "chordal"
    elif diagonal:
        method = "lago"
        g_call = lambda: stack.call(gtsam.lago.initialize, graph, True)  # noqa: E731
        a_call = lambda: rx.lago_pose2(n, I, J, Z, INFO, pidx, prior, pinfo, keys=keys)  # noqa: E731
        as_arr = lambda v: np.array([[v.atPose2(int(k)).x(), v.atPose2(int(k)).y(), v.atPose2(int(k)).theta()]  # noqa: E731
                                     for k in keys])
        init_method = "lago"
    else:
        method = "chordal, planar Pose3"
        planar = LI._native_graph(LI._planar_pose3_graph(LI._convert(graph)))
        g_call = lambda: stack.call(gtsam.InitializePose3.initialize, planar)  # noqa: E731
        a_call = lambda: rx.chordal_pose2(n, I, J, Z, INFO, pidx, prior, pinfo)  # noqa: E731
        as_arr = lambda v: np.array([[v.atPose3(int(k)).x(), v.atPose3(int(k)).y(),  # noqa: E731
                                      v.atPose3(int(k)).rotation().yaw()] for k in keys])
        init_method = "chordal"
    tg = ta = tig = tia = float("inf")
    real = rx.cholmod_available
    for _ in range(repeat):
        t0 = time.perf_counter()
        ref = g_call()
        tg = min(tg, time.perf_counter() - t0)
        t0 = time.perf_counter()
        ours = a_call()
        ta = min(ta, time.perf_counter() - t0)
        t0 = time.perf_counter()
        LI.initialize(graph, init_method)
        tia = min(tia, time.perf_counter() - t0)
        rx.cholmod_available = lambda: False
        try:
            t0 = time.perf_counter()
            LI.initialize(graph, init_method)
            tig = min(tig, time.perf_counter() - t0)
        finally:
            rx.cholmod_available = real
    refa = as_arr(ref)
    d = ours - refa
    if not pg.is3d:
        d[:, 2] = np.arctan2(np.sin(d[:, 2]), np.cos(d[:, 2]))
    rel = np.max(np.abs(d)) / max(1.0, np.max(np.abs(refa)))
    return dict(graph=os.path.basename(path).removesuffix(".g2o"), poses=n, factors=int(graph.size()),
                method=method, gtsam=tg, arrays=ta, init_gtsam=tig, init_arrays=tia, rel=rel)


def generated(n: int) -> None:
    """relaxation.initialize_pose3 alone on generate_posegraph's n-pose helix (arrays straight from the
    generator, no file): seconds and peak RSS."""
    import resource

    from generate_posegraph import SIGMAS, generate

    i, j, Z, _ = generate(n)
    info = np.broadcast_to(np.diag(1 / SIGMAS ** 2), (i.size, 6, 6)).copy()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    t0 = time.perf_counter()
    rx.initialize_pose3(n, i, j, Z, info)
    seconds = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    print(f"generated helix: {n} poses, {i.size} edges: initialize_pose3 {seconds:.1f} s, "
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
    print("| graph | poses | factors | method | GTSAM (s) | arrays (s) | ratio | initialize(): GTSAM inside → "
          "arrays inside (s) | max rel. difference |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in a.graphs:
        r = run(name, a.repeat)
        print(f"| {r['graph']} | {r['poses']} | {r['factors']} | {r['method']} | {r['gtsam']:.3f} | "
              f"{r['arrays']:.3f} | {r['arrays'] / r['gtsam']:.2f}× | {r['init_gtsam']:.3f} → "
              f"{r['init_arrays']:.3f} | {r['rel']:.1e} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
