"""Input check speed: lie_factors.g2o.check_g2o vs gtsam.readG2o on the same file.

Both run in this process, alternated, best of ``--repeat`` runs each (the
machine is shared: the best run is the least disturbed one).  The check does
everything ``lie-factors posegraph`` checks before GTSAM reads the file
(parse, per-record checks, duplicates, references, connectivity); the target
is check ≤ 2 × readG2o.

    python benchmarks/g2o_check.py [--data-dir DIR] [--datasets A B ...] [--repeat N]

Prints a markdown table.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import gtsam  # noqa: E402

from lie_factors import g2o  # noqa: E402

DEFAULT = ["city10000.g2o", "ais2klinik.g2o", "torus3D.g2o", "sphere2500.g2o", "cubicle.g2o",
           "w20000.txt", "victoria_park.txt", "cityTrees_reduced_1k.g2o"]


def _path(data_dir: str, name: str) -> str:
    candidate = os.path.join(data_dir, name)
    return candidate if os.path.isfile(candidate) else gtsam.findExampleDataFile(name)


def _is3d(path: str) -> bool:
    with open(path) as fh:
        for line in fh:
            if line.split():
                return g2o.RECORDS[line.split()[0]].dim == 3
    return False


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", default=str(ROOT / "data"))
    ap.add_argument("--datasets", nargs="+", default=DEFAULT)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args(argv)

    print("| file | lines | check (s) | gtsam.readG2o (s) | ratio | check result |")
    print("|---|---:|---:|---:|---:|---|")
    for name in args.datasets:
        path = _path(args.data_dir, name)
        with open(path, "rb") as fh:
            nlines = fh.read().count(b"\n")
        is3d = _is3d(path)
        try:
            g2o.check_g2o(path)
            result = "accepted"
        except g2o.InputError as exc:
            result = "refused: " + str(exc).split(": ", 1)[1][:60]

        def check():
            try:
                g2o.check_g2o(path)
            except g2o.InputError:
                pass

        def read():
            gtsam.readG2o(path, is3d)

        check_s, read_s = [], []
        for _ in range(args.repeat):  # alternate, so both see the same machine load
            check_s.append(_timed(check))
            read_s.append(_timed(read))
        c, r = min(check_s), min(read_s)
        print(f"| {name} | {nlines} | {c:.3f} | {r:.3f} | {c / r:.2f} | {result} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
