"""Start-up costs of the CLI: help, first-run compilation, factor construction,
and the whole ``posegraph --max-iterations 0`` command on city10000 split into its pieces.

    python benchmarks/startup.py [--repeat 3] [--dataset data/city10000.g2o] [--only SECTION]
        [--reference REV] [--commands NAME ...]

Every whole-command figure is a fresh process (``python -m lie_factors.app.cli ...``), best of
``--repeat``, backends alternated. The first-run figures run each command a user reaches
(:data:`COMMANDS`) from a fresh clone of HEAD (and of ``--reference REV``, alternated) with an
empty NUMBA_CACHE_DIR, then again with the cache it wrote: the compile seconds the command
prints, and first-run wall − second-run wall.  The after-install figures make a fresh virtual
environment, run the README's main-job install in a fresh clone (which compiles the kernels:
docs/installing.md), then each command and :data:`PYTHON_RUNS` twice.
Prints markdown tables (docs/benchmarks.md, section "Start-up").
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENV = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))


def wall(argv, env=ENV, cwd=None) -> float:
    t = time.perf_counter()
    p = subprocess.run(argv, env=env, capture_output=True, text=True, cwd=cwd)
    dt = time.perf_counter() - t
    if p.returncode != 0:
        raise SystemExit(f"{argv} failed: {p.stderr.strip()[-500:]}")
    return dt


def cli(*args) -> list[str]:
    return [sys.executable, "-m", "lie_factors.app.cli", *args]


def help_table(repeat: int) -> None:
    rows = {"python -c pass": [sys.executable, "-c", "pass"],
            "lie-factors --help": cli("--help"),
            "lie-factors posegraph --help": cli("posegraph", "--help")}
    best = {k: min(wall(v) for _ in range(repeat)) for k, v in rows.items()}
    print("| command (fresh process) | wall s (best of %d) |\n|---|---|" % repeat)
    for k, v in best.items():
        print(f"| `{k}` | {v:.3f} |")


#: The commands a user reaches, as run by the first-run table (paths relative to the checkout's data/).
COMMANDS = {
    "demo": ["demo"],
    "posegraph intel": ["posegraph", "{data}/intel.g2o"],
    "posegraph intel --incremental": ["posegraph", "{data}/intel.g2o", "--incremental"],
    "posegraph intel --gnc tls": ["posegraph", "{data}/intel.g2o", "--gnc", "tls"],
    "posegraph intel --covariances": ["posegraph", "{data}/intel.g2o", "--covariances", "{out}/c.npz"],
    "posegraph city10000 --output x.tum": ["posegraph", "{data}/city10000.g2o", "--output", "{out}/city.tum"],
    "posegraph sphere2500": ["posegraph", "{data}/sphere2500.g2o"],
    "evaluate": ["evaluate", "{data}/groundtruth/city10000.tum", "{data}/groundtruth/city10000.tum"],
    "corrupt": ["corrupt", "{data}/intel.g2o", "{out}/bad.g2o", "--fraction", "0.2", "--kind", "group",
                "--seed", "1"],
}


def clone(revision: str, into: str) -> str:
    """A fresh clone of this repository at ``revision`` (no ``__pycache__``, no numba cache): its path."""
    subprocess.run(["git", "clone", "-q", ROOT, into], check=True)
    subprocess.run(["git", "-C", into, "checkout", "-q", revision], check=True)
    return into


def _first_run(checkout: str, argv: list, out: str) -> tuple[float, float, float | None]:
    """``argv`` in a fresh process on ``checkout``'s code with an empty numba cache, then again with
    the cache it wrote: (first wall s, later wall s, the compile seconds the command printed or None)."""
    import re

    argv = [a.format(data=os.path.join(ROOT, "data"), out=out) for a in argv]
    cmd = [sys.executable, "-m", "lie_factors.app.cli", *argv]
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=checkout)
        t = time.perf_counter()
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=out)
        first = time.perf_counter() - t
        if p.returncode != 0:
            raise SystemExit(f"{argv} failed: {p.stderr.strip()[-500:]}")
        note = re.search(r"compiled numba kernels in ([0-9.]+) s", p.stderr)
        later = wall(cmd, env, cwd=out)  # the cwd is first on sys.path: never the working tree's package
    return first, later, float(note.group(1)) if note else None


def first_run_table(repeat: int, reference: str | None, only: list | None = None) -> None:
    """Each command of :data:`COMMANDS` (or ``only``) from a fresh clone of HEAD with an empty numba
    cache, then with the warm cache; with ``reference`` (a revision), the same for a fresh clone of
    it, the two alternated; best of ``repeat``."""
    names = only or list(COMMANDS)
    with tempfile.TemporaryDirectory() as work:
        sides = {"HEAD": clone("HEAD", os.path.join(work, "head"))}
        if reference:
            sides[reference] = clone(reference, os.path.join(work, "reference"))
        best: dict = {}
        for r in range(repeat):
            for name in names:
                for side in (list(sides) if r % 2 == 0 else list(sides)[::-1]):
                    out = os.path.join(work, "out")
                    os.makedirs(out, exist_ok=True)
                    first, later, note = _first_run(sides[side], COMMANDS[name], out)
                    f0, l0, n0 = best.get((name, side), (float("inf"), float("inf"), None))
                    best[(name, side)] = (min(f0, first), min(l0, later),
                                          note if n0 is None or (note is not None and note < n0) else n0)
    print(f"First runs, fresh clones, empty numba cache then warm, fresh processes, best of {repeat}"
          f"{', sides alternated' if reference else ''} (wall s):\n")
    print("| command | side | first run | later run | compile printed | first − later |")
    print("|---|---|---|---|---|---|")
    for (name, side), (first, later, note) in best.items():
        shown = f"{note:.1f}" if note is not None else "–"
        print(f"| `{name}` | {side} | {first:.2f} | {later:.2f} | {shown} | {first - later:.2f} |")


#: Python a user runs (the issue's other first runs): a smoother loop of projection factors as
#: GTSAM's VisualISAM2Example builds it, ``lf.optimize`` on a BAL scene with GTSAM's
#: GeneralSFMFactor, and a new ``lf.factor`` kind (its own residual, never seen by the install).
PYTHON_RUNS = {
    "VisualISAM2-sized lf.Smoother loop": "from lie_factors.app import warmup; warmup._visual_smoother()",
    "lf.optimize on a BAL file (GeneralSFMFactor)": r"""
import gtsam, lie_factors as lf
scene = gtsam.SfmData.FromBalFile(gtsam.findExampleDataFile("dubrovnik-3-7-pre"))
graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
for j in range(scene.numberTracks()):
    for m in range(scene.track(j).numberMeasurements()):
        i, uv = scene.track(j).measurement(m)
        graph.add(gtsam.GeneralSFMFactorCal3Bundler(uv, noise, gtsam.symbol("c", i), gtsam.symbol("p", j)))
graph.add(gtsam.PriorFactorPinholeCameraCal3Bundler(gtsam.symbol("c", 0), scene.camera(0), gtsam.noiseModel.Isotropic.Sigma(9, 0.1)))
graph.add(gtsam.PriorFactorPoint3(gtsam.symbol("p", 0), scene.track(0).point3(), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
for i in range(scene.numberCameras()):
    values.insert(gtsam.symbol("c", i), scene.camera(i))
for j in range(scene.numberTracks()):
    values.insert(gtsam.symbol("p", j), scene.track(j).point3())
print(lf.optimize(graph, values).error)
""",
    "a new lf.factor kind": r"""
import time, gtsam, numpy as np, lie_factors as lf
salt = time.time_ns() % 1000 + 1.0   # a residual no earlier run has compiled
kind = lf.factor("Pose2", "Point2", measured="Point2")(lambda x, l, z: x.transformTo(l) - salt * z)
graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
graph.add(kind(1, 2, np.ones(2), gtsam.noiseModel.Unit.Create(2)))
graph.add(gtsam.PriorFactorPose2(1, gtsam.Pose2(), gtsam.noiseModel.Unit.Create(3)))
values.insert(1, gtsam.Pose2()); values.insert(2, np.ones(2))
print(lf.optimize(graph, values).error)
""",
}

_COMPILED = r"""
import sys
from lie_factors.util.timing import compile_seconds
exec(sys.argv[1])
print("COMPILED", compile_seconds(), file=sys.stderr)
"""


def after_install_table() -> None:
    """The README's main-job install (``pip install -e .``) in a fresh virtual environment on a
    fresh clone of HEAD, its wall time; then each command of :data:`COMMANDS` and each of
    :data:`PYTHON_RUNS`, first run and second run, fresh processes: the compile seconds each
    prints (numba's compilation in the process) and first − later."""
    import re

    with tempfile.TemporaryDirectory() as work:
        checkout = clone("HEAD", os.path.join(work, "head"))
        venv = os.path.join(work, "venv")
        subprocess.run([sys.executable, "-m", "venv", venv], check=True)
        python = os.path.join(venv, "bin", "python")
        t = time.perf_counter()
        subprocess.run([python, "-m", "pip", "install", "-q", "-e", "."], cwd=checkout, check=True,
                       capture_output=True)
        install = time.perf_counter() - t
        print(f"`pip install -e .` in a fresh venv, fresh clone: {install:.0f} s\n")
        print("| first run after the install | first run s | later run s | compiled s |\n|---|---|---|---|")
        out = os.path.join(work, "out")
        os.makedirs(out)
        env = dict(os.environ)
        env.pop("PYTHONPATH", None)
        runs = {name: [python, "-m", "lie_factors.app.cli", *[a.format(data=os.path.join(checkout, "data"), out=out)
                                                                for a in argv]] for name, argv in COMMANDS.items()}
        runs.update({name: [python, "-c", _COMPILED, code] for name, code in PYTHON_RUNS.items()})
        for name, cmd in runs.items():
            walls, compiled = [], 0.0
            for _ in range(2):
                t = time.perf_counter()
                p = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=out)
                walls.append(time.perf_counter() - t)
                if p.returncode != 0:
                    raise SystemExit(f"{name} failed: {p.stderr.strip()[-500:]}")
                if len(walls) == 1:
                    found = re.search(r"compiled numba kernels in ([0-9.]+) s|COMPILED ([0-9.e-]+)", p.stderr)
                    compiled = float(found.group(1) or found.group(2)) if found else 0.0
            print(f"| `{name}` | {walls[0]:.2f} | {walls[1]:.2f} | {compiled:.1f} |")


FLOOR = r"""
import sys, time
t0 = time.perf_counter()
import numpy as np
t1 = time.perf_counter()
import numba
t2 = time.perf_counter()
sys.path.insert(0, sys.argv[1])
from floor_kernel import one  # a cached @njit kernel: np.empty and a float add
one(1.0)
t3 = time.perf_counter()
print(f"{t1 - t0} {t2 - t1} {t3 - t2}")
"""

FLOOR_KERNEL = """
import numba
import numpy as np


@numba.njit(cache=True)
def one(x):
    a = np.empty(3)
    a[0] = x
    return a[0] + 1.0
"""


def floor_table(repeat: int) -> None:
    """What any numba-based command pays before its first kernel runs, kernels cached."""
    with tempfile.TemporaryDirectory() as d:
        with open(os.path.join(d, "floor_kernel.py"), "w") as fh:
            fh.write(FLOOR_KERNEL)
        argv = [sys.executable, "-c", FLOOR, d]
        subprocess.run(argv, env=ENV, check=True, capture_output=True)  # compile + cache once
        runs = []
        for _ in range(repeat):
            p = subprocess.run(argv, env=ENV, check=True, capture_output=True, text=True)
            runs.append([float(x) for x in p.stdout.split()])
        native = [wall([sys.executable, "-c", "import gtsam"]) for _ in range(repeat)]
    best = [min(r[i] for r in runs) for i in range(3)]
    print("| fresh process, kernel already cached | s (best of %d) |\n|---|---|" % repeat)
    print(f"| `import numpy` | {best[0]:.3f} |")
    print(f"| `import numba` (after numpy) | {best[1]:.3f} |")
    print(f"| first call of a cached trivial kernel (numba's target initialisation) | {best[2]:.3f} |")
    print(f"| numba's share: import + first call | {best[1] + best[2]:.3f} |")
    print(f"| for scale: `python -c 'import gtsam'` whole process | {min(native):.3f} |")


COMPILE_SPLIT = r"""
import numpy as np, gtsam, numba
from lie_factors import so3, se3, factors
from lie_factors.kernels import dispatch as _dispatch
from lie_factors.kernels.jit import compile_seconds
R, T, x = np.eye(3), np.eye(4), np.zeros(6)
o3, o6, M6, M4 = np.empty(3), np.empty(6), np.empty((6, 6)), np.empty((4, 4))
F = np.asfortranarray(T)
@numba.njit
def trivial(x):
    return x + 1.0
steps = [("numba's first compilation (a trivial function)", lambda: trivial(1.0)),
         ("so3._log", lambda: so3._log(R, o3)),
         ("se3._log (+ its coefficient helpers)", lambda: se3._log(T, o6)),
         ("se3._dlog (+ its coefficient helpers)", lambda: se3._dlog(x, M6)),
         ("se3._compose, _inverse, _Ad", lambda: (se3._compose(T, T, M4), se3._inverse(T, M4), se3._Ad(T, M6))),
         ("factors.between_error", lambda: factors.between_error(_dispatch.SE3, T, F, F, o6)),
         ("factors.between (what a factor evaluation runs)", lambda: factors.between(_dispatch.SE3, T, np.eye(6), F, F, o6, M6, M6.copy())),
         ("factors.between_setup (construction: check, M⁻¹, Ad)", lambda: factors.BetweenFactorPose3(1, 2, gtsam.Pose3(), gtsam.noiseModel.Unit.Create(6)))]
for name, run in steps:
    a = compile_seconds()
    run()
    print(f"{name}	{compile_seconds() - a}")
"""


def compile_split_table(repeat: int) -> None:
    """Compile seconds of the SE(3) factor path, core by core (each line: what it adds), empty cache."""
    rows: dict = {}
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as cache:
            p = subprocess.run([sys.executable, "-c", COMPILE_SPLIT], env=dict(ENV, NUMBA_CACHE_DIR=cache),
                               check=True, capture_output=True, text=True)
        for line in p.stdout.strip().splitlines():
            name, sec = line.rsplit("\t", 1)
            rows.setdefault(name, []).append(float(sec))
    print("| compiled (in this order, empty numba cache) | s added (best of %d) |\n|---|---|" % repeat)
    for name, secs in rows.items():
        print(f"| {name} | {min(secs):.2f} |")
    print(f"| total | {sum(min(v) for v in rows.values()):.2f} |")


def construction_table() -> None:
    code = r"""
import timeit, numpy as np, gtsam
from lie_factors import factors
vals = {"Rot3": gtsam.Rot3.Ypr(0.1, 0.2, 0.3), "Pose3": gtsam.Pose3(gtsam.Rot3.Ypr(0.1, 0.2, 0.3), np.array([1., 2, 3])),
        "Pose2": gtsam.Pose2(1, 2, 0.3), "Similarity2": gtsam.Similarity2(gtsam.Rot2(0.3), np.array([1., 2]), 1.5),
        "Similarity3": gtsam.Similarity3(gtsam.Rot3.Ypr(0.1, 0.2, 0.3), np.array([1., 2, 3]), 1.5)}
class Bare(gtsam.CustomFactor):
    def __init__(self, k1, k2, m, noise):
        super().__init__(noise, [k1, k2], self._ev)
        self._m = m
    def _ev(self, this, values, H):
        return None
N = 20000
best = lambda f: min(timeit.repeat(f, number=N, repeat=7)) / N * 1e6
print("| group | ours Between µs | ours Prior µs | GTSAM's Between µs | bare CustomFactor subclass µs |")
print("|---|---|---|---|---|")
for name, v in vals.items():
    n = factors.GROUPS[name].dim
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.ones(n))
    B = getattr(factors, "BetweenFactor" + name); P = getattr(factors, "PriorFactor" + name)
    B(1, 2, v, noise); P(1, v, noise)
    nat = getattr(gtsam, "BetweenFactor" + name, None)
    row = [best(lambda: B(1, 2, v, noise)), best(lambda: P(1, v, noise)),
           best(lambda: nat(1, 2, v, noise)) if nat else float("nan"), best(lambda: Bare(1, 2, v, noise))]
    print(f"| {name} | " + " | ".join("—" if x != x else f"{x:.2f}" for x in row) + " |")
"""
    p = subprocess.run([sys.executable, "-c", code], env=ENV, capture_output=True, text=True)
    if p.returncode:
        raise SystemExit(p.stderr)
    print(p.stdout, end="")


SPLIT = r"""
import sys, time, json, tempfile, os
t0 = time.perf_counter()
import gtsam
import lie_factors as lf
from lie_factors import backends, g2o
from lie_factors.initialization import initialize
t1 = time.perf_counter()
backend = sys.argv[1]; path = sys.argv[2]
backends.factor_namespace(backend)
t2 = time.perf_counter()
summary = g2o.check_g2o(path)
t3 = time.perf_counter()
arrays = g2o.read_arrays(summary)
t4 = time.perf_counter()
pg = lf.read_g2o(path)  # (check + read again, not counted: the pieces above are)
t4b = time.perf_counter()
built = backends.build_graph(pg, backend)
t5 = time.perf_counter()
start = initialize(pg.with_first_prior(), "auto", engine="lie_factors" if backend == "batch" else "gtsam")
t6 = time.perf_counter()
params = gtsam.LevenbergMarquardtParams()
params.setMaxIterations(0)
res = backends.optimize_with(backend, built, start.values, params)
t7 = time.perf_counter()
with tempfile.TemporaryDirectory() as d:
    g2o.write_g2o(os.path.join(d, "out.g2o"), pg.factor_graph(), res.values)
t8 = time.perf_counter()
print(json.dumps({"imports": t2 - t0, "check": t3 - t2, "read": t4 - t3, "build": t5 - t4b,
                  "init": t6 - t5, "optimize": t7 - t6, "write": t8 - t7}))
"""


def city_table(dataset: str, repeat: int) -> None:
    import json

    backends = ("native", "dropin", "batch")
    whole = {b: [] for b in backends}
    split = {b: None for b in backends}
    with tempfile.TemporaryDirectory() as out:
        for _ in range(repeat):
            for b in backends:
                whole[b].append(wall(cli("posegraph", dataset, "--backend", b, "--max-iterations", "0",
                                         "--quiet", "--output", os.path.join(out, f"{b}.g2o"))))
                p = subprocess.run([sys.executable, "-c", SPLIT, b, dataset], env=ENV,
                                   capture_output=True, text=True)
                if p.returncode:
                    raise SystemExit(p.stderr)
                s = json.loads(p.stdout.strip().splitlines()[-1])
                if split[b] is None or sum(s.values()) < sum(split[b].values()):
                    split[b] = s
    keys = list(split["native"])
    print(f"`lie-factors posegraph {os.path.basename(dataset)} --max-iterations 0 --output X` "
          f"(fresh process each, best of {repeat}, backends alternated):\n")
    print("| backend | whole command s | ratio to native | " + " | ".join(keys) + " |")
    print("|---|---|---|" + "---|" * len(keys))
    nat = min(whole["native"])
    for b in backends:
        w = min(whole[b])
        print(f"| {b} | {w:.2f} | {w / nat:.2f} | " + " | ".join(f"{split[b][k]:.2f}" for k in keys) + " |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--dataset", default=os.path.join(ROOT, "data", "city10000.g2o"))
    ap.add_argument("--reference", default=None,
                    help="first-run: also time a fresh clone of this revision (e.g. the previous main), alternated")
    ap.add_argument("--commands", nargs="+", choices=list(COMMANDS), default=None, metavar="NAME",
                    help=f"first-run: only these commands (default: all: {', '.join(COMMANDS)})")
    ap.add_argument("--only", choices=("help", "first-run", "after-install", "compile-split", "construction", "city",
                                       "floor"), default=None)
    args = ap.parse_args(argv)
    sections = [("help", lambda: help_table(args.repeat)),
                ("first-run", lambda: first_run_table(args.repeat, args.reference, args.commands)),
                ("after-install", after_install_table),
                ("compile-split", lambda: compile_split_table(args.repeat)),
                ("construction", construction_table), ("city", lambda: city_table(args.dataset, args.repeat)),
                ("floor", lambda: floor_table(args.repeat))]
    for name, run in sections:
        if args.only in (None, name):
            print(f"\n### {name}\n")
            run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
