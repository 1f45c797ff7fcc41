"""The dense elimination of a front: the compiled loops against BLAS's trailing update, by size.

    python benchmarks/dense_fronts.py [--repeat 5]
    OPENBLAS_NUM_THREADS=1 python benchmarks/dense_fronts.py

:func:`lie_factors.incremental.fronts.eliminate_columns` eliminates D scalars of a random
symmetric positive definite front of side N = D + M + 1 (M trailing scalars and the
right-hand side), once with its loops alone and once with the trailing update from BLAS
(:func:`~lie_factors.incremental.fronts._trailing_blas`), alternated, best of ``--repeat``
batches.  Prints both times, their ratio, whether
:func:`~lie_factors.incremental.fronts.uses_blas` picks BLAS there, and the largest
difference between the two results (relative).  OpenBLAS's threads are what the environment
says (``OPENBLAS_NUM_THREADS``); the tiles stay below the size at which OpenBLAS starts them.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from lie_factors.incremental.fronts import BLAS_TILE, eliminate_columns, uses_blas  # noqa: E402

SIZES = [(6, 60), (6, 150), (6, 300), (12, 60), (12, 100), (12, 200), (18, 60), (18, 120), (24, 60), (24, 100),
         (30, 150), (30, 300), (60, 60), (60, 140), (60, 340), (100, 500)]


def front(D: int, M: int, rng) -> np.ndarray:
    N = D + M + 1
    A = rng.normal(size=(N + 5, N))
    Phi = A.T @ A
    Phi[N - 1, :N - 1] = np.diag(Phi)[:N - 1]
    return Phi


def timed(Phi: np.ndarray, D: int, blas: bool, reps: int, Tt, G) -> float:
    t0 = time.perf_counter()
    for _ in range(reps):
        x = Phi.copy()
        eliminate_columns(x, 0, D, blas, Tt, G)
    return (time.perf_counter() - t0) / reps


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    print(f"# load: {subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()}")
    print(f"# OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}")
    rng = np.random.default_rng(0)
    print("| D | M | loops µs | BLAS µs | BLAS / loops | uses_blas | rel. diff |")
    print("|---|---|---|---|---|---|---|")
    for D, M in SIZES:
        Phi = front(D, M, rng)
        N = Phi.shape[0]
        Tt, G = np.empty(N * N), np.empty(BLAS_TILE * BLAS_TILE)
        a, b = Phi.copy(), Phi.copy()
        eliminate_columns(a, 0, D, False, Tt, G)
        eliminate_columns(b, 0, D, True, Tt, G)
        diff = np.max(np.abs(np.triu(a) - np.triu(b))) / np.max(np.abs(np.triu(a)))
        reps = max(3, int(3e7 / (D * N * N)))
        best = [np.inf, np.inf]
        for r in range(args.repeat):
            for blas in ((False, True) if r % 2 == 0 else (True, False)):
                best[blas] = min(best[blas], timed(Phi, D, blas, reps, Tt, G))
        print(f"| {D} | {M} | {best[0] * 1e6:.1f} | {best[1] * 1e6:.1f} | {best[1] / best[0]:.2f} | "
              f"{bool(uses_blas(D, M))} | {diff:.1e} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
