"""Pose-graph optimization through the CLI's backends: native, custom, batch.

For each dataset: load once (lie_factors.posegraph.load), build the graph with
each backend, run that backend's Levenberg-Marquardt (``posegraph.run``, what
``lie-factors posegraph`` runs), and tabulate iterations, final error and
optimization seconds per backend, with the relative difference of the final
error to native's (acceptance: ≤ 1e-6 for custom, ≤ 1e-4 for batch) and the
time ratio to native.

    python benchmarks/posegraph_backends.py [--data-dir DIR] [--datasets A B ...]
        [--backends native custom batch] [--max-iterations K]
        [--output FILE.md]

Prints the markdown table; with --output also writes it, with a short header, to that file.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import os
import platform
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Run from a checkout without installing: the script's own directory is on
# sys.path, the repository root is not.
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from lie_factors import atomic  # noqa: E402
from lie_factors import posegraph as P  # noqa: E402
DEFAULT_DATASETS = ["parking-garage", "sphere2500", "torus3D", "intel", "MIT", "CSAIL", "smallGrid3D"]
DEFAULT_BACKENDS = ["native", "custom", "batch"]


def dataset_path(data_dir: str, name: str) -> str:
    for candidate in (name, os.path.join(data_dir, name), os.path.join(data_dir, name + ".g2o")):
        if os.path.isfile(candidate):
            return candidate
    return name  # let posegraph.resolve_dataset try GTSAM's examples / report it


def run_dataset(path: str, backends: list[str], max_iterations: int, log) -> dict:
    pg = P.load(path)
    row = {"dataset": pg.name, "dim": "SE(3)" if pg.is3d else "SE(2)", "poses": pg.poses,
           "factors": pg.edges + 1}
    for backend in backends:
        try:
            # Warm-up outside the timing: the first call of each numba kernel
            # compiles it (~1 s), a one-off cost that is not per-iteration speed.
            P.build_graph(pg, backend).linearize(pg.initial)
            record, _, _ = P.run(pg, backend, max_iterations)
        except P.PoseGraphError as exc:  # e.g. custom factors not importable
            log(f"  {backend}: {exc}")
            row[backend] = None
            continue
        log(f"  {backend}: {record.iterations} it, error {record.final_error:.10g}, {record.seconds:.2f} s")
        row[backend] = record
    return row


def _fmt(record, attr, spec):
    return "n/a" if record is None else format(getattr(record, attr), spec)


def markdown_table(rows: list[dict], backends: list[str]) -> str:
    others = [b for b in backends if b != "native"]
    head = ["dataset", "group", "poses", "factors"]
    head += [f"iterations {b}" for b in backends] + [f"final error {b}" for b in backends]
    head += [f"rel. diff {b}" for b in others] + [f"seconds {b}" for b in backends]
    head += [f"ratio {b}/native" for b in others]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        n = r.get("native")
        cells = [r["dataset"], r["dim"], str(r["poses"]), str(r["factors"])]
        cells += [_fmt(r.get(b), "iterations", "d") for b in backends]
        cells += [_fmt(r.get(b), "final_error", ".10g") for b in backends]
        for b in others:
            c = r.get(b)
            ok = n is not None and c is not None
            cells.append(f"{abs(c.final_error - n.final_error) / max(abs(n.final_error), 1e-300):.1e}" if ok else "n/a")
        cells += [_fmt(r.get(b), "seconds", ".3f") for b in backends]
        for b in others:
            c = r.get(b)
            ok = n is not None and c is not None and n.seconds > 0
            cells.append(f"{c.seconds / n.seconds:.2f}" if ok else "n/a")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _gtsam_version() -> str:
    try:
        return importlib.metadata.version("gtsam")
    except importlib.metadata.PackageNotFoundError:  # e.g. built from source
        return "unknown version"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default="/work/shared/data", help="directory of the g2o files")
    parser.add_argument("--datasets", nargs="+", default=DEFAULT_DATASETS,
                        help="names (with or without .g2o), paths, or GTSAM example names")
    parser.add_argument("--backends", nargs="+", default=DEFAULT_BACKENDS, choices=list(P.BACKENDS))
    parser.add_argument("--max-iterations", type=int, default=100)
    parser.add_argument("--output", default="", help="also write the table (with a header) to this markdown file")
    args = parser.parse_args(argv)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    if args.output:
        try:
            atomic.check_writable(args.output)  # before spending minutes optimizing
        except P.PoseGraphError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    rows = []
    for name in args.datasets:
        log(f"{name}:")
        try:
            rows.append(run_dataset(dataset_path(args.data_dir, name), args.backends, args.max_iterations, log))
        except P.PoseGraphError as exc:
            log(f"  skipped: {exc}")
    table = markdown_table(rows, args.backends)
    print(table)
    if args.output:
        stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        text = (
            "# Pose-graph benchmarks: the CLI's backends\n\n"
            f"Generated by `benchmarks/posegraph_backends.py --backends {' '.join(args.backends)}` on {stamp} "
            f"(gtsam {_gtsam_version()}, Python {platform.python_version()}, {platform.machine()}).\n"
            "Same graph for every backend (readG2o noise models, prior on the first pose), "
            "GTSAM's default LevenbergMarquardtParams (native/custom: GTSAM's optimizer stepped "
            "from Python; batch: lie_factors.batch), "
            f"max {args.max_iterations} iterations. Seconds: optimization only (single run, wall clock, "
            "after one warm-up linearization so numba compilation is excluded). "
            "`rel. diff` = |backend − native| / native final error.\n\n"
            + table + "\n"
        )
        atomic.replace_atomically(args.output, lambda tmp: Path(tmp).write_text(text), suffix=".md")
        log(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
