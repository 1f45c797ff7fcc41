"""``lie-factors evaluate ESTIMATE REFERENCE``: :func:`lie_factors.evaluate`, reported, plotted, as JSON."""

from __future__ import annotations

import json

import lie_factors as lf
from lie_factors.util.atomic import check_writable, replace_atomically

STATISTICS = ("rmse", "mean", "median", "std", "min", "max")


def run(args) -> int:
    if args.plot:
        check_writable(args.plot)
    ev = lf.evaluate(args.estimate, args.reference, align=args.align, delta=args.delta)
    if not args.quiet:
        print(f"{ev.ate.count} poses associated; alignment {ev.alignment}"
              + (f" (scale {ev.scale:.9g})" if ev.alignment == "sim3" else ""))
        print("            " + "".join(f"{k:>12s}" for k in STATISTICS))
        for label, stats in (("ATE (m)", ev.ate), (f"RPE/{ev.delta} (m)", ev.rpe)):
            d = stats.to_dict()
            print(f"{label:12s}" + "".join(f"{d[k]:12.6g}" for k in STATISTICS))
    if args.plot:
        from .plotting import plot_evaluation

        replace_atomically(args.plot, lambda tmp: plot_evaluation(tmp, ev), suffix=".png")
        if not args.quiet:
            print(f"wrote {args.plot}")
    if args.json:
        print(json.dumps({"estimate": args.estimate, "reference": args.reference, **ev.to_dict()}), flush=True)
    return 0
