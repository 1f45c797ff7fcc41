"""What lie_factors.optimizers.compat costs over GTSAM's own functions, side by side in one process.

    python benchmarks/compat.py [--repeats 5] [--datasets sphere2500.txt,cityTrees_reduced_1k.g2o]

For each dataset (GTSAM's example data, found by ``gtsam.findExampleDataFile``;
a prior on pose 0 added): GTSAM's function on GTSAM's factors against the
compat function on ours (``from_gtsam_graph`` of the same graph), for
readG2o, writeG2o, and the initializer (``InitializePose3.initialize`` in 3-D,
``lago.initialize`` in 2-D).  Wall seconds, the minimum over ``--repeats``
runs in which the two alternate.  Also checked: the files written are
identical and the initializers' values equal to the last bit.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import gtsam
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from lie_factors.optimizers import compat  # noqa: E402


def _with_prior(graph, is3D):
    if is3D:
        graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    else:
        graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
    return graph


def alternate(a, b, repeats):
    """(best seconds of a, best of b, last result of a, last result of b), a and b alternating."""
    ta, tb = [], []
    for _ in range(repeats):
        t = time.perf_counter()
        ra = a()
        ta.append(time.perf_counter() - t)
        t = time.perf_counter()
        rb = b()
        tb.append(time.perf_counter() - t)
    return min(ta), min(tb), ra, rb


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--datasets", default="sphere2500.txt,cityTrees_reduced_1k.g2o")
    args = ap.parse_args()
    tmp = tempfile.mkdtemp()
    print("| dataset | factors | function | GTSAM, its factors (s) | compat, ours (s) | ratio |")
    print("|---|---|---|---|---|---|")
    for name in args.datasets.split(","):
        path = gtsam.findExampleDataFile(name)
        is3D = name.startswith(("sphere", "torus", "pose3", "parking"))
        native, initial = gtsam.readG2o(path, is3D)
        ours = compat.from_gtsam_graph(native)
        n = native.size()
        rows = []
        ta, tb, _, _ = alternate(lambda: gtsam.readG2o(path, is3D), lambda: compat.readG2o(path, is3D),
                                 args.repeats)
        rows.append(("readG2o", ta, tb))
        fa, fb = os.path.join(tmp, "gtsam.g2o"), os.path.join(tmp, "ours.g2o")
        ta, tb, _, _ = alternate(lambda: gtsam.writeG2o(native, initial, fa),
                                 lambda: compat.writeG2o(ours, initial, fb), args.repeats)
        with open(fa) as a, open(fb) as b:
            assert a.read() == b.read()
        rows.append(("writeG2o", ta, tb))
        native_p, ours_p = _with_prior(native, is3D), compat.from_gtsam_graph(_with_prior(ours, is3D))
        if is3D:
            fname, fa_, fb_ = ("InitializePose3.initialize", gtsam.InitializePose3.initialize,
                               compat.InitializePose3.initialize)
        else:
            fname, fa_, fb_ = "lago.initialize", gtsam.lago.initialize, compat.lago.initialize
        ta, tb, va, vb = alternate(lambda: fa_(native_p), lambda: fb_(ours_p), args.repeats)
        assert va.equals(vb, 0.0)
        rows.append((fname, ta, tb))
        for fn, a, b in rows:
            print(f"| {name} | {n} | {fn} | {a:.3f} | {b:.3f} | {b / a:.2f}x |")
    print(f"\n(python {sys.version.split()[0]}, numpy {np.__version__}, repeats {args.repeats})")


if __name__ == "__main__":
    main()
