"""Optimization timers that never count numba compilation.

Numba compiles a kernel the first time it meets a new signature (on a fresh
machine: no on-disk cache yet). The optimizers warm their kernels before
starting the clock (:func:`warm_up_factors`), and their stopwatches subtract
whatever compilation still happens while they run, so reported optimization
seconds are the same on a first and a later run. This module imports neither
numba nor GTSAM: it reads the compile clock of :mod:`lie_factors.kernels.jit` only if
something has loaded it (no kernel, no compilation).
"""

from __future__ import annotations

import sys
import time

__all__ = ["compile_seconds", "warm_up_factors", "Stopwatch"]


def compile_seconds() -> float:
    """Seconds numba has spent compiling in this process so far."""
    jit = sys.modules.get("lie_factors.kernels.jit")
    return jit.compile_seconds() if jit is not None else 0.0


def warm_up_factors() -> None:
    """Compile (or load) the evaluation kernels of every lie_factors factor built so far."""
    factors = sys.modules.get("lie_factors.factors")
    if factors is not None:
        factors.warm_up_constructed()


class Stopwatch:
    """Wall-clock seconds since start (or :meth:`restart`), less numba compilation in between."""

    def __init__(self):
        self.restart()

    def restart(self) -> None:
        self._t0 = time.perf_counter()
        self._c0 = compile_seconds()

    def seconds(self) -> float:
        return (time.perf_counter() - self._t0) - (compile_seconds() - self._c0)
