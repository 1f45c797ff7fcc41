"""g2o write time: ``lie_factors.g2o.write_g2o`` (GTSAM's layout, every digit) against
``gtsam.writeG2o`` (six significant digits) on the same graph and values.

    python benchmarks/g2o_write.py [FILE ...] [--repeat 5]

FILE is a path or the name of a file in ``data/`` (default: city10000.g2o, sphere2500.g2o).
The graph is read once with ``gtsam.readG2o``; the two writers then alternate ``--repeat``
times to scratch files, and the best of each counts.  Also reported: the largest relative
difference between each file's numbers read back by ``gtsam.readG2o`` and the values written
(vertices), which is GTSAM's rounding for its writer and the last bits for ours.  Prints a
markdown table.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import gtsam

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lie_factors.g2o import write_g2o  # noqa: E402


def _is3d(path: str) -> bool:
    with open(path) as fh:
        for line in fh:
            if line.startswith(("VERTEX_SE3", "EDGE_SE3")):
                return True
            if line.startswith(("VERTEX_SE2", "EDGE_SE2")):
                return False
    return False


def _vertex_error(path: str, values: gtsam.Values, is3d: bool) -> float:
    """Largest |written − read back| / max(1, |value|) over the vertices' matrices."""
    _, back = gtsam.readG2o(path, is3d)
    at = "atPose3" if is3d else "atPose2"
    worst = 0.0
    for key in values.keys():
        a, b = getattr(values, at)(key).matrix(), getattr(back, at)(key).matrix()
        worst = max(worst, float(np.abs(a - b).max() / max(1.0, np.abs(a).max())))
    return worst


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="*", default=["city10000.g2o", "sphere2500.g2o"])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print(f"load at start: {os.getloadavg()[0]:.2f}")
    print("| file | lines | gtsam.writeG2o (s) | write_g2o (s) | ratio | read-back error: GTSAM's | ours |")
    print("|---|---|---|---|---|---|---|")
    for name in args.files:
        path = name if os.path.exists(name) else str(ROOT / "data" / name)
        is3d = _is3d(path)
        graph, values = gtsam.readG2o(path, is3d)
        with tempfile.TemporaryDirectory() as d:
            theirs, ours = os.path.join(d, "gtsam.g2o"), os.path.join(d, "ours.g2o")
            best = {"gtsam": float("inf"), "ours": float("inf")}
            for _ in range(args.repeat):
                t = time.perf_counter()
                gtsam.writeG2o(graph, values, theirs)
                best["gtsam"] = min(best["gtsam"], time.perf_counter() - t)
                t = time.perf_counter()
                write_g2o(ours, graph, values)
                best["ours"] = min(best["ours"], time.perf_counter() - t)
            lines = sum(1 for _ in open(ours))
            e_theirs, e_ours = _vertex_error(theirs, values, is3d), _vertex_error(ours, values, is3d)
        print(f"| {Path(path).name} | {lines} | {best['gtsam']:.3f} | {best['ours']:.3f} | "
              f"{best['ours'] / best['gtsam']:.2f}x | {e_theirs:.1e} | {e_ours:.1e} |")
    print(f"load at end: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
