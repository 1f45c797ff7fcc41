"""The whole command, as a user runs it: ``lie-factors posegraph FILE --json``, default backend vs native.

    python benchmarks/posegraph_e2e.py [--repeats 2] [--datasets sphere2500,intel,...]
        [--init auto] [--output FILE.md] [--reference DIR]

Each run is a fresh process (``python -c 'from lie_factors.app import cli; cli.entry()'``,
what the ``lie-factors`` script runs), timed from outside (wall seconds from
spawning to exit, so Python's start-up and every import count), with its peak
RSS read from ``/proc/self/status`` (``VmHWM``: ``ru_maxrss`` would carry this
process's peak across fork + exec) just before it exits.  Native and batch
alternate (native first in odd repetitions, batch first in even ones); the
best wall time of ``--repeats`` counts, with that run's ``--json`` record:
``seconds`` (optimization, set-up included) and ``timings`` (imports, read and
check, initialization, set-up, iterations), and that process's CPU seconds
(user + system, all threads: less disturbed by the machine's other users).

Graphs: the datasets in ``$LIE_FACTORS_DATA`` (default data/),
``w20000`` (GTSAM's ``w20000.txt``), and seeded SE(3) helix graphs with loop
closures written by ``benchmarks/generate_posegraph.py`` (``helix20k``,
``helix100k``: 20 000 / 100 000 poses, a closure every 10th pose).

``--reference DIR`` adds a third side, the default command of another checkout of the
library (``PYTHONPATH=DIR``, e.g. ``git archive main | tar -x -C DIR``), alternated with the
other two, and a second table: that checkout's default command against this one's.

The targets checked per row: whole command ≤ native's (≥ 10k
factors) or ≤ native's + 0.5 s (smaller graphs); optimization ≤ 0.7×
native's; the same optimum (1e-4 relative); peak RSS ≤ max(1.5× native's,
native's + 150 MB).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("LIE_FACTORS_DATA", os.path.join(ROOT, "data"))
GENERATED = os.environ.get("LIE_FACTORS_TMP", "/tmp")
DEFAULT = "sphere2500,torus3D,city10000,intel,kitti_00,parking-garage,w20000,helix20k,helix100k"
SPLIT = ("imports", "read", "init", "setup", "iterations")

CODE = ("import sys; from lie_factors.app import cli; rc = cli.entry(); "
        "hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')][0]; "
        "print('VmHWM', hwm.split()[1], file=sys.stderr); sys.exit(rc)")


def dataset_path(name: str) -> str:
    if name == "w20000":
        import gtsam

        return gtsam.findExampleDataFile("w20000.txt")
    if name.startswith("helix") and name.endswith("k"):
        poses = int(name[5:-1]) * 1000
        path = os.path.join(GENERATED, f"lie_factors_{name}.g2o")
        if not os.path.exists(path):
            subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "generate_posegraph.py"),
                            "--poses", str(poses), "--closure-every", "10", "--seed", "0",
                            "--output", path], check=True)
        return path
    return os.path.join(DATA, name + ".g2o")


#: Further options of every run (``--args``), e.g. ``--gnc tls``.
EXTRA: list[str] = []


def run_once(path: str, backend: str, init: str, root: str = ROOT) -> tuple[float, float, dict]:
    """(wall seconds, peak RSS MiB, --json record) of one fresh ``lie-factors posegraph`` process.

    The record gains ``cpu``: the process's user + system CPU seconds (all its
    threads), a figure the machine's other users disturb less than wall time.
    """
    env = dict(os.environ, PYTHONPATH=root)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    # cwd: `python -c` puts the working directory first on sys.path, before PYTHONPATH
    p = subprocess.run([sys.executable, "-c", CODE, "posegraph", path, "--backend", backend, "--init", init,
                        *EXTRA, "--json", "--quiet"], capture_output=True, text=True, env=env, cwd=root)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if p.returncode != 0:
        raise RuntimeError(f"{backend} on {path}: {p.stderr.strip()[-500:]}")
    hwm = [line for line in p.stderr.splitlines() if line.startswith("VmHWM")][-1]
    record = json.loads(p.stdout.strip().splitlines()[-1])
    record["cpu"] = cpu
    return wall, int(hwm.split()[1]) / 1024.0, record


def load_average() -> str:
    with open("/proc/loadavg") as fh:
        return " ".join(fh.read().split()[:3])


def measure(name: str, repeats: int, init: str, reference: str = "") -> dict:
    path = dataset_path(name)
    best: dict = {}
    loads = [load_average()]
    sides = ("native", "batch", "reference") if reference else ("native", "batch")
    for r in range(repeats):
        order = sides[r % len(sides):] + sides[:r % len(sides)]
        for side in order:
            if side == "reference":
                wall, rss, rec = run_once(path, "batch", init, reference)
            else:
                wall, rss, rec = run_once(path, side, init)
            if side not in best or wall < best[side][0]:
                best[side] = (wall, rss, rec)
    loads.append(load_average())
    return {"name": name, "best": best, "load": loads}


def verdict(row: dict) -> dict:
    (wn, rn, n), (wb, rb, b) = row["best"]["native"], row["best"]["batch"]
    small = n["factors"] < 10_000
    return {
        "whole": wb <= (wn + 0.5 if small else wn),
        "opt": b["seconds"] <= 0.7 * n["seconds"],
        "optimum": abs(b["final_error"] - n["final_error"]) <= 1e-4 * abs(n["final_error"]),
        "rss": rb <= max(1.5 * rn, rn + 150.0),
    }


def table(rows: list[dict]) -> str:
    out = ["| graph | factors | init | whole command, native → default (s) | CPU, native → default (s) "
           "| optimization, native → default (s) "
           "| peak RSS, native → default (MiB) | default split: imports / read / init / setup / iterations (s) "
           "| native split (s) | iterations n / d | final error n / d | meets: whole, opt, optimum, RSS | load |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        (wn, rn, n), (wb, rb, b) = row["best"]["native"], row["best"]["batch"]
        v = verdict(row)
        split = " / ".join(f"{b['timings'][k]:.2f}" for k in SPLIT)
        nsplit = " / ".join(f"{n['timings'][k]:.2f}" for k in SPLIT)
        ratio = b["seconds"] / n["seconds"] if n["seconds"] else float("nan")
        out.append(
            f"| {row['name']} | {n['factors']} | {b['init']} | {wn:.2f} → {wb:.2f} | {n['cpu']:.2f} → {b['cpu']:.2f} | "
            f"{n['seconds']:.3f} → {b['seconds']:.3f} ({ratio:.2f}×) | {rn:.0f} → {rb:.0f} | {split} | {nsplit} | "
            f"{n['iterations']} / {b['iterations']} | {n['final_error']:.6g} / {b['final_error']:.6g} | "
            + ", ".join("yes" if v[k] else "**no**" for k in ("whole", "opt", "optimum", "rss"))
            + f" | {row['load'][0]} → {row['load'][1]} |")
    return "\n".join(out)


def reference_table(rows: list[dict]) -> str:
    """The default command of the reference checkout against this one's (best runs)."""
    out = ["| graph | whole command, reference → this (s) | ratio | CPU (s) | optimization (s) | peak RSS (MiB) "
           "| final error | load |",
           "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        (wr, rr, r), (wb, rb, b) = row["best"]["reference"], row["best"]["batch"]
        out.append(f"| {row['name']} | {wr:.2f} → {wb:.2f} | {wb / wr:.3f} | {r['cpu']:.2f} → {b['cpu']:.2f} | "
                   f"{r['seconds']:.3f} → {b['seconds']:.3f} | {rr:.0f} → {rb:.0f} | "
                   f"{r['final_error']:.9g} / {b['final_error']:.9g} | {row['load'][0]} → {row['load'][1]} |")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--datasets", default=DEFAULT)
    ap.add_argument("--init", default="auto")
    ap.add_argument("--output", default="", help="also write the table to this markdown file")
    ap.add_argument("--args", default="", help="further options of every run, e.g. '--gnc tls'")
    ap.add_argument("--reference", default="", metavar="DIR",
                    help="another checkout whose default command runs alongside (PYTHONPATH=DIR)")
    args = ap.parse_args(argv)
    EXTRA[:] = args.args.split()
    rows = []
    for name in args.datasets.split(","):
        row = measure(name, args.repeats, args.init, args.reference)
        rows.append(row)
        print(table([row]).splitlines()[-1], flush=True)
    text = (f"python benchmarks/posegraph_e2e.py --repeats {args.repeats} --init {args.init} "
            f"--datasets {args.datasets}" + (f" --args '{args.args}'" if args.args else "")
            + (f" --reference {args.reference}" if args.reference else "")
            + "\n\n" + table(rows) + "\n")
    if args.reference:
        text += "\n" + reference_table(rows) + "\n"
    print(text)
    if args.output:
        with open(args.output, "w") as fh:
            fh.write(text)


if __name__ == "__main__":
    main()
