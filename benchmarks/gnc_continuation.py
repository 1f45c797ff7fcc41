"""The false-closure pipeline's GNC continued from its last solution, against GTSAM's restarts;
or its second start's bounded first solve, against LM's own iteration limit.

    python benchmarks/gnc_continuation.py --graphs intel smallGrid3D --kinds uniform group \
        --fractions 0.2 0.5 --seeds 4 5 6 [--repeat 2] [--against unbounded-relaxation]

Each case: the graph from data/, its clean optimum (the default command), ``lf.corrupt``'s false
closures planted from it; then ``lf.optimize(graph, gnc="tls")`` twice, alternated in one process,
best of ``--repeat``: as it ships (each GNC solve after the first starts from the last solution,
``GncSettings.warm_start``), and with every solve restarted from the initial values as GTSAM's
``GncOptimizer`` does (the setting forced off).  One markdown row per case: seconds of each, GNC's
LM iterations, precision, recall, the map's RMS position error in % of the clean optimum's
diagonal, and the status.  ``--clean`` runs the graphs without planted closures instead (true
closures rejected, map error).  ``--against unbounded-relaxation`` compares, the same way, the
pipeline as it ships with the relaxation's first solve given LM's own iteration limit instead of
:func:`lie_factors.robust.rejection.relaxation_iterations`.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from unittest import mock

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import numpy as np  # noqa: E402

import lie_factors as lf  # noqa: E402
from lie_factors import corruption  # noqa: E402
from lie_factors.robust import gnc, pipeline, rejection  # noqa: E402
from lie_factors.sweeps.metrics import map_error_percent  # noqa: E402
from lie_factors.testing.outliers import classify  # noqa: E402


def _restarting(**kw):
    return gnc.GncSettings(**{**kw, "warm_start": False})


def _unbounded(lm_params=None):
    return None


#: ``--against``: (the variant's patch, the two columns' names).
VARIANTS = {
    "restarts": (lambda: mock.patch.object(pipeline, "GncSettings", _restarting), ("continued", "restarted")),
    "unbounded-relaxation": (lambda: mock.patch.object(rejection, "relaxation_iterations", _unbounded),
                             ("bounded", "unbounded")),
}


def run(graph, shipped: bool, against: str = "restarts"):
    """(seconds, result, GNC's LM iterations) of the pipeline as it ships or as ``against`` varies it."""
    inner = []
    original = gnc.gnc_optimize

    def counted(*a, **k):
        r = original(*a, **k)
        inner.append(r.inner_iterations)
        return r

    with mock.patch("lie_factors.robust.solvers.gncm.gnc_optimize", counted), \
            (VARIANTS[against][0]() if not shipped else contextlib.nullcontext()):
        t = time.perf_counter()
        r = lf.optimize(graph, gnc="tls")
        return time.perf_counter() - t, r, sum(i or 0 for i in inner)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--graphs", nargs="+", default=["intel", "smallGrid3D"])
    ap.add_argument("--kinds", nargs="+", default=["uniform", "group"])
    ap.add_argument("--fractions", nargs="+", type=float, default=[0.2])
    ap.add_argument("--seeds", nargs="+", type=int, default=[4, 5, 6])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--clean", action="store_true", help="the graphs without planted closures")
    ap.add_argument("--against", choices=sorted(VARIANTS), default="restarts",
                    help="the variant timed against the pipeline as it ships (module docstring)")
    args = ap.parse_args(argv)
    a, b = VARIANTS[args.against][1]
    print(f"| graph | kind | false | seed | {a} s | {b} s | ratio | LM its {a} / {b} "
          f"| precision {a} / {b} | recall {a} / {b} | map {a} / {b} | status {a} / {b} |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.graphs:
        pg = lf.read_g2o(os.path.join(ROOT, "data", name + ".g2o"))
        clean = lf.optimize(pg)
        ref = np.asarray(clean.poses)[:, :-1, -1]
        lf.optimize(pg, gnc="tls")  # loads every kernel the pipeline runs
        cases = ([("none", 0.0, None)] if args.clean else
                 [(k, f, s) for k in args.kinds for f in args.fractions for s in args.seeds])
        for kind, fraction, seed in cases:
            if seed is None:
                graph, planted = pg, np.zeros(0, dtype=np.int64)
            else:
                c = corruption.plant(pg, fraction=fraction, kind=kind, seed=seed, reference=np.asarray(clean.poses))
                graph, planted = c.graph, c.planted
            best = {True: None, False: None}
            for _ in range(args.repeat):
                for warm in (True, False):
                    out = run(graph, warm, args.against)
                    if best[warm] is None or out[0] < best[warm][0]:
                        best[warm] = out
            cols = []
            for warm in (True, False):
                s, r, its = best[warm]
                k = classify(r.outliers, planted)
                err = map_error_percent(np.asarray(r.poses)[:, :-1, -1], ref)
                cols.append((s, its, k, err, r.robust_status["status"]))
            (s1, i1, k1, e1, st1), (s2, i2, k2, e2, st2) = cols
            prec = (f"{k1.precision:.3f} / {k2.precision:.3f}" if seed is not None else
                    f"{len(best[True][1].outliers)} rejected / {len(best[False][1].outliers)}")
            print(f"| {name} | {kind} | {fraction:.0%} | {seed if seed is not None else '–'} | {s1:.1f} | {s2:.1f} "
                  f"| {s1 / s2:.2f}× | {i1} / {i2} | {prec} | {k1.recall:.3f} / {k2.recall:.3f} "
                  f"| {e1:.3g} % / {e2:.3g} % | {st1} / {st2} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
