"""Run GTSAM's shipped examples and unit tests, capture every graph they hand an optimizer, and
optimize each with ``lie_factors.optimize`` beside GTSAM's own optimizer.

    python capture_gtsam_graphs.py OUT_JSON CLIENT [CLIENT ...]

``CLIENT``: ``examples/NAME[:ARG ARG ...]`` (an example, run as ``__main__`` with those
arguments, or driven as run_gtsam_example.py drives a module-like one), ``tests/NAME.py``
(a unit test file, its tests run by ``unittest``), relative to the gtsam package, or
``readG2o/FILE`` (``gtsam.readG2o`` of a 3-D file shipped with GTSAM).  Run by
tests/gtsam/test_gtsam_clients.py.

Before any client runs, GTSAM's classes the clients hand graphs to are replaced in ``gtsam``'s
namespace by subclasses that record what they are given and then do what GTSAM's do:

* ``LevenbergMarquardtOptimizer``, ``GaussNewtonOptimizer``, ``DoglegOptimizer``,
  ``SfmLevenbergMarquardtOptimizer``: (graph, initial values, params) at construction (params
  None: the optimizer's defaults);
* ``ISAM2``: the union of its updates (every factor added, minus those removed, and every value
  inserted, recorded before GTSAM's update runs), as one graph with GTSAM's default
  Levenberg–Marquardt params;
* ``Marginals``: the graph and the values it is given, with the default params;
* ``readG2o``: the graph and values it returns, with the default params.

Each graph is copied when it is recorded (a client may empty its graph afterwards, as
VisualISAM2Example does); equal captures of one client (same source, factor count, keys,
initial error and params) are kept once.  After the clients ran, GTSAM's own classes are put
back and each capture is optimized by GTSAM's own optimizer for it (``optimize()``), by
``lie_factors.optimize(graph, initial, params)``, and by the same with
``linear_solver="gtsam"``.  ``OUT_JSON`` gets one record per capture: where it came from; the
initial error; both final errors and iteration counts; whether GTSAM's ``Marginals`` compute
at GTSAM's optimum (``determined``); the largest difference of the estimates (each variable's
``localCoordinates``, relative to a point's, pose's or camera's translation where above 1);
whether ``print(result)``, ``result.keys``, ``result.values`` (each value of the C++ type the
caller gave, as ``Values`` prints it) and ``result.covariances()`` work, and the covariances'
largest difference from GTSAM's ``Marginals``' at the same estimate; the text of any exception.
Clients that raise are listed with their traceback.
"""

from __future__ import annotations

import json
import os
import re
import sys
import tempfile
import time
import traceback
import unittest

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import gtsam  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import run_gtsam_example  # noqa: E402
import run_gtsam_tests  # noqa: E402

PACKAGE = os.path.dirname(gtsam.__file__)
#: the optimizers whose constructor is recorded
OPTIMIZERS = ("LevenbergMarquardtOptimizer", "GaussNewtonOptimizer", "DoglegOptimizer", "SfmLevenbergMarquardtOptimizer")
#: GTSAM's own classes, before the recording ones replace them
OWN = {name: getattr(gtsam, name) for name in (*OPTIMIZERS, "ISAM2", "Marginals", "readG2o")}


class Captures:
    """The graphs recorded while one client runs."""

    def __init__(self):
        self.client = ""
        self.items: list[dict] = []
        self._seen: set = set()

    def add(self, source: str, graph, values, params) -> None:
        graph = gtsam.NonlinearFactorGraph(graph)
        values = gtsam.Values(values)
        try:
            error = float(graph.error(values))
        except Exception:  # noqa: BLE001 - a graph the values do not cover: still a capture
            error = float("nan")
        keys = tuple(sorted(int(k) for k in values.keys()))
        identity = (self.client, source if source in OPTIMIZERS else "", graph.size(), keys,
                    round(error, 9) if error == error else "nan", _text(params))
        if identity in self._seen:
            return
        self._seen.add(identity)
        self.items.append({"client": self.client, "source": source, "graph": graph, "values": values,
                           "params": params})


CAPTURES = Captures()
#: where the clients' scratch directories go (beside OUT_JSON)
SCRATCH: list = [None]


def _text(params) -> str:
    """What ``params`` print (every setting) and their class, or '' for None."""
    return "" if params is None else str(params) + type(params).__name__


def _params_of(args, kwargs):
    for a in (*args, *kwargs.values()):
        if isinstance(a, gtsam.NonlinearOptimizerParams):
            return a
    return None


def _recording_optimizer(name: str):
    base = OWN[name]

    class Recording(base):
        def __init__(self, graph, values, *args, **kwargs):
            CAPTURES.add(name, graph, values, _params_of(args, kwargs))
            super().__init__(graph, values, *args, **kwargs)

    Recording.__name__ = Recording.__qualname__ = name
    return Recording


class RecordingISAM2(OWN["ISAM2"]):
    """``gtsam.ISAM2``, recording the union of its updates."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._union = gtsam.NonlinearFactorGraph()
        self._theta = gtsam.Values()

    def update(self, *args, **kwargs):
        names = ("newFactors", "newTheta", "removeFactorIndices")
        bound = dict(zip(names, args), **{k: v for k, v in kwargs.items() if k in names})
        factors, theta = bound.get("newFactors"), bound.get("newTheta")
        remove = bound.get("removeFactorIndices")
        if len(args) > 2 and isinstance(args[2], gtsam.ISAM2UpdateParams):
            remove = args[2].removeFactorIndices
        for i in list(remove or []):
            self._union.remove(int(i))
        if factors is not None:
            self._union.push_back(factors)
        if theta is not None:
            self._theta.insert(theta)
        if self._union.size():  # recorded first: the update may raise
            CAPTURES.add("ISAM2", self._union, self._theta, None)
        return super().update(*args, **kwargs)


RecordingISAM2.__name__ = RecordingISAM2.__qualname__ = "ISAM2"


class RecordingMarginals(OWN["Marginals"]):
    def __init__(self, graph, values, *args, **kwargs):
        if isinstance(graph, gtsam.NonlinearFactorGraph):
            CAPTURES.add("Marginals", graph, values, None)
        super().__init__(graph, values, *args, **kwargs)


RecordingMarginals.__name__ = RecordingMarginals.__qualname__ = "Marginals"


def recording_read_g2o(*args, **kwargs):
    graph, values = OWN["readG2o"](*args, **kwargs)
    CAPTURES.add("readG2o", graph, values, None)
    return graph, values


def start_recording() -> None:
    for name in OPTIMIZERS:
        setattr(gtsam, name, _recording_optimizer(name))
    gtsam.ISAM2 = RecordingISAM2
    gtsam.Marginals = RecordingMarginals
    gtsam.readG2o = recording_read_g2o


def stop_recording() -> None:
    """GTSAM's own classes back in its namespace (lie_factors then sees GTSAM as a user has it)."""
    for name, own in OWN.items():
        setattr(gtsam, name, own)


# --------------------------------------------------------------------------- #
# Running the clients
# --------------------------------------------------------------------------- #

def prepare(scratch: str) -> None:
    """What running the clients needs, once a process: their scratch directories under
    ``scratch``, no plot window (Agg, ``show`` and ``pause`` doing nothing), GTSAM's examples
    importable by one another."""
    SCRATCH[0] = scratch
    plt.show = lambda *a, **k: None
    plt.pause = lambda *a, **k: None
    sys.path.insert(0, os.path.join(PACKAGE, "examples"))


def run_client(client: str) -> str:
    """Run one client in a scratch directory (:func:`prepare` first); '' or the traceback of what
    it raised (a unit test's failures are its own business: only a file that cannot run counts).
    ``sys.argv`` is as it was after it."""
    CAPTURES.client = client
    where = tempfile.mkdtemp(prefix="client_", dir=SCRATCH[0])
    cwd, argv = os.getcwd(), list(sys.argv)
    os.chdir(where)
    try:
        if client.startswith("examples/"):
            name, _, args = client[len("examples/"):].partition(":")
            run_example(name, args.split() if args else [])
        elif client.startswith("readG2o/"):
            gtsam.readG2o(gtsam.findExampleDataFile(client[len("readG2o/"):]), True)
        else:
            suite = run_gtsam_tests.load(client[len("tests/"):], "original")
            suite.run(unittest.TestResult())
        return ""
    except BaseException:  # noqa: BLE001 - recorded, then the next client
        return traceback.format_exc()[-3000:]
    finally:
        plt.close("all")
        os.chdir(cwd)
        sys.argv = argv


def run_example(name: str, args: list) -> None:
    """An example as a script (``__main__``, ``sys.argv`` its arguments, ``np.random`` seeded), or
    a module-like one driven as run_gtsam_example.py drives it."""
    path = os.path.join(PACKAGE, "examples", name + ".py")
    with open(path) as fh:
        source = fh.read()
    sys.argv = [path, *args]
    np.random.seed(0)
    driven = name in run_gtsam_example.DRIVERS
    namespace = {"__name__": name if driven else "__main__", "__file__": path}
    exec(compile(source, path, "exec"), namespace)
    if driven:
        exec(run_gtsam_example.DRIVERS[name], namespace)


# --------------------------------------------------------------------------- #
# Optimizing the captures
# --------------------------------------------------------------------------- #

def _gtsam_optimum(item):
    """GTSAM's own optimizer of the capture (the one recorded, else Levenberg–Marquardt), run to
    its end: (values, error, iterations)."""
    name = item["source"] if item["source"] in OPTIMIZERS else "LevenbergMarquardtOptimizer"
    own, params = OWN[name], item["params"]
    opt = own(item["graph"], item["values"], params) if params is not None else own(item["graph"], item["values"])
    values = opt.optimize()
    return values, float(item["graph"].error(values)), int(opt.iterations())


def _magnitude(values, key) -> float:
    """The size of a variable's coordinates (a point's, a pose's or a camera's translation), 1
    for a variable of another type."""
    for read in ("atVector", "atPoint3", "atPoint2"):
        try:
            return float(np.max(np.abs(np.asarray(getattr(values, read)(key)))))
        except (RuntimeError, TypeError):
            pass
    for read in ("atPose3", "atPose2", "atPinholeCameraCal3Bundler", "atPinholeCameraCal3_S2", "atSphericalCamera"):
        try:
            x = getattr(values, read)(key)
        except (RuntimeError, TypeError):
            continue
        x = x.pose() if hasattr(x, "pose") else x
        return float(np.max(np.abs(np.asarray(x.translation()))))
    return 1.0


def _deviation(reference, ours) -> float:
    """The largest difference of two estimates of the same types, key by key
    (``localCoordinates``), relative to the variable's size where it is above 1."""
    worst = 0.0
    delta = reference.localCoordinates(ours)
    for key in reference.keys():
        d = np.asarray(delta.at(key))
        if d.size:
            worst = max(worst, float(np.max(np.abs(d))) / max(1.0, _magnitude(reference, key)))
    return worst


def check(item) -> dict:
    """The record of one capture (module docstring)."""
    rec = {"client": item["client"], "source": item["source"], "params": type(item["params"]).__name__,
           "factors": int(item["graph"].size()), "variables": int(item["values"].size())}
    try:
        ref_values, rec["gtsam_error"], rec["gtsam_iterations"] = _gtsam_optimum(item)
    except Exception as exc:  # noqa: BLE001 - GTSAM refuses the graph: ours must refuse it too
        rec["gtsam_raised"] = f"{type(exc).__name__}: {exc}"[:500]
        ref_values = None
    try:
        rec["initial_error"] = float(item["graph"].error(item["values"]))
    except Exception as exc:  # noqa: BLE001
        rec["initial_error_raised"] = f"{type(exc).__name__}: {exc}"[:500]
    try:  # does the graph determine its variables at GTSAM's optimum? (GTSAM's Marginals say)
        rec["determined"] = ref_values is not None and OWN["Marginals"](item["graph"], ref_values) is not None
    except Exception:  # noqa: BLE001
        rec["determined"] = False
    result = _ours(item, rec, "")
    if result is None:
        return rec
    for what, get in (("repr", lambda: repr(result)), ("print", lambda: str(result)),
                      ("keys", lambda: len(result.keys)), ("values", lambda: result.values.size()),
                      ("covariances", lambda: _covariances(item["graph"], result, rec))):
        try:
            rec[what] = str(get())
        except Exception as exc:  # noqa: BLE001
            rec[what + "_raised"] = f"{type(exc).__name__}: {exc}"[:500]
    if "values_raised" not in rec:
        given, got = _types(item["values"]), _types(result.values)
        rec["type_mismatch"] = [f"{k}: {given[k]} became {got.get(k)}" for k in given if got.get(k) != given[k]]
    if ref_values is not None and "values_raised" not in rec and not rec["type_mismatch"]:
        try:
            rec["deviation"] = _deviation(ref_values, result.values)
        except Exception as exc:  # noqa: BLE001
            rec["deviation_raised"] = f"{type(exc).__name__}: {exc}"[:500]
    # and with GTSAM's elimination as the batch solver's linear solver
    result = _ours(item, rec, "gtsam_solver_", linear_solver="gtsam")
    if result is not None and ref_values is not None:
        try:
            rec["gtsam_solver_deviation"] = _deviation(ref_values, result.values)
        except Exception as exc:  # noqa: BLE001
            rec["gtsam_solver_deviation_raised"] = f"{type(exc).__name__}: {exc}"[:500]
    return rec


def _ours(item, rec: dict, prefix: str, **options):
    """``lie_factors.optimize`` of the capture, its error, iterations and seconds in ``rec`` (each
    name after ``prefix``); None if it raised (what it raised in ``rec``)."""
    import lie_factors as lf

    start = time.perf_counter()
    try:
        result = lf.optimize(item["graph"], item["values"], item["params"], **options)
    except Exception as exc:  # noqa: BLE001
        rec[prefix + "ours_raised"] = f"{type(exc).__name__}: {exc}"[:500]
        rec[prefix + "ours_traceback"] = traceback.format_exc()[-2000:]
        return None
    rec[prefix + "seconds"] = time.perf_counter() - start
    rec[prefix + "error"], rec[prefix + "iterations"] = float(result.error), int(result.iterations)
    return result


def _types(values) -> dict:
    """Each key's C++ type, as ``Values`` prints it (``Value l0: (Eigen::Matrix<double, 3, 1, …>)``)."""
    return dict(re.findall(r"^Value (\S+): \((.*)\)$", str(values), flags=re.M))


def _covariances(graph, result, rec: dict) -> str:
    """``result.covariances()`` beside GTSAM's ``Marginals`` at the same estimate: in ``rec``,
    whether GTSAM's gives every one of ``result.keys`` and the largest difference of the two,
    relative to the largest entry of GTSAM's."""
    try:
        marginals = OWN["Marginals"](graph, result.values)
        theirs = [np.asarray(marginals.marginalCovariance(int(k))) for k in result.keys]
        rec["gtsam_covariances"] = True
    except Exception:  # noqa: BLE001
        theirs = None
        rec["gtsam_covariances"] = False
    covs = result.covariances()
    ours = list(covs.values()) if isinstance(covs, dict) else list(covs)
    if theirs is not None:
        scale = max([float(np.max(np.abs(c))) for c in theirs] + [1e-300])
        rec["covariance_deviation"] = max([float(np.max(np.abs(a - b))) for a, b in zip(ours, theirs)] + [0.0]) / scale
    return f"{len(ours)} covariances"


def main() -> None:
    out, clients = sys.argv[1], sys.argv[2:]
    prepare(os.path.dirname(os.path.abspath(out)))
    start_recording()
    records: list[dict] = []
    failures: dict[str, str] = {}
    captured: list[dict] = []
    for client in clients:
        CAPTURES.items = []
        failure = run_client(client)
        if failure:
            failures[client] = failure
        captured.extend(CAPTURES.items)
    stop_recording()
    for item in captured:
        records.append(check(item))
    with open(out, "w") as fh:
        json.dump({"records": records, "client_failures": failures}, fh, indent=1)


if __name__ == "__main__":
    main()
