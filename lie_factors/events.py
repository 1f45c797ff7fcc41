"""What a run reports while it runs: subclass :class:`Events` and override what you want to hear.

Every method is a no-op here. :func:`lie_factors.optimize` and :func:`lie_factors.replay`
take ``events=``; the command line's progress lines are one such subclass.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .initialization import Initialization
    from .lm import IterationInfo

__all__ = ["Events"]


class Events:
    """Hooks of a run, in the order they come."""

    def started(self, start: "Initialization") -> None:
        """The initial values are chosen (``start.method``, ``start.seconds``, ``start.poses``)."""

    def set_up(self, seconds: float) -> None:
        """The optimizer is set up (graph or problem, linear system, symbolic analysis) in
        ``seconds``; its iterations come next."""

    def iteration(self, info: "IterationInfo") -> None:
        """One Levenberg–Marquardt iteration is done (``info.iteration``, ``info.error``,
        ``info.lambda_``, ``info.seconds``)."""

    def gnc_iteration(self, iteration: int, mu: float, cost: float, lm_iterations: int) -> None:
        """One outer iteration of graduated non-convexity is done (0-based ``iteration``, its
        control parameter ``mu``, the weighted cost, the inner LM's iterations)."""

    def replayed(self, done: int, total: int, seconds: float) -> None:
        """An online replay has done ``done`` of ``total`` updates in ``seconds``."""
