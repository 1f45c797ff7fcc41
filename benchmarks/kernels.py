"""Kernel cost per call against GTSAM's, batched throughput, and accuracy (the crosscheck table).

    python benchmarks/kernels.py [--only percall|breakdown|ratios|batched|accuracy] [--calls 20000] [--repeat 5]
                                 [--n 100000] [--ratio-n 200000] [--samples 5] [--groups so3,se3,...]
                                 [--clock cpu|wall]

Timings use the calling thread's CPU time by default (``time.thread_time``): on
this shared 2-core machine wall time mostly measures the other jobs, while a
kernel call's CPU time is its cost (``--clock wall`` for wall time).

percall: one element per call (every group, then the unit and dual quaternions), steady state (warmed up first), the best of ``--repeat``
rounds of ``--calls`` calls, ours and GTSAM's nearest call alternated round by round
in the same process. Our inputs are what a user's factor holds: float64 arrays, the
tangent of shape (n,), the element a C-ordered (m, m) matrix (one row also times the
Fortran-ordered matrix that GTSAM's ``.matrix()`` returns). GTSAM's inputs are its own
objects (``Pose3`` …) where its call takes one, built once outside the loop.

breakdown: where one ``se3.Ad(X)`` call goes: the whole call, its compiled part called
directly and through numba's dispatcher, the output's allocation, the fast path's type test.

ratios: Sim(3) against SE(3) on ``--ratio-n`` elements (exp, log, dexp, dlog), the
median of 7 calls each, the two alternated.

batched: every public kernel on ``--n`` elements (median of 7 calls after a warm-up
call, input validation and output allocation included). Rotation angles uniform in
[0, π), translations ~N(0, 10²), λ uniform in [-2, 2].

accuracy: ``lie_factors.app.crosscheck.run``, ours and GTSAM's error against the
50-digit reference per function and θ band.
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import statistics
import time

import gtsam
import numpy as np

from lie_factors.app import crosscheck
from lie_factors import se3, sim3
from lie_factors import interop
from lie_factors.kernels import registry

#: The clock of every timing (set by --clock): the thread's CPU time or wall time.
clock = time.thread_time

FUNCTIONS = ("exp", "log", "dexp", "dlog", "Ad", "ad", "compose", "inverse", "hat", "vee")


def _tangents(group: str, n: int, rng) -> np.ndarray:
    """n tangent vectors: rotation angle uniform in [0, π), translations ~N(0, 10²), λ in [-2, 2]."""
    K = crosscheck.KERNELS[group]
    x = 10.0 * rng.normal(size=(n, K.DIM))
    r = crosscheck.rotation_slice(group)
    w = rng.normal(size=(n, r.stop - r.start))
    w *= (rng.uniform(0, np.pi, size=n) / np.linalg.norm(w, axis=1))[:, None]
    x[:, r] = w
    if registry.group(group).corner == registry.POSITIVE:  # λ of Sim(2), Sim(3)
        x[:, -1] = rng.uniform(-2.0, 2.0, size=n)
    return x


def _gtsam_object(group: str, X: np.ndarray):
    return interop.to_gtsam(group, X)


def _percall_rows(group: str, rng):
    """(label, our call, our argument, GTSAM label, GTSAM call, GTSAM argument) for each kernel."""
    K = crosscheck.KERNELS[group]
    cls = getattr(gtsam, registry.group(group).gtsam)
    c = cls.__name__
    x = _tangents(group, 2, rng)
    x[:, crosscheck.rotation_slice(group)] *= 0.5  # well inside the principal branch
    xa, xb = np.ascontiguousarray(x[0]), np.ascontiguousarray(x[1])
    X, Y = K.exp(xa), K.exp(xb)
    P, Q = _gtsam_object(group, X), _gtsam_object(group, Y)
    rows = [
        (f"{group}.exp(x)", K.exp, (xa,), f"{c}.Expmap(x)", cls.Expmap, (xa,)),
        (f"{group}.log(X)", K.log, (X,), f"{c}.Logmap(P)", cls.Logmap, (P,)),
    ]
    if group == "se3":
        XF = np.asfortranarray(X)
        rows.append((f"{group}.log(X) Fortran-ordered", K.log, (XF,), f"{c}.Logmap(P)", cls.Logmap, (P,)))
    if hasattr(cls, "ExpmapDerivative"):
        rows += [
            (f"{group}.dexp(x)", K.dexp, (xa,), f"{c}.ExpmapDerivative(x)", cls.ExpmapDerivative, (xa,)),
            (f"{group}.dlog(x)", K.dlog, (xa,), f"{c}.LogmapDerivative(x)", cls.LogmapDerivative, (xa,)),
        ]
    else:  # no GTSAM derivative for Similarity2/3: the nearest is Pose3's / Pose2's
        near, nx = (gtsam.Pose3, xa[:6]) if group == "sim3" else (gtsam.Pose2, xa[:3])
        n = near.__name__
        rows += [
            (f"{group}.dexp(x)", K.dexp, (xa,), f"{n}.ExpmapDerivative(x)", near.ExpmapDerivative, (nx,)),
            (f"{group}.dlog(x)", K.dlog, (xa,), f"{n}.LogmapDerivative(x)", near.LogmapDerivative, (nx,)),
        ]
    rows.append((f"{group}.Ad(X)", K.Ad, (X,), "P.AdjointMap()", cls.AdjointMap, (P,)))
    if hasattr(cls, "adjointMap_"):
        rows.append((f"{group}.ad(x)", K.ad, (xa,), f"{c}.adjointMap_(x)", cls.adjointMap_, (xa,)))
    else:
        rows.append((f"{group}.ad(x)", K.ad, (xa,), f"{c}.Hat(x)", cls.Hat, (xa,)))
    rows += [
        (f"{group}.compose(X, Y)", K.compose, (X, Y), "P.compose(Q)", cls.compose, (P, Q)),
        (f"{group}.inverse(X)", K.inverse, (X,), "P.inverse()", cls.inverse, (P,)),
        (f"{group}.hat(x)", K.hat, (xa,), f"{c}.Hat(x)", cls.Hat, (xa,)),
        (f"{group}.vee(X)", K.vee, (K.hat(xa),), f"{c}.Vee(X)", cls.Vee, (K.hat(xa),)),
    ]
    return rows


def _quaternion_rows(rng):
    """The unit and dual quaternion modules' exp and log, against GTSAM's SO(3)/SE(3) calls
    (GTSAM has no quaternion exponential of its own)."""
    from lie_factors import dual_quaternion, quaternion

    w = 0.5 * rng.normal(size=3)
    x = np.concatenate([w, rng.normal(size=3)])
    q, d = quaternion.exp(w), dual_quaternion.exp(x)
    R, P = gtsam.Rot3.Expmap(w), gtsam.Pose3.Expmap(x)
    return [
        ("quaternion.exp(x)", quaternion.exp, (w,), "Rot3.Expmap(x)", gtsam.Rot3.Expmap, (w,)),
        ("quaternion.log(q)", quaternion.log, (q,), "Rot3.Logmap(P)", gtsam.Rot3.Logmap, (R,)),
        ("dual_quaternion.exp(x)", dual_quaternion.exp, (x,), "Pose3.Expmap(x)", gtsam.Pose3.Expmap, (x,)),
        ("dual_quaternion.log(q)", dual_quaternion.log, (d,), "Pose3.Logmap(P)", gtsam.Pose3.Logmap, (P,)),
    ]


def _per_call(f, args, calls: int) -> float:
    loop = itertools.repeat(None, calls)
    if len(args) == 1:
        (a,) = args
        t = clock()
        for _ in loop:
            f(a)
    else:
        a, b = args
        t = clock()
        for _ in loop:
            f(a, b)
    return (clock() - t) / calls


def percall(groups, calls: int, repeat: int):
    """Rows (ours, µs, GTSAM's, µs, ratio), each pair timed alternately, best of ``repeat``."""
    rng = np.random.default_rng(1)
    out = []
    rows = [row for group in groups for row in _percall_rows(group, rng)] + _quaternion_rows(rng)
    for label, f, a, glabel, g, ga in rows:
        f(*a), g(*ga)  # compile / load from cache outside the timing
        ours, theirs = math.inf, math.inf
        for _ in range(repeat):
            ours = min(ours, _per_call(f, a, calls))
            theirs = min(theirs, _per_call(g, ga, calls))
        out.append((label, ours * 1e6, glabel, theirs * 1e6, ours / theirs))
    return out


def breakdown(calls: int, repeat: int = 15):
    """Where one call of ``se3.Ad(X)`` goes: (part, µs) rows, each the best of ``repeat`` × ``calls``."""
    from lie_factors.kernels import public

    X = se3.exp(np.array([0.1, -0.2, 0.3, 1.0, 2.0, 3.0]))
    se3.Ad(X)  # binds the fast path's compiled entry point into the function's globals
    g = se3.Ad.__globals__
    G, OP, fast = g["G"], g["OP"], g["fast"]
    out = np.empty((6, 6))
    nd, f64 = np.ndarray, np.dtype(np.float64)
    parts = [
        ("`se3.Ad(X)`, the whole call (in a lambda)", lambda: se3.Ad(X)),
        ("the compiled call: check of X + core", lambda: fast(G, OP, X, out)),
        ("the same through numba's dispatcher", lambda: public.one(G, OP, X, out)),
        ("`np.empty((6, 6))` for the result", lambda: np.empty((6, 6))),
        ("`type(X) is ndarray and X.shape == (4, 4) and X.dtype is float64`",
         lambda: type(X) is nd and X.shape == (4, 4) and X.dtype is f64),
        ("an empty lambda (the loop's own cost)", lambda: None),
    ]
    rows = []
    for label, f in parts:
        f()
        best = math.inf
        for _ in range(repeat):
            t = clock()
            for _ in itertools.repeat(None, calls):
                f()
            best = min(best, (clock() - t) / calls)
        rows.append((label, best * 1e6))
    return rows


def _median_time(f, x, k: int = 7) -> float:
    samples = []
    for _ in range(k):
        t = clock()
        f(x)
        samples.append(clock() - t)
    return statistics.median(samples)


def _batched_inputs(group: str, n: int, rng):
    K = crosscheck.KERNELS[group]
    x = _tangents(group, n, rng)
    X = K.exp(x)
    return x, X


def batched(groups, n: int):
    """(label, seconds) for every public kernel on n elements."""
    rng = np.random.default_rng(0)
    rows = []
    for group in groups:
        K = crosscheck.KERNELS[group]
        x, X = _batched_inputs(group, n, rng)
        Y = X[::-1].copy()
        hx = K.hat(x)
        calls = {
            "exp": (K.exp, x), "log": (K.log, X), "dexp": (K.dexp, x), "dlog": (K.dlog, x),
            "Ad": (K.Ad, X), "ad": (K.ad, x), "compose": (lambda X: K.compose(X, Y), X),
            "inverse": (K.inverse, X), "hat": (K.hat, x), "vee": (K.vee, hx),
        }
        for fname in FUNCTIONS:
            f, a = calls[fname]
            f(a)
            rows.append((f"{group}.{fname}", _median_time(f, a)))
    return rows


def ratios(n: int, rounds: int = 7):
    """Sim(3) / SE(3) batched time of exp, log, dexp, dlog on n elements (alternated, medians)."""
    rng = np.random.default_rng(0)
    xs, Xs = _batched_inputs("sim3", n, rng)
    xe, Xe = _batched_inputs("se3", n, rng)
    rows = []
    for fname in ("exp", "log", "dexp", "dlog"):
        a_s, a_e = (Xs, Xe) if fname == "log" else (xs, xe)
        fs, fe = getattr(sim3, fname), getattr(se3, fname)
        fs(a_s), fe(a_e)
        ts, te = [], []
        for _ in range(rounds):
            ts.append(_median_time(fs, a_s, 1))
            te.append(_median_time(fe, a_e, 1))
        s, e = statistics.median(ts), statistics.median(te)
        rows.append((fname, s, e, s / e))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("percall", "breakdown", "ratios", "batched", "accuracy"), action="append",
                    help="run only these sections (repeatable; default: all)")
    ap.add_argument("--calls", type=int, default=20_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--ratio-n", type=int, default=200_000)
    ap.add_argument("--samples", type=int, default=5)
    ap.add_argument("--groups", default=",".join(crosscheck.GROUPS), help="comma-separated (default: all)")
    ap.add_argument("--clock", choices=("cpu", "wall"), default="cpu",
                    help="the calling thread's CPU time (default) or wall time")
    args = ap.parse_args(argv)
    global clock
    clock = time.thread_time if args.clock == "cpu" else time.perf_counter
    groups = tuple(g for g in args.groups.split(",") if g)
    unknown = [g for g in groups if g not in crosscheck.KERNELS]
    if unknown:
        ap.error(f"unknown group(s) {', '.join(unknown)}; choose from {', '.join(crosscheck.GROUPS)}")
    only = set(args.only or ("percall", "breakdown", "ratios", "batched", "accuracy"))
    print(f"load average before: {os.getloadavg()[0]:.2f}; clock: {args.clock}\n")
    if "percall" in only:
        print(f"## One element per call (µs, best of {args.repeat} × {args.calls} calls, alternated)\n")
        print("| ours | µs | GTSAM's nearest | µs | ratio |\n|---|---|---|---|---|")
        for label, o, glabel, g, r in percall(groups, args.calls, args.repeat):
            print(f"| `{label}` | {o:.2f} | `{glabel}` | {g:.2f} | {r:.2f}× |")
        print()
    if "breakdown" in only:
        print(f"## Where one call goes (µs, best of 15 × {args.calls} calls)\n")
        print("| part | µs |\n|---|---|")
        for label, us in breakdown(args.calls):
            print(f"| {label} | {us:.2f} |")
        print()
    if "ratios" in only:
        print(f"## Sim(3) / SE(3), batched on {args.ratio_n} elements (median of 7, alternated)\n")
        print("| function | sim3 ms | se3 ms | ratio |\n|---|---|---|---|")
        for fname, s, e, r in ratios(args.ratio_n):
            print(f"| {fname} | {s * 1e3:.2f} | {e * 1e3:.2f} | {r:.2f}× |")
        print()
    if "batched" in only:
        print(f"## Batched ({args.n} elements per call, median of 7)\n")
        print("| function | ms | ns per element |\n|---|---|---|")
        for label, t in batched(groups, args.n):
            print(f"| {label} | {t * 1e3:.2f} | {t / args.n * 1e9:.0f} |")
        print()
    if "accuracy" in only:
        rows = crosscheck.run(samples=args.samples, seed=0, groups=groups)
        print(f"## Accuracy ({args.samples} random points per band)\n")
        print(crosscheck.format_table(rows))
        print(f"\nworst lie_factors error: {max(r.ours for r in rows):.1e}\n")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
