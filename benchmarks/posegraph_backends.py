"""Pose-graph optimization through the CLI's backends: native, dropin, batch.

For each dataset and each start (``--init``; default: the file's vertices and
``auto``): read once (lie_factors.read_g2o), build the graph with each
backend, initialize and run that backend's Levenberg-Marquardt
(``posegraph.run``, what ``lie-factors posegraph`` runs), and tabulate the start
used, iterations, final error, initialization and optimization seconds per
backend, with the relative difference of the final error to native's from the
same start (acceptance: ≤ 1e-6 for dropin, ≤ 1e-4 for batch), the change of
the final error against the file start, and the time ratio to native.

    python benchmarks/posegraph_backends.py [--data-dir DIR] [--datasets A B ...]
        [--backends native dropin batch] [--max-iterations K]
        [--inits file auto] [--repeat N] [--output FILE.md]

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

from lie_factors.util import atomic  # noqa: E402
import lie_factors as lf  # noqa: E402
from lie_factors.backends import BACKENDS, build_graph  # noqa: E402
from lie_factors.g2o import read_pose_graph  # noqa: E402
from lie_factors.errors import InputError  # noqa: E402
from lie_factors.initialization import METHODS as INIT_METHODS  # noqa: E402
DEFAULT_DATASETS = ["parking-garage", "sphere2500", "torus3D", "intel", "MIT", "CSAIL", "smallGrid3D"]
DEFAULT_BACKENDS = ["native", "dropin", "batch"]


def dataset_path(data_dir: str, name: str) -> str:
    for candidate in (name, os.path.join(data_dir, name), os.path.join(data_dir, name + ".g2o")):
        if os.path.isfile(candidate):
            return candidate
    return name  # let g2o.resolve_dataset try GTSAM's examples / report it


def run_dataset(path: str, backends: list[str], max_iterations: int, log,
                inits: tuple[str, ...] = ("file",), repeat: int = 1) -> list[dict]:
    """One row per start in ``inits``; per backend the record of its fastest of ``repeat`` runs.

    The runs alternate (repeat ▸ start ▸ backend), so a slow spell of the shared
    machine hits every column alike.
    """
    pg = read_pose_graph(path)
    base = {"dataset": pg.name, "dim": "SE(3)" if pg.is3d else "SE(2)", "poses": pg.pose_count,
            "factors": pg.edge_count + 1}
    rows = {init: dict(base, init=init) for init in inits}
    for backend in backends:
        try:
            # Warm-up outside the timing: the first call of each numba kernel
            # compiles it (~1 s), a one-off cost that is not per-iteration speed.
            build_graph(pg, backend).linearize(pg.initial)
        except InputError as exc:  # e.g. our factors not importable
            log(f"  {backend}: {exc}")
            for row in rows.values():
                row[backend] = None
    for _ in range(repeat):
        for init in inits:
            row = rows[init]
            for backend in backends:
                if backend in row and row[backend] is None:
                    continue
                try:
                    record = lf.optimize(pg, backend=backend, max_iterations=max_iterations, init=init)
                except InputError as exc:
                    log(f"  {backend} --init {init}: {exc}")
                    row[backend] = None
                    continue
                log(f"  {backend} --init {init} ({record.init}, {record.init_seconds:.2f} s): "
                    f"{record.iterations} it, error {record.error:.10g}, {record.seconds:.2f} s")
                best = row.get(backend)
                if best is None or record.init_seconds + record.seconds < best.init_seconds + best.seconds:
                    row[backend] = record
    return list(rows.values())


def _fmt(record, attr, spec):
    return "n/a" if record is None else format(getattr(record, attr), spec)


def _rel(a, b) -> str:
    return f"{abs(a - b) / max(abs(b), 1e-300):.1e}"


def markdown_table(rows: list[dict], backends: list[str]) -> str:
    """One line per (dataset, start).

    ``start`` is the method that ran (``auto`` resolves to chordal, lago, …);
    ``vs file`` is (final − final from the file start) / final from the file
    start for the first backend, negative when the start found a lower minimum;
    ``total`` = initialization + optimization seconds.
    """
    ref = backends[0]
    others = backends[1:]
    head = ["dataset", "group", "poses", "factors", "start"]
    head += [f"iterations {b}" for b in backends] + [f"final error {b}" for b in backends]
    head += [f"rel. diff {b}" for b in others] + [f"vs file ({ref})"]
    head += [f"init s {b}" for b in backends] + [f"optimize s {b}" for b in backends]
    head += [f"total s {b}" for b in backends] + [f"ratio {b}/{ref} (optimize)" for b in others]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    file_final = {r["dataset"]: r[ref].error for r in rows
                  if r["init"] == "file" and r.get(ref) is not None}
    for r in rows:
        n = r.get(ref)
        start = next((r[b].init for b in backends if r.get(b) is not None), "n/a")
        cells = [r["dataset"], r["dim"], str(r["poses"]), str(r["factors"]), start]
        cells += [_fmt(r.get(b), "iterations", "d") for b in backends]
        cells += [_fmt(r.get(b), "error", ".10g") for b in backends]
        for b in others:
            c = r.get(b)
            cells.append(_rel(c.error, n.error) if n is not None and c is not None else "n/a")
        f = file_final.get(r["dataset"])
        cells.append(f"{(n.error - f) / f:+.1e}" if n is not None and f else "n/a")
        cells += [_fmt(r.get(b), "init_seconds", ".3f") for b in backends]
        cells += [_fmt(r.get(b), "seconds", ".3f") for b in backends]
        cells += ["n/a" if r.get(b) is None else f"{r[b].init_seconds + r[b].seconds:.3f}"
                  for b in backends]
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
    parser.add_argument("--data-dir", default=str(ROOT / "data"), help="directory of the g2o files")
    parser.add_argument("--datasets", nargs="+", default=DEFAULT_DATASETS,
                        help="names (with or without .g2o), paths, or GTSAM example names")
    parser.add_argument("--backends", nargs="+", default=DEFAULT_BACKENDS, choices=list(BACKENDS))
    parser.add_argument("--max-iterations", type=int, default=100)
    parser.add_argument("--inits", nargs="+", default=["file", "auto"], choices=list(INIT_METHODS),
                        help="starts (lie-factors posegraph --init), one table row each")
    parser.add_argument("--repeat", type=int, default=1,
                        help="runs per (start, backend), interleaved; the fastest is reported")
    parser.add_argument("--output", default="", help="also write the table (with a header) to this markdown file")
    args = parser.parse_args(argv)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    if args.output:
        try:
            atomic.check_writable(args.output)  # before spending minutes optimizing
        except InputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    rows = []
    for name in args.datasets:
        log(f"{name}:")
        try:
            rows.extend(run_dataset(dataset_path(args.data_dir, name), args.backends, args.max_iterations,
                                    log, tuple(args.inits), args.repeat))
        except InputError as exc:
            log(f"  skipped: {exc}")
    table = markdown_table(rows, args.backends)
    print(table)
    if args.output:
        stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        text = (
            "# Pose-graph benchmarks: the CLI's backends and starts\n\n"
            f"Generated by `benchmarks/posegraph_backends.py --backends {' '.join(args.backends)}` on {stamp} "
            f"(gtsam {_gtsam_version()}, Python {platform.python_version()}, {platform.machine()}).\n"
            "Same graph for every backend (readG2o noise models, prior on the first pose), "
            "GTSAM's default LevenbergMarquardtParams (native/dropin: GTSAM's optimizer stepped "
            "from Python; batch: lie_factors.batch), "
            f"max {args.max_iterations} iterations, starts {' '.join(args.inits)} (`--init`). "
            f"Seconds: wall clock, fastest (init + optimize) of {args.repeat} interleaved run(s), "
            "after one warm-up linearization so numba compilation is excluded; `init s` is the "
            "initializer, `optimize s` LM construction + iterations. "
            f"`rel. diff` = |backend − {args.backends[0]}| / {args.backends[0]} final error from the same start; "
            "`vs file` = (final − final from the file start) / final from the file start.\n\n"
            + table + "\n"
        )
        atomic.replace_atomically(args.output, lambda tmp: Path(tmp).write_text(text), suffix=".md")
        log(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
