"""Small problems as GTSAM's own clients build them: ``lf.optimize`` against GTSAM's optimizer.

    python benchmarks/small_problems.py [--repeat 5] [--only warm|stages|process]

GTSAM's shipped examples and unit tests are run as they are, with GTSAM's optimizers, ``ISAM2``
and ``readG2o`` recording the graphs they are given (``tests/support/capture_gtsam_graphs.py``):
SFMExample_bal (dubrovnik-3-7 and dubrovnik-3-7-18), VisualISAM2Example (the union of its
updates), test_ISAM2 (planar SLAM), test_SFMExample, known_landmark_localization_20.g2o (readG2o),
Pose3SLAMExample_g2o on pose3example.txt and on smallGrid3D.g2o (its Gauss–Newton params).

* ``warm``: each capture optimized by GTSAM's own optimizer for its params (Levenberg–Marquardt
  for an ISAM2 union or a readG2o capture) and by ``lf.optimize(graph, initial, params)``, in one
  process, after one untimed call of each, alternated, best of ``--repeat``; the two final errors
  (relative difference; absolute where GTSAM's is 0), the iterations, the path ``lf.optimize`` took
  (``small``: one compiled call; else why not), the ratio ours / GTSAM's.  ``lf.optimize`` is timed with ``result.values`` read (what
  GTSAM's ``optimize()`` returns).  The "Python floor" (``python_floor.py``), timed the same way:
  what any Python solver pays before computing, every factor and initial value read through
  GTSAM's accessors and the result built as a ``gtsam.Values``; beside it, its ratio to GTSAM's time.
* ``stages``: where ``lf.optimize``'s time goes on each capture (best of ``--repeat`` each):
  reading the graph into arrays (``Problem``), the small path's set-up (``SmallSolve``), the
  whole optimizer construction (both, the initial error, the LM state), the solve (one compiled
  call from the start), ``result.values``; and ``lf.optimize`` whole.
* ``process``: a whole script that reads dubrovnik-3-7 as SFMExample_bal does and optimizes it,
  with ``lf.optimize`` against the same with GTSAM's LM, in fresh processes with the cache warm,
  alternated, best of ``--repeat``; and numba's floor apart (``import numba`` and the first call
  of a cached trivial kernel).  Python's compiled modules are written and read, as a user's
  install has them (PYTHONDONTWRITEBYTECODE dropped for these processes).

The machine's load is printed before and after.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import python_floor as floor

ROOT = Path(__file__).resolve().parents[1]
SUPPORT = ROOT / "tests" / "support"

#: client → the captures of it that are timed (their position among the client's captures,
#: -1 the last: an ISAM2's union of every update)
CLIENTS = {
    "examples/SFMExample_bal": "dubrovnik-3-7",
    "examples/SFMExample_bal:-i {dubrovnik-3-7-18-pre.txt}": "dubrovnik-3-7-18",
    "examples/VisualISAM2Example": "VisualISAM2Example",
    "tests/test_ISAM2.py": "test_ISAM2 (planar SLAM)",
    "tests/test_SFMExample.py": "test_SFMExample",
    "readG2o/known_landmark_localization_20.g2o": "known_landmark_localization_20",
    "examples/Pose3SLAMExample_g2o": "pose3example (Pose3SLAMExample_g2o)",
    "examples/Pose3SLAMExample_g2o:-i " + str(ROOT / "data" / "smallGrid3D.g2o"): "smallGrid3D (Pose3SLAMExample_g2o)",
}


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def capture():
    """(label, capture) of the last capture of each client (an ISAM2's: the union of its updates)."""
    import gtsam

    sys.path.insert(0, str(SUPPORT))
    import capture_gtsam_graphs as cap

    cap.prepare(str(Path("/tmp") if Path("/tmp").exists() else Path.cwd()))
    cap.start_recording()
    out = []
    try:
        for client, label in CLIENTS.items():
            if "{" in client:
                head, name = client.split("{")
                client = head + gtsam.findExampleDataFile(name.rstrip("}"))
            cap.CAPTURES.items = []
            failure = cap.run_client(client)
            items = [i for i in cap.CAPTURES.items if i["source"] in (*cap.OPTIMIZERS, "ISAM2", "readG2o")]
            if failure or not items:
                print(f"{label}: no graph captured ({failure.strip().splitlines()[-1] if failure else 'none'})")
                continue
            out.append((label, items[-1]))
    finally:
        cap.stop_recording()
    return out


def _gtsam_run(item):
    """GTSAM's optimizer for the capture's params (LM for an ISAM2 union or a readG2o capture)."""
    import gtsam

    params = item["params"]
    if isinstance(params, gtsam.GaussNewtonParams):
        opt = gtsam.GaussNewtonOptimizer(item["graph"], item["values"], params)
    else:
        params = params if params is not None else gtsam.LevenbergMarquardtParams()
        opt = gtsam.LevenbergMarquardtOptimizer(item["graph"], item["values"], params)
    values = opt.optimize()
    return values, opt.iterations()


def _ours(item):
    import gtsam

    import lie_factors as lf

    params = item["params"] if item["params"] is not None else gtsam.LevenbergMarquardtParams()
    result = lf.optimize(item["graph"], item["values"], params)
    result.values  # noqa: B018 - what GTSAM's optimize() returns
    return result


def _floor(item, types: dict):
    """The Python floor of ``lf.optimize`` on the capture (``python_floor.py``)."""
    known: dict = {}
    floor.read_factors(item["graph"])
    floor.read_values(item["values"], types, known)
    return floor.build_values(known)


def _path(item) -> str:
    """``small`` where the batch solver solves the capture in one compiled call, else why not."""
    import gtsam

    from lie_factors.batch.optimizer import BatchLevenbergMarquardt

    params = item["params"] if item["params"] is not None else gtsam.LevenbergMarquardtParams()
    why = BatchLevenbergMarquardt(item["graph"], item["values"], params).small_refusal
    return "small" if why is None else f"general ({why})"


def warm(captures, repeat: int) -> None:
    import numpy as np

    print(f"load before: {load()}")
    print("| client graph | factors | GTSAM s | ours s | ours / GTSAM | iterations GTSAM / ours | path | "
          "final error rel. diff | Python floor s | floor / GTSAM |")
    print("|---|---:|---:|---:|---:|---|---|---:|---:|---:|")
    for label, item in captures:
        graph = item["graph"]
        ref_values, ref_its = _gtsam_run(item)
        res = _ours(item)
        types = floor.value_types(item["values"])
        best = {"gtsam": np.inf, "ours": np.inf, "floor": np.inf}
        for _ in range(repeat):
            for name, run in (("gtsam", _gtsam_run), ("ours", _ours), ("floor", lambda item: _floor(item, types))):
                t = time.perf_counter()
                run(item)
                best[name] = min(best[name], time.perf_counter() - t)
        ref_error = float(graph.error(ref_values))
        diff = abs(res.error - ref_error) / abs(ref_error) if ref_error else abs(res.error)
        path = _path(item)
        print(f"| {label} | {graph.size()} | {best['gtsam']:.6f} | {best['ours']:.6f} | "
              f"{best['ours'] / best['gtsam']:.2f} | {ref_its} / {res.iterations} | {path} | {diff:.1e} | "
              f"{best['floor']:.6f} | {best['floor'] / best['gtsam']:.2f} |")
    print(f"load after: {load()}")


def stages(captures, repeat: int) -> None:
    import gtsam

    import lie_factors as lf
    from lie_factors.batch import small
    from lie_factors.batch.graph import Problem
    from lie_factors.batch.optimizer import BatchLevenbergMarquardt

    def best(fn) -> float:
        out = float("inf")
        for _ in range(repeat):
            t = time.perf_counter()
            fn()
            out = min(out, time.perf_counter() - t)
        return out * 1e6

    print(f"load before: {load()}")
    print("| client graph | factors | read (Problem) µs | small path set-up µs | optimizer set-up µs | solve µs "
          "| values µs | lf.optimize µs |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for label, item in captures:
        graph, values = item["graph"], item["values"]
        params = item["params"] if item["params"] is not None else gtsam.LevenbergMarquardtParams()
        if BatchLevenbergMarquardt(graph, values, params).small_refusal is not None:
            continue
        lf.optimize(graph, values, params)
        problem = Problem(graph, values)
        read = best(lambda: Problem(graph, values))
        setup = best(lambda: small.SmallSolve(problem, params))
        optimizer = best(lambda: BatchLevenbergMarquardt(graph, values, params))
        solve = best(lambda: BatchLevenbergMarquardt(graph, values, params).optimize(values=False)) - optimizer
        opt = BatchLevenbergMarquardt(graph, values, params)
        opt.optimize(values=False)
        out = best(opt.values)
        whole = best(lambda: lf.optimize(graph, values, params).values)
        print(f"| {label} | {graph.size()} | {read:.0f} | {setup:.0f} | {optimizer:.0f} | {solve:.0f} | {out:.0f} "
              f"| {whole:.0f} |")
    print(f"load after: {load()}")


_PROCESS = r"""
import sys, time
t0 = time.perf_counter()
import gtsam
which = sys.argv[1]
scene = gtsam.SfmData.FromBalFile(gtsam.findExampleDataFile("dubrovnik-3-7-pre"))
graph = gtsam.NonlinearFactorGraph()
noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
for j in range(scene.numberTracks()):
    track = scene.track(j)
    for m in range(track.numberMeasurements()):
        i, uv = track.measurement(m)
        graph.add(gtsam.GeneralSFMFactorCal3Bundler(uv, noise, gtsam.symbol("c", i), gtsam.symbol("p", j)))
graph.push_back(gtsam.PriorFactorPinholeCameraCal3Bundler(gtsam.symbol("c", 0), scene.camera(0),
                                                          gtsam.noiseModel.Isotropic.Sigma(9, 0.1)))
graph.push_back(gtsam.PriorFactorPoint3(gtsam.symbol("p", 0), scene.track(0).point3(),
                                        gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
initial = gtsam.Values()
for i in range(scene.numberCameras()):
    initial.insert(gtsam.symbol("c", i), scene.camera(i))
for j in range(scene.numberTracks()):
    initial.insert(gtsam.symbol("p", j), scene.track(j).point3())
params = gtsam.LevenbergMarquardtParams()
if which == "ours":
    import lie_factors as lf
    values = lf.optimize(graph, initial, params).values
else:
    values = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
print(time.perf_counter() - t0, graph.error(values))
"""

_FLOOR = r"""
import time
t0 = time.perf_counter()
import numpy
t1 = time.perf_counter()
import numba
t2 = time.perf_counter()
from lie_factors import se3
import numpy as np
se3.log(np.eye(4))
t3 = time.perf_counter()
print(t1 - t0, t2 - t1, t3 - t2)
"""


def _fresh(code: str, *args: str) -> subprocess.CompletedProcess:
    """``code`` run in a fresh interpreter, with Python's compiled modules written (as a user's
    install has them: PYTHONDONTWRITEBYTECODE dropped)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    return subprocess.run([sys.executable, "-c", code, *args], check=True, capture_output=True, text=True, env=env)


def process(repeat: int) -> None:
    print(f"load before: {load()}")
    for which in ("gtsam", "ours"):  # once untimed each: the caches (numba's, Python's) and the OS's file cache warm
        _fresh(_PROCESS, which)
    best = {"gtsam": float("inf"), "ours": float("inf"), "wall gtsam": float("inf"), "wall ours": float("inf")}
    for _ in range(repeat):
        for which in ("gtsam", "ours"):
            t = time.perf_counter()
            out = _fresh(_PROCESS, which)
            wall = time.perf_counter() - t
            best[which] = min(best[which], float(out.stdout.split()[0]))
            best["wall " + which] = min(best["wall " + which], wall)
    print(f"dubrovnik-3-7 script, whole process: GTSAM {best['wall gtsam']:.3f} s, lf.optimize {best['wall ours']:.3f} s "
          f"({best['wall ours'] / best['wall gtsam']:.2f}x); inside the script (imports on): GTSAM {best['gtsam']:.3f} s, "
          f"ours {best['ours']:.3f} s")
    floors = []
    for _ in range(repeat):
        out = _fresh(_FLOOR)
        floors.append([float(x) for x in out.stdout.split()])
    numpy_s, numba_s, first = (min(f[k] for f in floors) for k in range(3))
    print(f"numba's floor: import numpy {numpy_s:.3f} s, import numba {numba_s:.3f} s, "
          f"import lie_factors.se3 and its first cached call {first:.3f} s")
    print(f"load after: {load()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--only", choices=("warm", "stages", "process"))
    args = parser.parse_args()
    captures = capture() if args.only in (None, "warm", "stages") else []  # GTSAM's clients run once a process
    if args.only in (None, "warm"):
        warm(captures, args.repeat)
    if args.only in (None, "stages"):
        stages(captures, args.repeat)
    if args.only in (None, "process"):
        process(args.repeat)


if __name__ == "__main__":
    main()
