"""Where `--gnc tls` spends its time on one corrupted graph: the consistency stage, GNC (and its
factorizations), the final check (and its leave-out statistics), from a profile of one run.

    python benchmarks/robust_stages.py torus3D [--kind group] [--fraction 0.2] [--seed 4]

The graph from data/, its clean optimum (the default command), ``lf.corrupt``'s false closures
planted from it; then ``lf.optimize(graph, gnc="tls")`` once under cProfile, after a first run of
the pipeline on the clean graph in the same process (its kernels loaded, none compiled in the
profiled run).  Prints the verdict (precision, recall, the status, the stage that rejected each
true closure rejected), one markdown row per stage (cumulative seconds and calls),
and one per round of the final check: the closures rejected before it, what it drops and takes
back (of them planted), its likelihood-ratio trials, the tail model's scale and one closure's
threshold.  cProfile's overhead is per Python call; the stages spend
their time in compiled code and CHOLMOD.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import numpy as np  # noqa: E402

import lie_factors as lf  # noqa: E402
from lie_factors import corruption  # noqa: E402
from lie_factors.robust import rejection  # noqa: E402
from lie_factors.testing.outliers import classify  # noqa: E402

#: Stage → (module path suffix, function name) of the profiled call that is the stage.
STAGES = {
    "consistency stage": ("robust/screening.py", "screen_closures"),
    "GNC": ("robust/gnc.py", "gnc_optimize"),
    "final check": ("robust/rejection.py", "check"),
    "leave-out statistics": ("robust/leave_out.py", "leave_out_chi2"),
    "CHOLMOD factorizations": ("sparse/cholmod.py", "factorize"),
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("graph")
    ap.add_argument("--kind", default="group")
    ap.add_argument("--fraction", type=float, default=0.2)
    ap.add_argument("--seed", type=int, default=4)
    args = ap.parse_args(argv)
    pg = lf.read_g2o(os.path.join(ROOT, "data", args.graph + ".g2o"))
    clean = lf.optimize(pg)
    lf.optimize(pg, gnc="tls")  # loads every kernel the pipeline runs
    c = corruption.plant(pg, fraction=args.fraction, kind=args.kind, seed=args.seed,
                         reference=np.asarray(clean.poses))
    planted = set(c.planted.tolist())
    rounds: list[str] = []
    final_round = rejection._final_round

    def logged(graph, X, weights, lc, *rest):
        v = final_round(graph, X, weights, lc, *rest)
        drop, back = v.drop.tolist(), v.back.tolist()
        rounds.append(f"| {len(rounds) + 1} | {int(np.sum(weights[lc] < 0.5))} | {len(drop)} "
                      f"({sum(e in planted for e in drop)}) | {len(back)} ({sum(e in planted for e in back)}) | "
                      f"{len(v.trials)} | {v.model.scale:.3g} | {v.model.threshold(1):.3g} |")
        return v

    rejection._final_round = logged
    profile = cProfile.Profile()
    t = time.perf_counter()
    profile.enable()
    result = lf.optimize(c.graph, gnc="tls")
    profile.disable()
    seconds = time.perf_counter() - t
    k = classify(result.outliers, c.planted)
    status = result.robust_status
    print(f"{args.graph} {args.kind} {args.fraction:.0%} seed {args.seed}: {c.planted.size} planted, "
          f"{seconds:.1f} s, precision {k.precision:.3f}, recall {k.recall:.3f}, "
          f"{status['status']}{''.join('; ' + r for r in status['reasons'])}")
    stages = getattr(result, "rejected_by", None) or {}
    true_out = sorted(set(int(e) for e in result.outliers) - set(int(e) for e in c.planted))
    by = {}
    for e in true_out:
        by[stages.get(e, "?")] = by.get(stages.get(e, "?"), 0) + 1
    print("true closures rejected, by stage:", ", ".join(f"{k} {v}" for k, v in sorted(by.items())) or "none")
    stats = pstats.Stats(profile).stats
    print("| stage | seconds | calls |")
    print("|---|---|---|")
    for stage, (path, name) in STAGES.items():
        found = [(v[3], v[1]) for (file, _, func), v in stats.items() if file.endswith(path) and func == name]
        cum = sum(f[0] for f in found)
        calls = sum(f[1] for f in found)
        print(f"| {stage} | {cum:.1f} | {calls} |")
    print("\n| final check round | rejected before it | drop (false) | take back (false) | trials | scale "
          "| threshold |")
    print("|---|---|---|---|---|---|---|")
    print("\n".join(rounds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
