"""GTSAM's own ISAM2 clients, replayed on ``gtsam.ISAM2`` and on ``lf.Smoother``.

    python benchmarks/smoother_clients.py [--repeat 5]

GTSAM's shipped VisualISAM2Example, test_VisualISAMExample and test_ISAM2 are run as they are
(``tests/support/capture_gtsam_graphs.py``'s runner), with ``gtsam.ISAM2`` replaced by a subclass
that logs every call the client makes: its params, each ``update`` (the factors and values
copied as given) and each ``calculateEstimate``/``calculateBestEstimate``.  Each log is then
replayed, call for call, on a fresh ``gtsam.ISAM2`` and on a fresh ``lf.Smoother`` with the same
params: in one process, after one untimed replay of each, alternated, best of ``--repeat``; a
client's time is the sum over the ISAM2 instances it made.  The two final estimates are compared
key by key as the capture compares optima (the largest entry of ``localCoordinates``, relative to
the variable's size where that is above 1).  The machine's load is printed before and after.

The "Python floor" column is what any smoother written in Python pays on the same calls, before
it computes anything (:mod:`python_floor`): each new factor's data and each new value read
through GTSAM's accessors, and for each ``calculateEstimate()`` a ``gtsam.Values`` built from
arrays (``calculateEstimate(key)``: one object).  It is timed as the replays are, and given
beside ISAM2's time.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import gtsam
import python_floor as floor

ROOT = Path(__file__).resolve().parents[1]
SUPPORT = ROOT / "tests" / "support"

CLIENTS = {
    "examples/VisualISAM2Example": "VisualISAM2Example",
    "tests/test_VisualISAMExample.py": "test_VisualISAMExample",
    "tests/test_ISAM2.py": "test_ISAM2",
}


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def record() -> dict:
    """client label → [(params, [(method, args, kwargs), ...]) per ISAM2 the client made]."""
    sys.path.insert(0, str(SUPPORT))
    import capture_gtsam_graphs as cap

    own = gtsam.ISAM2
    made: list = []  # (params, log) of each ISAM2 the client being run makes

    class LoggingISAM2(own):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self._log = []
            made.append((args[0] if args else kwargs.get("params"), self._log))

        def update(self, *args, **kwargs):
            args = list(args)
            if args:
                args[0] = gtsam.NonlinearFactorGraph(args[0])
            if len(args) > 1:
                args[1] = gtsam.Values(args[1])
            self._log.append(("update", tuple(args), dict(kwargs)))
            return super().update(*args, **kwargs)

        def calculateEstimate(self, *args):
            self._log.append(("calculateEstimate", args, {}))
            return super().calculateEstimate(*args)

        def calculateBestEstimate(self):
            self._log.append(("calculateBestEstimate", (), {}))
            return super().calculateBestEstimate()

    LoggingISAM2.__name__ = LoggingISAM2.__qualname__ = "ISAM2"
    cap.prepare("/tmp" if Path("/tmp").exists() else str(Path.cwd()))
    logs = {}
    gtsam.ISAM2 = LoggingISAM2
    try:
        for client, label in CLIENTS.items():
            made.clear()
            failure = cap.run_client(client)
            kept = [(p, log) for p, log in made if any(m == "update" for m, _, _ in log)]
            if failure or not kept:
                print(f"{label}: nothing recorded ({failure.strip().splitlines()[-1] if failure else 'no update'})")
                continue
            logs[label] = kept
    finally:
        gtsam.ISAM2 = own
    return logs


def replay(make, logs) -> list:
    """Each log's calls on a fresh ``make(params)``; the last estimate of each."""
    out = []
    for params, log in logs:
        s = make(params)
        for method, args, kwargs in log:
            getattr(s, method)(*args, **kwargs)
        out.append(s.calculateEstimate())
    return out


class Floor:
    """The Python floor (:mod:`python_floor`) of one log's calls: ``update`` reads, the estimate
    calls build; ``types``: :func:`python_floor.value_types` of the log's values, found untimed."""

    def __init__(self, types: dict):
        self.types = types
        self.known: dict = {}  # key → (type, an array of its value): the variables so far

    @staticmethod
    def prepare(log) -> dict:
        types = {}
        for method, args, _ in log:
            if method == "update" and len(args) > 1:
                types.update(floor.value_types(args[1]))
        return types

    def update(self, graph=None, values=None, *rest, **kwargs):
        if graph is not None:
            floor.read_factors(graph)
        if values is not None:
            floor.read_values(values, self.types, self.known)

    def calculateEstimate(self, key=None):
        if key is not None:
            return floor.gtsam_object(*self.known[int(key)])
        return floor.build_values(self.known)

    calculateBestEstimate = calculateEstimate


def floor_replay(logs, types: list) -> None:
    """:func:`replay` on :class:`Floor`; ``types``: :meth:`Floor.prepare` of each log."""
    for (params, log), key_types in zip(logs, types):
        s = Floor(key_types)
        for method, args, kwargs in log:
            getattr(s, method)(*args, **kwargs)
        s.calculateEstimate()


def _replays(make, one) -> bool:
    try:
        replay(make, [one])
    except RuntimeError:
        return False
    return True


def timed(make, logs) -> float:
    t = time.perf_counter()
    replay(make, logs)
    return time.perf_counter() - t


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    logs = record()
    import capture_gtsam_graphs as cap  # (its estimates' comparison; record() put it on the path)

    import lie_factors as lf

    def isam2(params):
        return gtsam.ISAM2(params) if params is not None else gtsam.ISAM2()

    def smoother(params):
        return lf.Smoother(params) if params is not None else lf.Smoother()

    print(f"load before: {load()}")
    print("| client | ISAM2 instances | updates | estimates | gtsam.ISAM2 s | lf.Smoother s | ours / ISAM2 | "
          "final estimates: largest difference | Python floor s | floor / ISAM2 |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for label, instances in logs.items():
        kept = [one for one in instances if _replays(isam2, one)]
        if len(kept) < len(instances):
            print(f"({label}: {len(instances) - len(kept)} ISAM2 instance(s) whose replay GTSAM refuses left out: "
                  "the test expects the exception)")
        instances = kept
        ref, ours = replay(isam2, instances), replay(smoother, instances)  # untimed once each
        worst = max(cap._deviation(r, o) for r, o in zip(ref, ours))
        types = [Floor.prepare(log) for _, log in instances]
        floor_replay(instances, types)
        best = {"gtsam": float("inf"), "ours": float("inf"), "floor": float("inf")}
        for _ in range(args.repeat):
            best["gtsam"] = min(best["gtsam"], timed(isam2, instances))
            best["ours"] = min(best["ours"], timed(smoother, instances))
            t = time.perf_counter()
            floor_replay(instances, types)
            best["floor"] = min(best["floor"], time.perf_counter() - t)
        updates = sum(m == "update" for _, log in instances for m, _, _ in log)
        estimates = sum(m != "update" for _, log in instances for m, _, _ in log)
        print(f"| {label} | {len(instances)} | {updates} | {estimates} | {best['gtsam']:.6f} | {best['ours']:.6f} | "
              f"{best['ours'] / best['gtsam']:.2f} | {worst:.1e} | {best['floor']:.6f} | "
              f"{best['floor'] / best['gtsam']:.2f} |")
    print(f"load after: {load()}")


if __name__ == "__main__":
    main()
