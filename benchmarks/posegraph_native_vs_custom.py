"""Pose-graph optimization: GTSAM's native factors vs lie_factors' custom factors.

For each dataset: load once (lie_factors.posegraph.load), build the graph with
each backend, run the same step-wise Levenberg-Marquardt, and tabulate
iterations, final error and optimization seconds per backend.  The issue's
acceptance criterion is that both backends reach the same final error
(relative difference ≤ 1e-6); the "rel. diff" column shows it.

    python benchmarks/posegraph_native_vs_custom.py [--data-dir DIR] [--datasets A B ...]
        [--max-iterations K] [--output docs/benchmarks_posegraph.md]

Prints the markdown table and writes it (with a short header) to --output.
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

from lie_factors import posegraph as P  # noqa: E402
DEFAULT_DATASETS = ["parking-garage", "sphere2500", "torus3D", "intel", "MIT", "CSAIL", "smallGrid3D"]
BACKENDS = ["native", "custom"]


def dataset_path(data_dir: str, name: str) -> str:
    for candidate in (name, os.path.join(data_dir, name), os.path.join(data_dir, name + ".g2o")):
        if os.path.isfile(candidate):
            return candidate
    return name  # let posegraph.resolve_dataset try GTSAM's examples / report it


def run_dataset(path: str, max_iterations: int, log) -> dict:
    pg = P.load(path)
    row = {"dataset": pg.name, "dim": "SE(3)" if pg.is3d else "SE(2)", "poses": pg.poses,
           "factors": pg.edges + 1}
    for backend in BACKENDS:
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


def markdown_table(rows: list[dict]) -> str:
    head = ("| dataset | group | poses | factors | iterations native | iterations custom "
            "| final error native | final error custom | rel. diff | seconds native "
            "| seconds custom | ratio custom/native |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        n, c = r.get("native"), r.get("custom")
        if n is not None and c is not None:
            diff = f"{abs(c.final_error - n.final_error) / max(abs(n.final_error), 1e-300):.1e}"
            ratio = f"{c.seconds / n.seconds:.1f}" if n.seconds > 0 else "n/a"
        else:
            diff = ratio = "n/a"
        lines.append(
            f"| {r['dataset']} | {r['dim']} | {r['poses']} | {r['factors']} "
            f"| {_fmt(n, 'iterations', 'd')} | {_fmt(c, 'iterations', 'd')} "
            f"| {_fmt(n, 'final_error', '.10g')} | {_fmt(c, 'final_error', '.10g')} | {diff} "
            f"| {_fmt(n, 'seconds', '.3f')} | {_fmt(c, 'seconds', '.3f')} | {ratio} |"
        )
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
    parser.add_argument("--max-iterations", type=int, default=100)
    parser.add_argument("--output", default=str(ROOT / "docs" / "benchmarks_posegraph.md"),
                        help="markdown file to write (default: docs/benchmarks_posegraph.md)")
    args = parser.parse_args(argv)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    if args.output:
        try:
            P.check_writable(args.output)  # before spending minutes optimizing
        except P.PoseGraphError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    rows = []
    for name in args.datasets:
        log(f"{name}:")
        try:
            rows.append(run_dataset(dataset_path(args.data_dir, name), args.max_iterations, log))
        except P.PoseGraphError as exc:
            log(f"  skipped: {exc}")
    table = markdown_table(rows)
    print(table)
    if args.output:
        stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        text = (
            "# Pose-graph benchmarks: native GTSAM factors vs lie_factors custom factors\n\n"
            f"Generated by `benchmarks/posegraph_native_vs_custom.py` on {stamp} "
            f"(gtsam {_gtsam_version()}, Python {platform.python_version()}, {platform.machine()}).\n"
            "Same graph for both backends (readG2o noise models, prior on the first pose), "
            "GTSAM's default LevenbergMarquardtParams stepped from Python, "
            f"max {args.max_iterations} iterations. Seconds: optimization only (single run, wall clock, "
            "after one warm-up linearization so numba compilation is excluded). "
            "`rel. diff` = |custom − native| / native final error.\n\n"
            + table + "\n"
        )
        P.replace_atomically(args.output, lambda tmp: Path(tmp).write_text(text), suffix=".md")
        log(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
