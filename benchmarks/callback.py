"""Per-callback cost of our factors: ``graph.linearize(values)`` over N Between factors.

Three graphs over the same Python-owned Values, timed alternately, best of
``--repeat``: our BetweenFactor (CustomFactor + ``_evaluate``), a CustomFactor
whose callback only assigns two fixed Jacobians (the pybind11 round trip
alone), and GTSAM's native BetweenFactor. Prints µs per factor.

    python benchmarks/callback.py [--n 2000] [--repeat 7]
"""

import argparse
import time

import gtsam
import numpy as np

from lie_factors.factors import BetweenFactorPose2, BetweenFactorPose3


def graphs(group: str, n: int):
    if group == "Pose2":
        d, ours, native = 3, BetweenFactorPose2, gtsam.BetweenFactorPose2
        value = lambda i: gtsam.Pose2(0.1 * i, 0.2, 0.01 * i)  # noqa: E731
        m = gtsam.Pose2(0.1, 0.0, 0.01)
    else:
        d, ours, native = 6, BetweenFactorPose3, gtsam.BetweenFactorPose3
        value = lambda i: gtsam.Pose3(gtsam.Rot3.RzRyRx(0.01 * i, 0.02, 0.03), gtsam.Point3(0.1 * i, 0.2, 0.3))  # noqa: E731
        m = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.01, 0.0, 0.0), gtsam.Point3(0.1, 0.0, 0.0))
    noise = gtsam.noiseModel.Isotropic.Sigma(d, 0.1)
    values = gtsam.Values()
    for i in range(n + 1):
        values.insert(i, value(i))
    J, e0 = np.eye(d), np.zeros(d)

    def empty(this, v, H):
        if H is not None:
            H[0] = J
            H[1] = J
        return e0

    out = {"ours": gtsam.NonlinearFactorGraph(), "empty callback": gtsam.NonlinearFactorGraph(),
           "native": gtsam.NonlinearFactorGraph()}
    for i in range(n):
        out["ours"].add(ours(i, i + 1, m, noise))
        out["empty callback"].add(gtsam.CustomFactor(noise, [i, i + 1], empty))
        out["native"].add(native(i, i + 1, m, noise))
    return out, values


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=7)
    a = ap.parse_args()
    for group in ("Pose2", "Pose3"):
        gs, values = graphs(group, a.n)
        best = dict.fromkeys(gs, float("inf"))
        for _ in range(a.repeat):
            for name, g in gs.items():
                t = time.perf_counter()
                g.linearize(values)
                best[name] = min(best[name], (time.perf_counter() - t) / a.n * 1e6)
        print(group, "  ".join(f"{k}: {v:.2f} µs" for k, v in best.items()))


if __name__ == "__main__":
    main()
