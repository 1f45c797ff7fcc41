"""The smoother's choices measured on replays: how small sets are ordered, and which variables are relinearized when.

    python benchmarks/incremental_choices.py [--datasets intel kitti_00 parking-garage sphere2500 FILE.g2o ...]
        [--variants default colamd md64 variable global] [--repeat 2]

Each variant is the replay of :func:`lie_factors.incremental.replay.replay_arrays` (what
``lie-factors posegraph FILE --incremental`` runs) with one choice changed:

- ``default``: the library's choices;
- ``colamd``: every set of more than three variables ordered by GTSAM's CCOLAMD (no minimum
  degree on small sets, ``BlockFactor.max_small = 3``);
- ``mdK`` (``md64``, …): sets of up to K variables ordered by minimum degree
  (``BlockFactor.max_small = K``; the default is
  :data:`~lie_factors.incremental.ordering.MAX_SMALL`, the kernel takes up to 64);
- ``variable``, ``global``: ``SmootherParams.relinearizePolicy``.

Variants alternate within one process (repeat ▸ dataset ▸ variant, the order reversed every
other repeat); each reports its best update seconds of ``--repeat``, the dense elimination
work (Σ D·N² over fronts), the columns re-eliminated, the variables relinearized, and the
final error of the whole graph.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from lie_factors.g2o import read_pose_graph  # noqa: E402
from lie_factors.incremental import Smoother, SmootherParams  # noqa: E402
from lie_factors.incremental.replay import replay_arrays, warm_up_smoother  # noqa: E402

VARIANTS = ("default", "colamd", "variable", "global")


def load(name: str):
    for candidate in (ROOT / "data" / f"{name}.g2o", Path(name)):
        if candidate.is_file():
            return read_pose_graph(str(candidate))
    raise SystemExit(f"no graph {name}")


def smoother(variant: str) -> Smoother:
    policy = variant if variant in ("variable", "global") else SmootherParams().relinearizePolicy
    s = Smoother(SmootherParams(relinearizePolicy=policy))
    if variant == "colamd":
        s.bf.max_small = 3
    elif variant.startswith("md"):
        s.bf.max_small = int(variant[2:])
    return s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", nargs="+", default=["intel", "kitti_00", "parking-garage", "sphere2500"])
    ap.add_argument("--variants", nargs="+", default=["default", "colamd"],
                    help=f"{', '.join(VARIANTS)}, or mdK (minimum degree on sets of up to K variables)")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args(argv)
    for v in args.variants:
        if v not in VARIANTS and not (v.startswith("md") and v[2:].isdigit() and 3 <= int(v[2:]) <= 64):
            ap.error(f"unknown variant {v}")
    print(f"# load: {subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()}", flush=True)
    graphs = {name: load(name) for name in args.datasets}
    for pg in graphs.values():
        warm_up_smoother(pg.group)
    best: dict = {}
    for r in range(args.repeat):
        for name, pg in graphs.items():
            for variant in (args.variants if r % 2 == 0 else args.variants[::-1]):
                s = smoother(variant)
                res = replay_arrays(pg, s)
                print(f"# repeat {r + 1} {name} {variant}: {res.update_seconds:.3f} s", file=sys.stderr, flush=True)
                key = (name, variant)
                if key not in best or res.update_seconds < best[key][0].update_seconds:
                    best[key] = (res, int(s.bf.work.stats[6]), s.bf.totals.columns, s.relinearizations)
    print(f"# load after: {subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()}")
    print("| graph | variant | update s | p99 ms | work Σ D·N² | columns | relinearized | final error |")
    print("|---|---|---|---|---|---|---|---|")
    for name, pg in graphs.items():
        for variant in args.variants:
            res, work, columns, relin = best[(name, variant)]
            print(f"| {pg.name} | {variant} | {res.update_seconds:.3f} | {res.update_p99 * 1e3:.2f} | {work:.3g} | "
                  f"{columns} | {relin} | {res.error:.10g} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
