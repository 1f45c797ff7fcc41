"""Each command compiles (or loads from the cache) the kernels of the path it runs, and no others.

A first run compiles every kernel its process calls, seconds each for the largest, so a kernel
that a command does not need must not be called: a module imported eagerly that compiles, a
parallel wrapper called where the serial loop runs anyway, a signature compiled twice.  Each
command runs in a fresh process; at its exit the process lists every dispatcher of the package
that holds a signature (a compiled or a loaded kernel: the same calls, so the test does not
need an empty cache).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"

#: Run a command through the CLI, then print {dispatcher: [signatures], ...} and the parallel ones.
LISTING = r"""
import atexit, json, sys
from numba.core import event
from numba.core.dispatcher import Dispatcher

compiled = []  # every function numba compiles in this process, numba's own included

class Compiled(event.Listener):
    def on_start(self, e):
        f = getattr(e.data.get("dispatcher"), "py_func", None)
        compiled.append(f"{f.__module__}.{f.__qualname__}" if f else "?")

    def on_end(self, e):
        pass

event.register("numba:compile", Compiled())

def listing():
    seen = {}
    for name, mod in list(sys.modules.items()):
        if not name.startswith("lie_factors"):
            continue
        for value in list(vars(mod).values()):
            d = value if isinstance(value, Dispatcher) else getattr(value, "kernel", None)
            if isinstance(d, Dispatcher) and d.signatures:
                key = f"{d.py_func.__module__}.{d.py_func.__qualname__}"
                seen[key] = dict(signatures=[str(s) for s in d.signatures],
                                 parallel=bool(d.targetoptions.get("parallel")))
    print("KERNELS " + json.dumps(seen))
    print("COMPILED " + json.dumps(compiled))

atexit.register(listing)
from lie_factors.app import cli
status = cli.main(sys.argv[1:])
assert status == 0, status
"""


def _run(tmp_path, argv, env=None) -> dict:
    out = subprocess.run([sys.executable, "-c", LISTING, *argv], capture_output=True, text=True, cwd=tmp_path,
                         env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    return {key: json.loads(line[len(key) + 1:]) for line in out.stdout.splitlines()
            for key in ("KERNELS", "COMPILED") if line.startswith(key + " ")}


def kernels_of(tmp_path, *argv) -> dict:
    return _run(tmp_path, argv)["KERNELS"]


def modules(kernels: dict) -> set[str]:
    return {name.rsplit(".", 1)[0].removeprefix("lie_factors.") for name in kernels}


#: What the batch path of an SE(3) pose graph runs: the group's kernels and the factors'
#: (checks, coefficients, SO(3) and SE(3) cores, the factors' construction), the batch loops and
#: the sparse assembly.
BATCH_SE3 = {"kernels.coeffs", "kernels.checks", "kernels.relative", "kernels.retraction", "so3", "se3", "batch.loops",
             "sparse.pattern"}


def test_the_demo_compiles_the_batch_path_only(tmp_path):
    """A first run (an empty numba cache): what the demo compiles, numba's own functions included."""
    cache = tmp_path / "numba-cache"
    run = _run(tmp_path, ["demo", "--poses", "60", "--quiet", "--output", str(tmp_path)],
               env=dict(os.environ, NUMBA_CACHE_DIR=str(cache)))
    kernels = run["KERNELS"]
    # numba's message for an array assignment of mismatched shapes: seconds of string formatting,
    # compiled by any kernel that assigns an array to a slice (write such copies entry by entry)
    assert not [name for name in run["COMPILED"] if "raise_with_shape_context" in name]
    assert modules(kernels) <= BATCH_SE3, modules(kernels) - BATCH_SE3
    assert not [k for k, v in kernels.items() if v["parallel"]]  # 60 poses: every loop on the calling thread
    # one signature per kernel, but where the arguments' types differ by design: the Horner sum
    # over series of different lengths, and the Gram block of a diagonal or an off-diagonal block
    twice = {k for k, v in kernels.items() if len(v["signatures"]) > 1}
    assert twice <= {"lie_factors.kernels.coeffs.horner", "lie_factors.sparse.pattern._add_gram"}, twice


@pytest.mark.parametrize("extra, absent", [
    ((), {"incremental", "robust", "sparse.selinv"}),
    (("--incremental",), {"robust", "sparse.selinv", "sparse.pattern"}),
    (("--gnc", "tls"), {"incremental"}),  # the leave-out test inverts on the factor's pattern
    (("--covariances", "c.npz"), {"incremental", "robust"}),
], ids=["batch", "incremental", "gnc", "covariances"])
def test_each_posegraph_command_compiles_its_own_path(tmp_path, extra, absent):
    kernels = kernels_of(tmp_path, "posegraph", str(DATA / "intel.g2o"), "--quiet", *extra)
    found = {m for m in modules(kernels) for a in absent if m == a or m.startswith(a + ".")}
    assert not found, found
    # intel is below PARALLEL_MIN_WORK; the leave-out test's Gram blocks are always worth threads
    # (each a sweep along the elimination tree, many times a factor's work)
    assert {k for k, v in kernels.items() if v["parallel"]} <= {"lie_factors.robust.leave_out._group_gram"}
