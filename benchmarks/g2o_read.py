"""g2o read throughput (MB/s) and peak memory: our readers against gtsam.readG2o, each in a fresh process.

    python benchmarks/g2o_read.py FILE [FILE ...] [--readers scan numpy check read_g2o loaded readG2o]
                                  [--repeat 5] [--reference DIR]

FILE is a path or the name of a file in ``--data-dir`` (default ``data/``).  For every file
the readers run in turn, ``--repeat`` rounds (so all see the same machine load), each run
a fresh process; the best run counts.  Readers:

* ``scan``: ``lie_factors.g2o.parse.parse_file`` — the file to typed arrays by the numba
  scan (what ``check_g2o`` reads with);
* ``numpy``: the vectorized numpy parse (``fast_parse`` of the file's bytes), the reader
  before the scan;
* ``check``: ``check_g2o`` + ``read_arrays`` — the whole input check (parse, per-record
  and whole-graph checks) and the ``PoseGraph`` arrays;
* ``read_g2o``: ``lie_factors.read_g2o(path)``, the public call, the first in its process:
  what a user's script pays, numba's import and its first kernel load included;
* ``loaded``: the same call in a process that has read a one-line file first (numba and
  the scan's kernels loaded): the call's own cost;
* ``readG2o``: ``gtsam.readG2o(path, is3d)`` — GTSAM's graph and values.

``--reference DIR``: the readers of ours also run from the checkout DIR (another commit),
alternated with this one's, labelled "(reference)".

Timed: from the path to the result, the file's reading included; imports are not (a
``scan`` run first scans a one-line file, which imports numba and loads the cached
kernels: the "warm-up" column, paid once per process).  Memory: the process's peak RSS
(``VmHWM``), and what the read added to the RSS before it; "file + arrays" is the size of
the file plus that of the arrays the scan returns.  A reader that refuses the file is timed
to its refusal ("(refused)").  Prints a markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
READERS = ("scan", "numpy", "check", "read_g2o", "loaded", "readG2o")

_CHILD = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
reader, path, is3d = sys.argv[2], sys.argv[3], sys.argv[4] == "1"

def status(key):
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024

warm = 0.0
if reader == "readG2o":
    import gtsam
    run = lambda: gtsam.readG2o(path, is3d)
elif reader in ("read_g2o", "loaded"):
    import lie_factors as lf
    if reader == "loaded":
        t = time.perf_counter()
        from lie_factors.g2o import parse
        parse.scan_parse(b"VERTEX_SE2 0 0 0 0\n")
        warm = time.perf_counter() - t
    run = lambda: lf.read_g2o(path)
else:
    from lie_factors.g2o import check, dataset, parse, read
    if reader == "scan":
        t = time.perf_counter()
        parse.scan_parse(b"VERTEX_SE2 0 0 0 0\n")
        warm = time.perf_counter() - t
        run = lambda: parse.parse_file(path)
    elif reader == "numpy":
        run = lambda: parse.fast_parse("x", dataset.read_bytes(path))
    else:
        run = lambda: read.read_arrays(check.check_g2o(path))
before = status("VmRSS")
t = time.perf_counter()
try:
    out = run()
except Exception as exc:  # a refused file: the time to the refusal
    out = exc
seconds = time.perf_counter() - t
arrays = 0
if reader == "scan" and not isinstance(out, Exception):
    arrays = sum(r.ids.nbytes + r.values.nbytes + r.lines.nbytes for r in out[0].values())
print(json.dumps({"seconds": seconds, "warm": warm, "peak": status("VmHWM"), "before": before,
                  "arrays": arrays, "refused": isinstance(out, Exception)}))
"""


def _path(data_dir: str, name: str) -> str:
    if os.path.isfile(name):
        return name
    candidate = os.path.join(data_dir, name)
    if os.path.isfile(candidate):
        return candidate
    raise SystemExit(f"{name}: no such file (nor in {data_dir})")


def _is3d(path: str) -> bool:
    sys.path.insert(0, str(ROOT))
    from lie_factors import g2o

    with open(path, "rb") as fh:
        for line in fh:
            tokens = line.split()
            if tokens and not tokens[0].startswith(b"#"):
                return g2o.RECORDS[tokens[0].decode()].dim == 3
    return False


def _run(reader: str, path: str, is3d: bool, root: Path = ROOT) -> dict:
    p = subprocess.run([sys.executable, "-c", _CHILD, str(root), reader, path, "1" if is3d else "0"],
                       capture_output=True, text=True, check=True)
    return json.loads(p.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--data-dir", default=os.environ.get("LIE_FACTORS_DATA", str(ROOT / "data")))
    ap.add_argument("--readers", nargs="+", choices=READERS, default=["scan", "readG2o"])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--reference", type=Path, help="a checkout of another commit, run alternated with this one")
    args = ap.parse_args(argv)
    sides = [("", ROOT)] + ([(" (reference)", args.reference.resolve())] if args.reference else [])

    with open("/proc/loadavg") as fh:
        print(f"load average before: {' '.join(fh.read().split()[:3])}", file=sys.stderr)
    print("| file | MB | reader | best s | MB/s | warm-up s | peak RSS MiB | added by the read MiB "
          "| file + arrays MiB |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|")
    mib = 2 ** 20
    for name in args.files:
        path = _path(args.data_dir, name)
        size = os.path.getsize(path)
        is3d = _is3d(path)
        runs: dict[str, list[dict]] = {}
        for _ in range(args.repeat):  # in turn, so every reader sees the same load
            for reader in args.readers:
                for label, root in (sides if reader != "readG2o" else sides[:1]):
                    runs.setdefault(reader + label, []).append(_run(reader, path, is3d, root))
        arrays = max((r["arrays"] for rs in runs.values() for r in rs), default=0)
        for reader, rs in runs.items():
            best = min(rs, key=lambda r: r["seconds"])
            warm = f"{min(r['warm'] for r in rs):.3f}" if reader.split()[0] in ("scan", "loaded") else "–"
            both = f"{(size + arrays) / mib:.0f}" if arrays else "–"
            label = reader + (" (refused)" if best["refused"] else "")
            print(f"| {os.path.basename(path)} | {size / 1e6:.1f} | {label} | {best['seconds']:.3f} "
                  f"| {size / 1e6 / best['seconds']:.0f} | {warm} | {max(r['peak'] for r in rs) / mib:.0f} "
                  f"| {max(r['peak'] - r['before'] for r in rs) / mib:.0f} | {both} |", flush=True)
    with open("/proc/loadavg") as fh:
        print(f"load average after: {' '.join(fh.read().split()[:3])}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
