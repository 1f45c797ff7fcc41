"""``lie-factors corrupt FILE OUT``: :func:`lie_factors.corrupt`, written with :func:`lie_factors.write_corruption`."""

from __future__ import annotations

import argparse
import json
import math

#: lie_factors.corruption.KINDS, here so that building the parser imports no numpy (a test checks they agree).
KINDS = ("uniform", "local", "group", "near")


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value) or not 0.0 < value <= 10.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 10], got {text}")
    return value


def add_arguments(p: argparse.ArgumentParser, seed_type) -> None:
    p.add_argument("file", metavar="FILE", help="a g2o pose graph (Pose2 or Pose3), taken as free of false closures")
    p.add_argument("out", metavar="OUT", help="the corrupted g2o file to write")
    p.add_argument("--fraction", type=_fraction, required=True, metavar="F",
                   help="false closures to plant, as a fraction of FILE's loop closures (0.2: one for every "
                        "five true ones)")
    p.add_argument("--kind", choices=KINDS, default="uniform",
                   help="uniform: random pose pairs, random relative poses (default); local: pairs within 20 "
                        "poses; group: runs of 8-12 consecutive closures between two places agreeing on one "
                        "wrong relative pose; near: such runs 5-15 sigma off the true relation")
    p.add_argument("--seed", type=seed_type, default=0, metavar="S", help="the random seed (default: 0)")
    p.add_argument("--planted", metavar="LIST",
                   help="where to write the planted closures, one 'edge key1 key2' a line: the edge's index among OUT's "
                        "edges and the keys it joins (default: OUT with its extension replaced by .planted.txt)")
    p.add_argument("--json", action="store_true", help="print a JSON summary as the last line of stdout")
    p.add_argument("--quiet", action="store_true", help="no human-readable report")


def run(args) -> int:
    import lie_factors as lf
    from lie_factors.corruption import planted_path
    from lie_factors.util.atomic import check_writable

    import os

    from lie_factors.errors import InputError

    planted = args.planted if args.planted is not None else planted_path(args.out)
    for out in (args.out, planted):
        if os.path.exists(out) and os.path.exists(args.file) and os.path.samefile(out, args.file):
            raise InputError(f"{out}: would overwrite the input graph {args.file}")
    check_writable(args.out)
    check_writable(planted)
    c = lf.corrupt(args.file, fraction=args.fraction, kind=args.kind, seed=args.seed)
    lf.write_corruption(c, args.out, planted)
    if not args.quiet:
        print(f"planted {len(c.planted)} {args.kind} false loop closures ({args.fraction:g} of "
              f"{len(c.graph.loop_closures()) - len(c.planted)}); wrote {args.out} and {planted}")
    if args.json:
        print(json.dumps({"file": args.file, "out": args.out, "planted_list": planted, "kind": args.kind,
                          "fraction": args.fraction, "seed": args.seed,
                          "planted": c.planted.tolist()}), flush=True)
    return 0
