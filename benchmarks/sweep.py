"""The sweep on a LocalCluster against the same cases one after another in one process.

    python benchmarks/sweep.py [--graphs intel] [--workers 2] [--repeat 2]

The spec (written to a temporary directory; printed): ``--graphs`` × lf.corrupt's four kinds ×
fractions 0.2 and 0.5 × seeds 1–5 × the method ``ours`` (``gnc = "tls"``): 40 cases on one graph.
Each timing is a fresh process, its whole wall time (start-up, kernels loaded from numba's
cache, every case, the results written):

- ``sweep``: ``lie-factors sweep SPEC --out R.csv --workers N`` (a LocalCluster of N worker
  processes, started and closed by the command);
- ``serial``: this script with ``--serial SPEC``: each graph's clean optimum, then each case
  (:func:`lie_factors.sweeps.cases.measure`), one after another in one process.

Alternated, best of ``--repeat``, with ``uptime`` before and after each. Then the ratio, and
where the sweep's time goes: the cases' own seconds per worker (``case_seconds`` of the rows)
against the wall time; and a check that both give the same figures for every case.
Run under an exclusive lock on a shared machine (``flock -x /tmp/quiet.lock ...``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENV = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
sys.path.insert(0, ROOT)

#: The figures compared between the two ways of running the cases.
FIGURES = ("planted", "rejected", "precision", "recall", "map_error", "ate_rmse", "final_error", "iterations")


def spec_text(graphs: list[str]) -> str:
    lines = ["[graphs]"] + [f'{g} = "{os.path.join(ROOT, "data", g + ".g2o")}"' for g in graphs]
    lines += ["[corruption]", 'kinds = ["uniform", "local", "group", "near"]', "fractions = [0.2, 0.5]",
              "seeds = [1, 2, 3, 4, 5]", "[methods.ours]", 'gnc = "tls"']
    return "\n".join(lines) + "\n"


def serial(spec_path: str, out: str) -> None:
    """Every case of the spec in this process, one after another; their figures to ``out`` (JSON)."""
    from lie_factors.sweeps.cases import cases_of, clean_optimum, graph_data, measure
    from lie_factors.sweeps.spec import read_spec

    spec = read_spec(spec_path)
    rows = {}
    for source in spec.graphs:
        data = graph_data(source)
        clean = clean_optimum(data)
        for case in (c for c in cases_of(spec) if c.graph == source.name):
            rows[case.id] = measure(case, data, clean)
    with open(out, "w") as fh:
        json.dump(rows, fh)


def uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def timed(argv: list[str]) -> float:
    print(f"#   before: {uptime()}", flush=True)
    t = time.perf_counter()
    p = subprocess.run(argv, env=ENV, capture_output=True, text=True)
    seconds = time.perf_counter() - t
    print(f"#   after:  {uptime()}", flush=True)
    print(f"#   {seconds:.1f} s", flush=True)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed: {p.stderr.strip()[-800:]}")
    return seconds


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--graphs", nargs="+", default=["intel"], help="graphs of data/ by name (default: intel)")
    ap.add_argument("--workers", type=int, default=2, help="the LocalCluster's workers (default 2)")
    ap.add_argument("--repeat", type=int, default=2, help="best of this many (default 2)")
    ap.add_argument("--serial", nargs=2, metavar=("SPEC", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.serial:
        serial(*args.serial)
        return 0
    from lie_factors.sweeps.results import read_results

    tmp = tempfile.mkdtemp(prefix="lie-factors-sweep-bench-")
    spec = os.path.join(tmp, "spec.toml")
    with open(spec, "w") as fh:
        fh.write(spec_text(args.graphs))
    print("# spec:\n" + "".join(f"#   {line}\n" for line in spec_text(args.graphs).splitlines()), end="", flush=True)
    best = {"serial": float("inf"), "sweep": float("inf")}
    rows, figures = [], {}
    for k in range(args.repeat):
        print(f"# serial, run {k + 1}", flush=True)
        out = os.path.join(tmp, f"serial{k}.json")
        best["serial"] = min(best["serial"], timed([sys.executable, __file__, "--serial", spec, out]))
        with open(out) as fh:
            figures = json.load(fh)
        print(f"# sweep ({args.workers} workers), run {k + 1}", flush=True)
        out = os.path.join(tmp, f"sweep{k}.csv")
        seconds = timed([sys.executable, "-m", "lie_factors.app.cli", "sweep", spec, "--out", out, "--workers",
                         str(args.workers), "--quiet"])
        if seconds < best["sweep"]:
            best["sweep"], rows = seconds, read_results(out)
    cases = len(rows)
    busy: dict[str, float] = {}
    for r in rows:
        busy[r["worker"]] = busy.get(r["worker"], 0.0) + r["case_seconds"]
    differ = [r["case"] for r in rows if any(
        (r[f] is None) != (figures[r["case"]].get(f) is None)
        or (r[f] is not None and abs(r[f] - figures[r["case"]][f]) > 1e-9 * max(1.0, abs(r[f]))) for f in FIGURES)]
    print(f"| cases | one process, one after another [s] | LocalCluster, {args.workers} workers [s] | ratio |")
    print("|---|---|---|---|")
    print(f"| {cases} | {best['serial']:.1f} | {best['sweep']:.1f} | {best['sweep'] / best['serial']:.2f} |")
    print(f"# the best sweep's cases per worker (count, seconds of their own): "
          + ", ".join(f"{w}: {sum(r['worker'] == w for r in rows)}, {s:.1f} s" for w, s in busy.items())
          + f"; wall {best['sweep']:.1f} s")
    print(f"# cases whose figures differ between the two: {differ or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
