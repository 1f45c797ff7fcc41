"""The fixed-lag smoother against GTSAM's: update time and agreement over a Pose3 run.

    python benchmarks/fixed_lag.py [--poses 1000] [--lag 10] [--rate 10] [--repeat 5] [--seeds 0 1]
        [--agreement]

A noisy Pose3 chain with loop closures 8 poses back every 7 poses (GTSAM's own Pose3 factors,
whose Jacobians are exact, in both), a pose every 1/``rate`` s, each new pose started at the
previous estimate composed with the odometry; ``gtsam.IncrementalFixedLagSmoother`` and
``lf.IncrementalFixedLagSmoother`` with ISAM2's default parameters, and again with an exact
back-substitution (wildfire threshold 0), alternated in one process, best of ``repeat``
(each timed leg after an untimed one).  Prints the total and the median update time, their
ratio, the variables each re-eliminated over the run (GTSAM's ``getVariablesReeliminated`` summed,
ours counted by the factor), the
largest difference of the final estimates (max |Log(A⁻¹B)|), and, as the scale that
difference is judged on, GTSAM's own: its final estimate against its run with each new pose's
start moved by 1e-15 (the run feeds each estimate into the next start, and amplifies its last
bits).  Also the totals with each read of the last estimate (the loop's, timed apart: ours
solves for δ when read, GTSAM's too, when its update did not), and the 99th percentile and the
longest update (ours marginalizes what left the window many keys at a time).
"""

from __future__ import annotations

import argparse
import statistics
import time

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

import lie_factors as lf


def truth_poses(n: int) -> list:
    """The chain's true poses."""
    truth = [gtsam.Pose3()]
    for i in range(1, n):
        truth.append(truth[-1].compose(_step(i)))
    return truth


def _step(i: int) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3.RzRyRx(0.01, 0.02 * np.cos(i / 20), 0.1 * np.sin(i / 10)), np.array([1.0, 0.0, 0.1]))


def chain(n: int, seed: int) -> list:
    """(factors, odometry) of each update; the value of a new pose is filled in at run time."""
    rng = np.random.default_rng(seed)
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.02] * 3 + [0.05] * 3))
    truth = truth_poses(n)
    out = [([gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), noise)], None)]
    for i in range(1, n):
        step = _step(i)
        z = step.compose(gtsam.Pose3.Expmap(rng.normal(0, [0.02] * 3 + [0.05] * 3)))
        factors = [gtsam.BetweenFactorPose3(X(i - 1), X(i), z, noise)]
        if i > 12 and i % 7 == 0:
            zc = truth[i - 8].between(truth[i]).compose(gtsam.Pose3.Expmap(rng.normal(0, 0.03, 6)))
            factors.append(gtsam.BetweenFactorPose3(X(i - 8), X(i), zc, noise))
        out.append((factors, z))
    return out


def params(exact: bool, relinearize: str = "default") -> gtsam.ISAM2Params:
    """ISAM2's default parameters; ``exact``: wildfire threshold 0; ``relinearize``: ``"off"``,
    or ``"every"`` (every variable at every update: a Gauss–Newton step each)."""
    p = gtsam.ISAM2Params()
    p.enableRelinearization = relinearize != "off"
    if relinearize == "every":
        p.relinearizeSkip = 1
        p.setRelinearizeThreshold(0.0)
    if exact:
        gn = gtsam.ISAM2GaussNewtonParams()
        gn.setWildfireThreshold(0.0)
        p.setOptimizationParams(gn)
    return p


def run(cls, updates: list, lag: float, rate: float, exact: bool, perturb: float = 0.0, starts: list | None = None,
        relinearize: str = "default"):
    """(smoother, update seconds, variables re-eliminated in all, seconds of each read of the
    last estimate, which the next start composes); ``perturb``: each new pose's start moved by
    Exp(perturb·n), n drawn from N(0, I₆) (seed 0): the run's own sensitivity to its last bits;
    ``starts``: the new poses' starts given (no feedback from the estimates, no reads);
    ``relinearize``: as :func:`params` takes it."""
    s = cls(lag, params(exact, relinearize))
    rng = np.random.default_rng(0)
    times = []
    reeliminated = 0
    reads = []
    for i, (factors, z) in enumerate(updates):
        g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for f in factors:
            g.add(f)
        if starts is not None:
            start = starts[i]
        else:
            t = time.perf_counter()
            last = None if z is None else s.calculateEstimatePose3(X(i - 1))
            reads.append(time.perf_counter() - t)
            start = gtsam.Pose3() if z is None else last.compose(z)
        if perturb:
            start = start.compose(gtsam.Pose3.Expmap(perturb * rng.normal(size=6)))
        v.insert(X(i), start)
        t = time.perf_counter()
        s.update(g, v, {X(i): i / rate})
        times.append(time.perf_counter() - t)
        reeliminated += s.getISAM2Result().getVariablesReeliminated()
    if isinstance(s, lf.IncrementalFixedLagSmoother):  # every re-elimination, those of late marginalizations too
        reeliminated = s.isam.bf.totals.columns
    return s, np.array(times), reeliminated, np.array(reads)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=1000)
    ap.add_argument("--lag", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--agreement", action="store_true",
                    help="instead: agreement on runs whose starts do not depend on the estimates")
    a = ap.parse_args()
    if a.agreement:
        agreement(a)
        return
    print("| seed | back-substitution | GTSAM s | ours s | × | with the reads, GTSAM / ours s | × | "
          "median update GTSAM / ours ms | p99 update GTSAM / ours ms | longest update GTSAM / ours ms | "
          "variables re-eliminated GTSAM "
          "(reported) / ours (counted by the factor) | final max diff | GTSAM against itself, starts moved by 1e-15 |")
    print("|---|---|---:|---:|---:|---|---:|---|---|---|---|---:|---:|")
    for seed in a.seeds:
        updates = chain(a.poses, seed)
        for exact in (False, True):
            best = {"gtsam": None, "ours": None}
            steps = {"gtsam": np.inf, "ours": np.inf}
            finals, counts = {}, {}
            for _ in range(a.repeat):
                for name, cls in (("gtsam", gtsam.IncrementalFixedLagSmoother),
                                  ("ours", lf.IncrementalFixedLagSmoother)):
                    run(cls, updates[:50], a.lag, a.rate, exact)  # untimed: caches and allocations
                    s, t, counts[name], reads = run(cls, updates, a.lag, a.rate, exact)
                    if best[name] is None or t.sum() < best[name].sum():
                        best[name] = t
                    steps[name] = min(steps[name], t.sum() + reads.sum())
                    finals[name] = s.calculateEstimate()
            perturbed = run(gtsam.IncrementalFixedLagSmoother, updates, a.lag, a.rate, exact, PERTURB)[0]
            diff = largest_difference(finals["gtsam"], finals["ours"])
            itself = largest_difference(finals["gtsam"], perturbed.calculateEstimate())
            g, o = best["gtsam"], best["ours"]
            print(f"| {seed} | {'exact' if exact else 'wildfire'} | {g.sum():.3f} | {o.sum():.3f} | "
                  f"{o.sum() / g.sum():.2f} | {steps['gtsam']:.3f} / {steps['ours']:.3f} | "
                  f"{steps['ours'] / steps['gtsam']:.2f} | "
                  f"{1e3 * statistics.median(g):.3f} / {1e3 * statistics.median(o):.3f} | "
                  f"{1e3 * np.percentile(g, 99):.2f} / {1e3 * np.percentile(o, 99):.2f} | "
                  f"{1e3 * g.max():.2f} / {1e3 * o.max():.2f} | "
                  f"{counts['gtsam']} / {counts['ours']} | {diff:.2e} | {itself:.2e} |", flush=True)


def agreement(a) -> None:
    """``--agreement``: ours against GTSAM's, and GTSAM's against itself with its starts moved
    by 1e-15, on runs whose starts do not depend on the estimates (the truth moved by
    Exp(N(0, 0.05² I₆)), seed + 100), with relinearization as ISAM2's default and off (then
    both solve the same sequence of linear systems); and on the benchmark's run (starts from
    the estimates) relinearizing every variable at every update, exactly (no threshold
    decides anything)."""
    print("| seed | starts | back-substitution | relinearization | ours against GTSAM | GTSAM against itself |")
    print("|---|---|---|---|---:|---:|")
    for seed in a.seeds:
        updates = chain(a.poses, seed)
        rng = np.random.default_rng(seed + 100)
        starts = [p.compose(gtsam.Pose3.Expmap(rng.normal(0, 0.05, 6))) for p in truth_poses(a.poses)]
        cases = [(starts, exact, relin) for exact in (False, True) for relin in ("default", "off")]
        for given, exact, relin in cases + [(None, True, "every")]:
            def final(cls, perturb=0.0):
                return run(cls, updates, a.lag, a.rate, exact, perturb, given, relin)[0].calculateEstimate()
            theirs, ours = final(gtsam.IncrementalFixedLagSmoother), final(lf.IncrementalFixedLagSmoother)
            moved = final(gtsam.IncrementalFixedLagSmoother, PERTURB)
            print(f"| {seed} | {'fixed' if given is not None else 'estimates'} | {'exact' if exact else 'wildfire'} "
                  f"| {relin} | {largest_difference(theirs, ours):.2e} | {largest_difference(theirs, moved):.2e} |",
                  flush=True)


#: How far each start is moved for GTSAM's own sensitivity: about one unit in the last place of a
#: coordinate of order 1.
PERTURB = 1e-15


def largest_difference(a: gtsam.Values, b: gtsam.Values) -> float:
    """max over the poses of |Log(A⁻¹B)|."""
    return max(float(np.max(np.abs(gtsam.Pose3.Logmap(a.atPose3(k).between(b.atPose3(k)))))) for k in a.keys())


if __name__ == "__main__":
    main()
