"""The smoother's parameters (:class:`SmootherParams`, ISAM2's under GTSAM's names) and what an update reports.

:class:`SmootherParams` mirrors ``gtsam.ISAM2Params``: its fields keep GTSAM's
camelCase names so that ISAM2 code reads the same.
"""

from __future__ import annotations

import contextlib
import io
import re
from dataclasses import dataclass

import gtsam
import numpy as np

from ..errors import InputError


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
            raise InputError(f"relinearizeThreshold must be finite and >= 0, got {self.relinearizeThreshold}")
        if int(self.relinearizeSkip) < 1:
            raise InputError(f"relinearizeSkip must be >= 1, got {self.relinearizeSkip}")
        if not (np.isfinite(self.wildfireThreshold) and self.wildfireThreshold >= 0):
            raise InputError(f"wildfireThreshold must be finite and >= 0, got {self.wildfireThreshold}")
        if self.relinearizePolicy not in ("variable", "global"):
            raise InputError(f"relinearizePolicy must be 'variable' or 'global', got {self.relinearizePolicy!r}")
        self.relinearizeSkip = int(self.relinearizeSkip)

    @classmethod
    def from_isam2(cls, params: gtsam.ISAM2Params) -> "SmootherParams":
        """The values of a ``gtsam.ISAM2Params`` the smoother honours.

        ``relinearizeSkip`` and ``enableRelinearization`` are read through GTSAM's
        accessors.  Its Python API has setters only for the relinearization threshold
        (``setRelinearizeThreshold``) and the optimization parameters
        (``setOptimizationParams``: their type and wildfire threshold): those are read from
        what ``params.print()`` writes, to 6 significant digits (``std::cout``'s precision).
        Refused: Dogleg parameters (the smoother takes Gauss–Newton steps) and per-type
        thresholds (``ISAM2ThresholdMap``).  The other fields (``factorization``,
        ``cacheLinearizedFactors``, ``evaluateNonlinearError``,
        ``enablePartialRelinearizationCheck``, ``findUnusedFactorSlots``, …) concern how
        ISAM2 computes, not what: the smoother has no counterpart to them.
        """
        fields = _printed_fields(params)
        kind = fields.get("type")
        if kind == "ISAM2DoglegParams":
            raise InputError("the smoother runs Gauss-Newton steps: ISAM2DoglegParams are not supported")
        threshold = fields.get("relinearizeThreshold")
        if threshold == "{mapped}":
            raise InputError("per-type relinearization thresholds (ISAM2ThresholdMap) are not supported: "
                                "give one threshold")
        if kind != "ISAM2GaussNewtonParams" or threshold is None or "wildfireThreshold" not in fields:
            raise InputError("could not read relinearizeThreshold and wildfireThreshold from "
                                "gtsam.ISAM2Params.print(): give a SmootherParams instead")
        return cls(relinearizeThreshold=float(threshold),
                   relinearizeSkip=int(params.relinearizeSkip),
                   enableRelinearization=bool(params.enableRelinearization),
                   wildfireThreshold=float(fields["wildfireThreshold"]))


def _printed_fields(params: gtsam.ISAM2Params) -> dict[str, str]:
    """The ``name: value`` lines ``params.print()`` writes (GTSAM's wrapper sends C++'s
    ``std::cout`` to ``sys.stdout``), the optimization parameters' included."""
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        params.print()
    return dict(re.findall(r"^(?:optimizationParams:\s*)?(\w+):\s*(\S+)", text.getvalue(), re.M))


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
