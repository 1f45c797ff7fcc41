"""The loops over factors on numba's threads or on the calling thread (batch.loops.parallel):
small graphs never compile the parallel wrappers, and both give the same bits."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

import lie_factors as lf
from lie_factors.batch import loops
from lie_factors.batch.loops import PARALLEL_MIN_WORK
from lie_factors.posegraph.graph import PoseGraph

ROOT = Path(__file__).resolve().parents[2]
INTEL = str(ROOT / "data" / "intel.g2o")

WRAPPERS = """
import sys
import lie_factors as lf
from lie_factors.batch import loops
from lie_factors.robust import consistency
lf.optimize(lf.read_g2o(sys.argv[1]), gnc="tls")
print(sum(len(k.signatures) for k in (loops._factor_chunks, loops._retract, consistency._gate_kernel,
                                      consistency._pair_kernel)))
"""


def test_small_graphs_never_compile_the_parallel_loops():
    """Below PARALLEL_MIN_WORK every loop runs on the calling thread: a fresh process running
    the default path and GNC compiles (or loads) none of the parallel wrappers, numba's
    costliest compilations."""
    pg = lf.read_g2o(INTEL)
    assert pg.edge_count * 9 < PARALLEL_MIN_WORK
    out = subprocess.run([sys.executable, "-c", WRAPPERS, INTEL], check=True, capture_output=True, text=True,
                         cwd=ROOT).stdout
    assert out.split() == ["0"]


def _chain(n: int, seed: int) -> PoseGraph:
    """A noisy SE(3) chain of ``n`` poses with a loop closure every 10 poses (some false)."""
    rng = np.random.default_rng(seed)
    from lie_factors import se3

    steps = se3.exp(np.concatenate([rng.normal(0, 0.05, (n - 1, 3)), rng.normal([1, 0, 0], 0.1, (n - 1, 3))], 1))
    truth = [np.eye(4)]
    for S in steps:
        truth.append(truth[-1] @ S)
    pairs = [(i, i + 1) for i in range(n - 1)] + [(i, i + 10) for i in range(0, n - 10, 10)]
    Z = np.array([np.linalg.inv(truth[i]) @ truth[j] for i, j in pairs])
    Z[n - 1::3] = se3.exp(rng.normal(0, 1.0, (len(Z[n - 1::3]), 6)))  # false closures
    info = np.broadcast_to(np.diag([400.0] * 3 + [100.0] * 3), (len(pairs), 6, 6))
    return PoseGraph("Pose3", np.arange(n), np.array(pairs), Z, np.ascontiguousarray(info), None, None)


def test_the_parallel_loops_give_the_serial_loops_bits(monkeypatch):
    """With every call above PARALLEL_MIN_WORK (threshold 0) the loops run as parallel kernels
    (even where numba has one thread), and the optimization is the serial one, bit for bit:
    each factor writes only its own outputs.  The default path and GNC's consistency stage."""
    pg = _chain(120, 3)
    serial = lf.optimize(pg)
    robust = lf.optimize(pg, gnc="tls")
    monkeypatch.setattr(loops, "PARALLEL_MIN_WORK", 0)
    monkeypatch.setattr(loops, "threads", lambda: 2)
    parallel = lf.optimize(pg)
    robust_parallel = lf.optimize(pg, gnc="tls")
    assert loops._factor_chunks.signatures and loops._retract.signatures
    assert parallel.errors == serial.errors
    assert np.array_equal(parallel.poses, serial.poses)
    assert np.array_equal(robust_parallel.outliers, robust.outliers)
    assert np.array_equal(robust_parallel.poses, robust.poses)
