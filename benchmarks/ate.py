"""The absolute trajectory error of the default command's optimum against ground truth, beside
``--backend native``'s, on the graphs shipped with ground truth (data/groundtruth/).

    python benchmarks/ate.py [--datasets city10000 manhattan sphere2500] [--align se3]

Each run is the whole command in a fresh process, ``lie-factors posegraph FILE --groundtruth
GT --json``, its ATE (SE(3)-aligned, as ``evo_ape -a``) read from the JSON; the RPE over one
pose from ``lie-factors evaluate`` on the trajectory it wrote (``--output X.tum``).
Prints a markdown table for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENV = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))


def _json(*args) -> dict:
    p = subprocess.run([sys.executable, "-m", "lie_factors.app.cli", *args, "--json", "--quiet"], env=ENV,
                       capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{args} failed: {p.stderr.strip()[-500:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", nargs="+", default=["city10000", "manhattan", "sphere2500"])
    a = ap.parse_args(argv)
    print("| graph | backend | final error | ATE start (m) | ATE RMSE (m) | ATE max (m) | RPE/1 RMSE (m) |\n"
          "|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.datasets:
            graph = os.path.join(ROOT, "data", f"{name}.g2o")
            truth = os.path.join(ROOT, "data", "groundtruth", f"{name}.tum")
            for backend in ("batch", "native"):
                out = os.path.join(tmp, f"{name}-{backend}.tum")
                run = _json("posegraph", graph, "--backend", backend, "--groundtruth", truth, "--output", out)
                rpe = _json("evaluate", out, truth)["rpe"]
                label = "default" if backend == "batch" else "--backend native"
                print(f"| {name} | {label} | {run['final_error']:.6g} | {run['ate_initial']['rmse']:.6f} | "
                      f"{run['ate']['rmse']:.6f} | {run['ate']['max']:.6f} | {rpe['rmse']:.6f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
