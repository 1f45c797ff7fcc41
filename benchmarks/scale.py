"""10⁴, 10⁵ and 10⁶ poses: the default command, ``--backend native`` and the GTSAM script a user writes.

    python benchmarks/scale.py [--sizes 10000,100000,1000000] [--repeats 3,3,1] [--settle 1.0]
        [--output FILE.md] [--json FILE.json]
    python benchmarks/scale.py --split 100000 [--split-reference 10000]

Graphs: ``benchmarks/generate_posegraph.py --poses N --closure-every 10 --seed 0`` (a helix of
1000 poses per turn with a loop closure every 10th pose to the pose one turn below), written
once under ``$LIE_FACTORS_TMP`` (default /tmp).

Sides, each a fresh process timed from outside (start-up, imports and exit count):

* ``default``: ``lie-factors posegraph FILE --json`` (the console script's ``cli.entry``);
* ``native``: the same with ``--backend native`` (GTSAM's factors, initializer and LM);
* ``gtsam``: the script a GTSAM user writes (:data:`GTSAM_SCRIPT`): ``gtsam.readG2o``, a prior
  on pose 0 (GTSAM's ``Pose3SLAMExample_g2o.py`` variances), ``InitializePose3.initialize``,
  ``LevenbergMarquardtOptimizer`` with default parameters, under ``ulimit -s unlimited``
  (GTSAM's recursive elimination of a 10⁶-pose graph needs more than 8 MB of stack).

Per run: wall seconds, CPU seconds (user + system of the child), peak RSS (``VmHWM`` read
just before the process exits), the split by stage (read, init, setup, iterations: the
``--json`` record's ``timings`` for ours, the script's own clock for GTSAM's), iterations and
final error.  The sides rotate their order at each repeat; the best wall time of the repeats
is kept, with that run's figures.  ``--settle L`` waits (up to 3 minutes) before each run
until the 1-minute load average is at most L, so that one run's load does not linger into
the next.  The 10⁶-pose processes take 5–8 GB each: run the script alone on the machine.

``--split N``: where one iteration goes, in this process, on the N-pose graph (the default
command's steps: read, chordal initialization, set-up, iterations): the optimizer's
seconds per linearization (linearize, assemble) and per λ tried (factorize, solve, retract,
error), the peak RSS of each stage, the sizes of H and of its factor, and the floors: the
numeric factorization at CHOLMOD's own flop rate on this machine (a dense SPD matrix
factored through the same code), the triangular solves at the machine's read bandwidth (two
passes over L), and the per-factor steps at their cost on the ``--split-reference`` graph
(small enough to stay in cache), both on all numba threads.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GENERATED = os.environ.get("LIE_FACTORS_TMP", "/tmp")
SIDES = ("default", "native", "gtsam")
STAGES = ("read", "init", "setup", "iterations")

CLI = ("import sys; from lie_factors.app import cli; rc = cli.entry(); "
       "hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')][0]; "
       "print('VmHWM', hwm.split()[1], file=sys.stderr); sys.exit(rc)")

#: What a GTSAM user writes to optimize a 3-D g2o file (GTSAM's Pose3SLAMExample_g2o.py and
#: Pose3SLAMExample_initializePose3Chordal.py together), with a clock around each step.
GTSAM_SCRIPT = r"""
import json, sys, time
t0 = time.perf_counter()
import gtsam
import numpy as np
t1 = time.perf_counter()
graph, initial = gtsam.readG2o(sys.argv[1], True)
t2 = time.perf_counter()
prior = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4]))
graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), prior))
start = gtsam.InitializePose3.initialize(graph)
t3 = time.perf_counter()
optimizer = gtsam.LevenbergMarquardtOptimizer(graph, start, gtsam.LevenbergMarquardtParams())
t4 = time.perf_counter()
result = optimizer.optimize()
t5 = time.perf_counter()
hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')][0]
print('VmHWM', hwm.split()[1], file=sys.stderr)
print(json.dumps({"factors": graph.size(), "iterations": optimizer.iterations(),
                  "final_error": graph.error(result),
                  "timings": {"imports": t1 - t0, "read": t2 - t1, "init": t3 - t2, "setup": t4 - t3,
                              "iterations": t5 - t4}}))
"""


def graph_path(poses: int) -> str:
    path = os.path.join(GENERATED, f"lie_factors_helix{poses // 1000}k.g2o")
    if not os.path.exists(path):
        subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "generate_posegraph.py"),
                        "--poses", str(poses), "--closure-every", "10", "--seed", "0", "--output", path],
                       check=True)
    return path


def load_average() -> float:
    with open("/proc/loadavg") as fh:
        return float(fh.read().split()[0])


def settle(limit: float) -> None:
    deadline = time.monotonic() + 180
    while limit > 0 and load_average() > limit and time.monotonic() < deadline:
        time.sleep(5)


def _unlimited_stack():
    resource.setrlimit(resource.RLIMIT_STACK, (resource.RLIM_INFINITY, resource.RLIM_INFINITY))


def run_once(side: str, path: str) -> dict:
    """One fresh process: wall, cpu, peak RSS (MiB), its record (split, iterations, final error)."""
    env = dict(os.environ, PYTHONPATH=ROOT)
    if side == "gtsam":
        argv, pre = [sys.executable, "-c", GTSAM_SCRIPT, path], _unlimited_stack
    else:
        argv = [sys.executable, "-c", CLI, "posegraph", path, "--json", "--quiet"]
        argv += ["--backend", "native"] if side == "native" else []
        pre = None
    load = load_average()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    # cwd: `python -c` puts the working directory first on sys.path, before PYTHONPATH
    p = subprocess.run(argv, capture_output=True, text=True, env=env, preexec_fn=pre, cwd=ROOT)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise RuntimeError(f"{side} on {path}: {p.stderr.strip()[-800:]}")
    hwm = [line for line in p.stderr.splitlines() if line.startswith("VmHWM")][-1]
    record = json.loads(p.stdout.strip().splitlines()[-1])
    return {"side": side, "wall": wall, "cpu": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
            "rss": int(hwm.split()[1]) / 1024.0, "load": load, "factors": record["factors"],
            "iterations": record["iterations"], "final_error": record["final_error"],
            "timings": {k: record["timings"].get(k, 0.0) for k in ("imports",) + STAGES}}


def measure(poses: int, repeats: int, settle_load: float, sides: tuple = SIDES) -> dict:
    path = graph_path(poses)
    best: dict = {}
    starts = []  # the load at the start of each run
    for r in range(repeats):
        order = sides[r % len(sides):] + sides[:r % len(sides)]
        for side in order:
            settle(settle_load)
            run = run_once(side, path)
            starts.append(run["load"])
            print(f"  {poses} {side}: {run['wall']:.2f} s, {run['rss']:.0f} MiB (load {run['load']:.2f})",
                  file=sys.stderr, flush=True)
            if side not in best or run["wall"] < best[side]["wall"]:
                best[side] = run
    return {"poses": poses, "file_mb": os.path.getsize(path) / 1e6, "repeats": repeats, "best": best,
            "load": [min(starts), max(starts)]}


def table(rows: list[dict]) -> str:
    out = ["| poses | factors | side | whole command s | CPU s | peak RSS MiB | read / init / setup / iterations s "
           "| iterations | s per iteration | µs per factor and iteration | final error | vs GTSAM script: wall, RSS "
           "| runs | load at the runs' starts |",
           "|---:|---:|---|---:|---:|---:|---|---:|---:|---:|---:|---|---:|---|"]
    for row in rows:
        g = row["best"].get("gtsam")
        for side in (s for s in SIDES if s in row["best"]):
            b = row["best"][side]
            t = b["timings"]
            per_it = t["iterations"] / max(b["iterations"], 1)
            out.append(
                f"| {row['poses']} | {b['factors']} | {side} | {b['wall']:.2f} | {b['cpu']:.2f} | {b['rss']:.0f} | "
                + " / ".join(f"{t[k]:.2f}" for k in STAGES)
                + f" | {b['iterations']} | {per_it:.3f} | {per_it / b['factors'] * 1e6:.2f} | {b['final_error']:.9g} | "
                + (f"{b['wall'] / g['wall']:.2f}×, {b['rss'] / g['rss']:.2f}×" if g else "–")
                + f" | {row['repeats']} | "
                f"{row['load'][0]:.2f}–{row['load'][1]:.2f} |")
    return "\n".join(out)


# --------------------------------------------------------------------------- #
# --split: where an iteration goes, and the floors
# --------------------------------------------------------------------------- #

def _clear_peak() -> None:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")  # resets VmHWM to the current RSS (Linux)
    except OSError:
        pass


def _dense_flop_rate(k: int = 3000, repeats: int = 3) -> float:
    """CHOLMOD's flop rate on this machine: a dense SPD k×k matrix through batch.cholmod (FLOP/s)."""
    import numpy as np

    from lie_factors.sparse import cholmod

    M = np.random.default_rng(0).normal(size=(k, k))
    A = M @ M.T + k * np.eye(k)
    r, c = np.tril_indices(k)
    colptr, rowind, values = cholmod.lower_csc(k, r, c, A[r, c])
    factor = cholmod.Cholesky(colptr, rowind)
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        factor.factorize(values)
        best = min(best, time.perf_counter() - t)
    return factor.flops / best


def _read_bandwidth(nbytes: int = 1 << 30, repeats: int = 3) -> float:
    """Bytes per second a sum over a large array reads."""
    import numpy as np

    a = np.ones(nbytes // 8)
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        a.sum()
        best = min(best, time.perf_counter() - t)
    return nbytes / best


def split(poses: int) -> dict:
    """The default command's steps in this process on the ``poses`` graph, with the peak RSS of each."""
    import gtsam

    from lie_factors.util import memory
    import lie_factors as lf
    from lie_factors.batch.graph import Problem
    from lie_factors.batch.optimizer import BatchLevenbergMarquardt
    from lie_factors.initialization import initialize
    from lie_factors.sparse.cholmod import reuse_factor_memory

    # the default command's stages, every size on all numba threads so that per-factor costs compare
    path = graph_path(poses)
    stages = {}
    job = {}

    def stage(name, fn):
        _clear_peak()
        t = time.perf_counter()
        job[name] = fn()
        rss, peak = memory.usage()
        stages[name] = {"seconds": time.perf_counter() - t, "peak_mib": peak / 2**20, "rss_mib": rss / 2**20}

    stage("read", lambda: lf.read_g2o(path).with_first_prior())
    pg = job["read"]
    with reuse_factor_memory():
        stage("init", lambda: initialize(pg, "auto"))
        opt = None

        def optimize():
            nonlocal opt
            opt = BatchLevenbergMarquardt(Problem.from_pose_graph(pg, job["init"].poses), None,
                                          gtsam.LevenbergMarquardtParams())
            return opt.optimize(values=False)

        stage("optimize", optimize)
    res = job["optimize"]
    factor = opt.solver.factor
    P = opt.problem
    inner = max(opt.inner_iterations, 1)  # λ tried: one factorization, solve, retraction and error each
    linearizations = max(res.iterations, 1)  # one per iteration
    return {"poses": poses, "factors": P.graph_size, "unknowns": opt.system.n, "h_entries": opt.system.pattern.nnz,
            "factor_entries": factor.factor_entries, "factor_bytes": int(factor._x.nbytes) if factor.supernodal else None,
            "flops": factor.flops, "iterations": res.iterations, "inner": inner, "linearizations": linearizations,
            "timings": dict(res.timings), "stages": stages,
            "final_error": res.final_error, "gtsam": gtsam.__version__ if hasattr(gtsam, "__version__") else ""}


def split_report(big: dict, small: dict, rate: float, bandwidth: float) -> str:
    """The per-iteration split of ``big`` against its floors (``small``: the in-cache per-factor costs)."""
    lines = []
    t, ts = big["timings"], small["timings"]
    per_lin = {k: t[k] / big["linearizations"] for k in ("linearize", "assemble")}
    per_try = {k: t[k] / big["inner"] for k in ("factorize", "solve", "retract", "error")}
    floor = {
        "linearize": ts["linearize"] / small["linearizations"] / small["factors"] * big["factors"],
        "assemble": ts["assemble"] / small["linearizations"] / small["factors"] * big["factors"],
        "retract": ts["retract"] / small["inner"] / small["factors"] * big["factors"],
        "error": ts["error"] / small["inner"] / small["factors"] * big["factors"],
        "factorize": big["flops"] / rate,
        "solve": 2 * (big["factor_bytes"] or 8 * big["factor_entries"]) / bandwidth,
    }
    lines.append(f"{big['poses']} poses, {big['factors']} factors, {big['unknowns']} unknowns; H: "
                 f"{big['h_entries']} stored entries; L: {big['factor_entries']} entries"
                 + (f" ({big['factor_bytes'] / 2**30:.2f} GiB)" if big["factor_bytes"] else "")
                 + f", {big['flops']:.3g} flops per numeric factorization; {big['iterations']} iterations, "
                 f"{big['inner']} λ tried, {big['linearizations']} linearizations; final error {big['final_error']:.9g}")
    lines.append(f"CHOLMOD's dense rate here: {rate / 1e9:.1f} GFlop/s; read bandwidth {bandwidth / 1e9:.1f} GB/s; "
                 f"in-cache per-factor costs from the {small['poses']}-pose graph")
    lines.append("")
    lines.append("| step | per | seconds | floor s | × floor | floor from |")
    lines.append("|---|---|---:|---:|---:|---|")
    for k, per, what in (("linearize", per_lin, "linearization"), ("assemble", per_lin, "linearization"),
                         ("factorize", per_try, "λ tried"), ("solve", per_try, "λ tried"),
                         ("retract", per_try, "λ tried"), ("error", per_try, "λ tried")):
        source = {"factorize": "flops ÷ dense rate", "solve": "2 passes over L ÷ read bandwidth"}.get(
            k, f"{small['poses']}-pose graph per factor")
        lines.append(f"| {k} | {what} | {per[k]:.3f} | {floor[k]:.3f} | {per[k] / floor[k]:.1f} | {source} |")
    lines.append("")
    lines.append("| stage | seconds | peak RSS MiB | RSS after MiB |")
    lines.append("|---|---:|---:|---:|")
    for name, s in big["stages"].items():
        lines.append(f"| {name} | {s['seconds']:.2f} | {s['peak_mib']:.0f} | {s['rss_mib']:.0f} |")
    lines.append(f"\nset-up {big['timings']['setup']:.2f} s; iterations {big['stages']['optimize']['seconds'] - big['timings']['setup']:.2f} s")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="10000,100000,1000000")
    ap.add_argument("--repeats", default="3,3,1", help="repeats per size (one number for all)")
    ap.add_argument("--sides", default=",".join(SIDES), help="which of default, native, gtsam")
    ap.add_argument("--settle", type=float, default=0.0, help="wait before each run until the load is at most this")
    ap.add_argument("--split", type=int, default=0, metavar="N", help="the per-iteration split at N poses instead")
    ap.add_argument("--split-reference", type=int, default=10000, metavar="N")
    ap.add_argument("--output", default="")
    ap.add_argument("--json", default="")
    a = ap.parse_args(argv)
    if a.split:
        sys.path.insert(0, ROOT)
        load0 = load_average()
        rate, bandwidth = _dense_flop_rate(), _read_bandwidth()
        small = split(a.split_reference)
        big = split(a.split)
        text = (f"python benchmarks/scale.py --split {a.split} --split-reference {a.split_reference} "
                f"(load {load0:.2f} → {load_average():.2f})\n\n" + split_report(big, small, rate, bandwidth) + "\n")
        result = {"big": big, "small": small, "rate": rate, "bandwidth": bandwidth}
    else:
        sizes = [int(s) for s in a.sizes.split(",")]
        reps = [int(r) for r in a.repeats.split(",")]
        reps = reps * len(sizes) if len(reps) == 1 else reps
        rows = []
        for poses, repeats in zip(sizes, reps):
            rows.append(measure(poses, repeats, a.settle, tuple(a.sides.split(","))))
            print(table(rows[-1:]), flush=True)
        text = (f"python benchmarks/scale.py --sizes {a.sizes} --repeats {a.repeats} --sides {a.sides} "
                f"--settle {a.settle}\n\n"
                + table(rows) + "\n")
        result = rows
    print(text)
    if a.output:
        with open(a.output, "w") as fh:
            fh.write(text)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(result, fh, indent=1, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())
