"""``lie-factors sweep SPEC --out RESULTS``: :func:`lie_factors.sweep` (on Dask); ``lie-factors sweep
--summary RESULTS [--plot FILE.png]``: :func:`lie_factors.sweep_summary` and :func:`lie_factors.plot_sweep`."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser, positive_float, bounded_int) -> None:
    p.add_argument("spec", metavar="SPEC", nargs="?",
                   help="the sweep's spec (TOML): graphs, corruptions (lf.corrupt's kinds, fractions, seeds), "
                        "methods (keywords of lf.optimize or lf.replay) and evaluation (docs/cli.md)")
    p.add_argument("--out", metavar="RESULTS",
                   help="the results file, one row per case (.csv, or .parquet with pyarrow), written as cases "
                        "finish; the cases it already holds are not run again")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a running Dask scheduler's address (tcp://host:8786); default: a LocalCluster on this "
                        "machine")
    p.add_argument("--workers", type=bounded_int("--workers", 1, 4096), metavar="N",
                   help="the LocalCluster's worker processes (default: one per core)")
    p.add_argument("--timeout", type=positive_float, metavar="S",
                   help="seconds after which a case is abandoned and recorded as such (default: the spec's "
                        "timeout, else none)")
    p.add_argument("--summary", metavar="RESULTS",
                   help="print the worst and the median of each cell (graph, fraction, kind, method) of a "
                        "results file, as the tables of docs/benchmarks.md")
    p.add_argument("--plot", metavar="FILE.png",
                   help="with --summary: draw precision, recall and map error against the fraction, per kind")
    p.add_argument("--tuning-seeds", type=bounded_int("--tuning-seeds", 0, 2**63 - 1), nargs="*", default=[],
                   metavar="SEED", help="with --summary: seeds left out of the worst and the median")
    p.add_argument("--quiet", action="store_true", help="no progress line")


def run(args) -> int:
    from lie_factors.errors import InputError

    if args.summary is not None:
        if args.spec is not None or args.out is not None or args.scheduler or args.workers or args.timeout:
            raise InputError("--summary RESULTS reads a results file; give no SPEC, --out, --scheduler, "
                             "--workers or --timeout with it")
        import lie_factors as lf

        print(lf.sweep_summary(args.summary, tuning=args.tuning_seeds), flush=True)
        if args.plot:
            lf.plot_sweep(args.summary, args.plot, tuning=args.tuning_seeds)
            if not args.quiet:
                print(f"wrote {args.plot}", flush=True)
        return 0
    if args.plot or args.tuning_seeds:
        raise InputError("--plot and --tuning-seeds go with --summary RESULTS")
    if args.spec is None or args.out is None:
        raise InputError("give SPEC and --out RESULTS to run a sweep, or --summary RESULTS")
    from lie_factors.sweeps import sweep

    rows = sweep(args.spec, args.out, scheduler=args.scheduler, workers=args.workers, timeout=args.timeout,
                 progress=not args.quiet)
    if not args.quiet:
        failed = sum(r["status"] != "ok" for r in rows)
        print(f"{len(rows)} cases in {args.out}, {failed} failed or past the timeout", flush=True)
    return 0
