"""Compile the kernels of the commands a user reaches into numba's on-disk cache.

The install runs this (``setup.py``'s build step, in pip's build environment, from the source
tree): a user's first ``lie-factors demo``, ``posegraph`` (batch, ``--incremental``, ``--gnc``, both,
``--covariances``), ``corrupt``, smoother loop or solve of a BAL scene then loads its kernels
instead of compiling them (docs/installing.md).  Each workload is small, and compiles what the
same command on a large graph compiles: the kernels are specialized on types (the group, the
factor kind), not sizes.  The cache is keyed by the package's sources and the numba, llvmlite
and NumPy versions (:mod:`lie_factors.kernels.cache`): an install whose runtime versions differ
from the build environment's compiles on first use, as without this step.

``python -m lie_factors.app.warmup`` runs it; it prints one line (what it compiled and how
long it took) and exits 0 whatever a workload raises (a workload that fails leaves its
kernels to their first use, and the line names it).
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

#: The repository's benchmark graphs, when the package runs from its source tree.
DATA = Path(__file__).resolve().parents[2] / "data"


def _cli(*argv: str) -> Callable[[], None]:
    def run() -> None:
        from . import cli

        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            status = cli.main(list(argv))
        if status:
            raise RuntimeError(f"lie-factors {' '.join(argv)}: exit status {status}")

    return run


def _visual_smoother() -> None:
    """A smoother loop of projection factors (the ready kinds), as GTSAM's VisualISAM2Example."""
    import gtsam
    import numpy as np

    import lie_factors as lf
    from lie_factors import factors
    from lie_factors.expressions import ready

    X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    K = gtsam.Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    points = [np.array([10.0, 10.0, 10.0]) * np.array(s) for s in
              [(1, 1, 1), (-1, 1, 1), (-1, -1, 1), (1, -1, 1), (1, 1, -1), (-1, 1, -1), (-1, -1, -1), (1, -1, -1)]]
    smoother = lf.Smoother()
    pix = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i in range(5):
        a = 2 * np.pi * i / 8
        eye = gtsam.Point3(30.0 * np.cos(a), 30.0 * np.sin(a), 0.0)
        pose = gtsam.PinholeCameraCal3_S2.Lookat(eye, gtsam.Point3(0, 0, 0), gtsam.Point3(0, 0, 1), K).pose()
        camera = gtsam.PinholeCameraCal3_S2(pose, K)
        for j, p in enumerate(points):
            graph.add(ready.GenericProjectionFactorCal3_S2(camera.project(p), pix, X(i), L(j), K))
        values.insert(X(i), pose)
        if i == 0:
            graph.add(factors.PriorFactorPose3(X(0), pose, gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
            graph.add(ready.GPSFactor(X(0), pose.translation(), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
            # where the camera sees a landmark fixes the scene's scale, which projections leave free
            graph.add(ready.PoseToPointFactor3D(X(0), L(0), pose.transformTo(points[0]),
                                                gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
            for j, p in enumerate(points):
                values.insert(L(j), p + 0.1)
            continue  # the landmarks need a second view
        smoother.update(graph, values)
        smoother.calculateEstimate()
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    lf.optimize(smoother.getFactorsUnsafe(), smoother.calculateEstimate())


def _bal() -> None:
    """A BAL scene of GTSAM's (the SFM example's) solved by ``lf.optimize``."""
    import gtsam

    import lie_factors as lf
    from lie_factors.expressions import bal

    scene = gtsam.SfmData.FromBalFile(gtsam.findExampleDataFile("dubrovnik-3-7-pre"))
    graph, values = bal.graph_of(scene)
    lf.optimize(graph, values)


def workloads(tmp: str) -> list[tuple[str, Callable[[], None]]]:
    """(name, run) of every workload, small graphs through the commands' own paths."""
    runs = [("demo", _cli("demo", "--poses", "40", "--quiet", "--output", tmp))]
    for name in ("intel.g2o", "tinyGrid3D.g2o"):
        path = DATA / name
        if not path.exists():
            continue
        runs += [(f"posegraph {name}", _cli("posegraph", str(path), "--quiet")),
                 (f"posegraph {name} --incremental", _cli("posegraph", str(path), "--incremental", "--quiet")),
                 (f"posegraph {name} --gnc tls", _cli("posegraph", str(path), "--gnc", "tls", "--quiet")),
                 (f"posegraph {name} --covariances", _cli("posegraph", str(path), "--quiet", "--covariances",
                                                          str(Path(tmp) / "c.npz"))),
                 (f"corrupt {name}", _cli("corrupt", str(path), str(Path(tmp) / f"bad-{name}"), "--fraction", "0.2",
                                          "--seed", "1"))]
    for name in ("MIT.g2o", "tinyGrid3D.g2o"):  # the online rejection's kernels: a 2-D and a 3-D graph
        path = DATA / name
        if path.exists():
            runs.append((f"posegraph {name} --incremental --gnc tls",
                         _cli("posegraph", str(path), "--incremental", "--gnc", "tls", "--quiet")))
    runs += [("smoother loop", _visual_smoother), ("BAL", _bal)]
    return runs


def main() -> int:
    from ..util.timing import compile_seconds

    start = time.perf_counter()
    failed = []
    with tempfile.TemporaryDirectory(prefix="lie-factors-warmup-") as tmp:
        for name, run in workloads(tmp):
            try:
                run()
            except Exception as exc:  # noqa: BLE001 - a warm-up that fails only leaves kernels uncached
                failed.append(f"{name} ({type(exc).__name__}: {exc})")
    line = (f"lie-factors: compiled the kernels of every command in {compile_seconds():.0f} s "
            f"({time.perf_counter() - start:.0f} s in all)")
    if failed:
        line += "; not cached: " + "; ".join(failed)
    print(line, file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
