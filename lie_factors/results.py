"""Result types of an optimization run, shared by every backend (posegraph and the batch solver import
them from here, not from each other)."""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam


@dataclass
class IterationInfo:
    """One LM iteration: number (1-based), error after it, λ after it, wall seconds."""

    iteration: int
    error: float
    lambda_: float
    seconds: float


@dataclass
class OptimizeResult:
    values: gtsam.Values
    iterations: int
    initial_error: float
    final_error: float
    seconds: float
    converged: bool
    history: list[IterationInfo] = field(default_factory=list)
    #: the values LM started from (set by lie_factors.app.run.run)
    start: gtsam.Values | None = None


def format_iteration(info: IterationInfo) -> str:
    """One progress line, in the spirit of GTSAM's SUMMARY verbosity."""
    return (f"iter {info.iteration:4d}  error {info.error:.6e}  lambda {info.lambda_:.2e}  "
            f"time {info.seconds:.3f} s")
