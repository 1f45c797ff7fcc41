"""The smoother's parameters (:class:`SmootherParams`, ISAM2's under GTSAM's names) and what an update reports.

:class:`SmootherParams` mirrors ``gtsam.ISAM2Params``: its fields keep GTSAM's
camelCase names so that ISAM2 code reads the same.
"""

from __future__ import annotations

import os
import re
import tempfile
from dataclasses import dataclass

import gtsam
import numpy as np


class SmootherError(ValueError):
    """Bad input to :class:`Smoother` (unknown or duplicate key, wrong type, non-finite numbers, …)."""


@dataclass
class SmootherParams:
    """ISAM2's parameters the smoother honours, under GTSAM's names.

    ``relinearizeThreshold``: relinearize a variable whose δ has a component of
    at least this size (``ISAM2Params.relinearizeThreshold``, 0.1); ``relinearizeSkip``:
    check every this many updates (10); ``enableRelinearization``;
    ``wildfireThreshold``: back-substitution stops below nodes that moved less
    (``ISAM2GaussNewtonParams.wildfireThreshold``, 0.001; 0: the exact
    solution); ``relinearizePolicy``: ``"variable"`` (ISAM2's, per variable) or
    ``"global"`` (SLAM++'s: every variable, when the largest δ reaches the threshold).
    """

    relinearizeThreshold: float = 0.1
    relinearizeSkip: int = 10
    enableRelinearization: bool = True
    wildfireThreshold: float = 0.001
    relinearizePolicy: str = "variable"

    def __post_init__(self):
        if not (np.isfinite(self.relinearizeThreshold) and self.relinearizeThreshold >= 0):
            raise SmootherError(f"relinearizeThreshold must be finite and >= 0, got {self.relinearizeThreshold}")
        if int(self.relinearizeSkip) < 1:
            raise SmootherError(f"relinearizeSkip must be >= 1, got {self.relinearizeSkip}")
        if not (np.isfinite(self.wildfireThreshold) and self.wildfireThreshold >= 0):
            raise SmootherError(f"wildfireThreshold must be finite and >= 0, got {self.wildfireThreshold}")
        if self.relinearizePolicy not in ("variable", "global"):
            raise SmootherError(f"relinearizePolicy must be 'variable' or 'global', got {self.relinearizePolicy!r}")
        self.relinearizeSkip = int(self.relinearizeSkip)

    @classmethod
    def from_isam2(cls, params: gtsam.ISAM2Params) -> "SmootherParams":
        """The values of a ``gtsam.ISAM2Params`` (GTSAM's Python API has no getters for the
        thresholds: they are read from its ``print`` output, 6 significant digits)."""
        text = _captured_print(params)

        def number(name, default):
            m = re.search(rf"^{name}:\s*(\S+)", text, re.M)
            return float(m.group(1)) if m else default

        if "ISAM2DoglegParams" in text:
            raise SmootherError("the smoother runs Gauss-Newton steps: ISAM2DoglegParams are not supported")
        return cls(relinearizeThreshold=number("relinearizeThreshold", 0.1),
                   relinearizeSkip=int(params.relinearizeSkip),
                   enableRelinearization=bool(params.enableRelinearization),
                   wildfireThreshold=number("wildfireThreshold", 0.001))


def _captured_print(params) -> str:
    """What ``params.print()`` writes: GTSAM's wrapper sends C++'s ``std::cout`` to Python's
    ``sys.stdout`` (caught here), or else to the process's standard output (caught on its
    descriptor, C's buffer flushed before it is put back)."""
    import contextlib
    import ctypes
    import io
    import sys

    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    libc.fflush(None)
    text = io.StringIO()
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        saved = os.dup(1)
        try:
            os.dup2(tmp.fileno(), 1)
            with contextlib.redirect_stdout(text):
                params.print()
            libc.fflush(None)
        finally:
            os.dup2(saved, 1)
            os.close(saved)
        tmp.seek(0)
        return text.getvalue() + tmp.read().decode(errors="replace")


@dataclass
class UpdateResult:
    """What an update did (ISAM2Result's counts): variables re-eliminated, relinearized,
    cliques (nodes) in the tree, and whether everything was reordered."""

    variablesReeliminated: int
    variablesRelinearized: int
    cliques: int
    reordered: bool

    def getVariablesReeliminated(self) -> int:
        return self.variablesReeliminated

    def getVariablesRelinearized(self) -> int:
        return self.variablesRelinearized

    def getCliques(self) -> int:
        return self.cliques
