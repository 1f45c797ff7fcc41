"""The smoother's parameters (:class:`SmootherParams`, ISAM2's under GTSAM's names) and what an update reports.

:class:`SmootherParams` mirrors ``gtsam.ISAM2Params``: its fields keep GTSAM's
camelCase names so that ISAM2 code reads the same.
"""

from __future__ import annotations

import contextlib
import io
import re
import weakref
from dataclasses import dataclass, field

import gtsam
import numpy as np

from ..errors import InputError


#: The optimization parameters of ISAM2 (``ISAM2GaussNewtonParams``, ``ISAM2DoglegParams``,
#: ``ISAM2DoglegLineSearchParams``).
OPTIMIZERS = ("GaussNewton", "Dogleg", "DoglegLineSearch")

#: ISAM2's Dogleg trust-region adaptation modes (``DoglegOptimizerImpl::TrustRegionAdaptationMode``).
ADAPTATION_MODES = ("SEARCH_EACH_ITERATION", "ONE_STEP_PER_ITERATION")


@dataclass
class SmootherParams:
    """ISAM2's parameters the smoother honours, under GTSAM's names.

    ``relinearizeThreshold``: relinearize a variable whose δ has a component of at least
    this size (``ISAM2Params.relinearizeThreshold``, 0.1), or a dict from a key's symbol
    character to a vector of per-component thresholds (``ISAM2ThresholdMap``: relinearized
    when a component exceeds its threshold); ``relinearizeSkip``: check every this many
    updates (10); ``enableRelinearization``; ``optimizer``: ``"GaussNewton"`` (ISAM2's
    default), ``"Dogleg"`` (``ISAM2DoglegParams``: Powell's dogleg on the whole δ, with
    ``initialDelta`` and ``adaptationMode``) or ``"DoglegLineSearch"``
    (``ISAM2DoglegLineSearchParams``: an outward search along the dogleg path, with
    ``minDelta``, ``maxDelta``, ``stepSize``, ``sufficientDecreaseCoeff``);
    ``wildfireThreshold``: back-substitution stops below nodes that moved less (0.001 for
    Gauss–Newton, 1e-5 for Dogleg, 1e-4 for the line search; 0: the exact solution); ``evaluateNonlinearError``: an update reports the graph's error before and
    after it; ``enableDetailedResults``: it reports the factor's entries (``getTreeNnz``);
    ``enableAdaptiveReorder``, ``adaptiveReorderThreshold``: every variable is ordered and
    eliminated afresh when the factor's entries grow past this many times their count after
    the last such reordering; ``relinearizePolicy``: ``"variable"`` (ISAM2's, per
    variable) or ``"global"`` (SLAM++'s: every variable, when the largest δ reaches the
    threshold).
    """

    relinearizeThreshold: "float | dict" = 0.1
    relinearizeSkip: int = 10
    enableRelinearization: bool = True
    wildfireThreshold: float = 0.001
    relinearizePolicy: str = "variable"
    optimizer: str = "GaussNewton"
    initialDelta: float = 1.0
    adaptationMode: str = "SEARCH_EACH_ITERATION"
    minDelta: float = 0.02
    maxDelta: float = 0.5
    stepSize: float = 1.5
    sufficientDecreaseCoeff: float = 1e-3
    evaluateNonlinearError: bool = False
    enableDetailedResults: bool = False
    enableAdaptiveReorder: bool = False
    adaptiveReorderThreshold: float = 2.0

    def __post_init__(self):
        t = self.relinearizeThreshold
        if isinstance(t, dict):
            checked = {}
            for c, v in t.items():
                v = np.asarray(v, dtype=np.float64).reshape(-1)
                if not (isinstance(c, str) and len(c) == 1) or not (np.all(np.isfinite(v)) and np.all(v >= 0)):
                    raise InputError("relinearizeThreshold: a map from one character to finite thresholds >= 0, "
                                     f"got {c!r}: {v}")
                checked[c] = v
            self.relinearizeThreshold = checked
        elif not (np.isfinite(t) and t >= 0):
            raise InputError(f"relinearizeThreshold must be finite and >= 0, got {t}")
        if int(self.relinearizeSkip) < 1:
            raise InputError(f"relinearizeSkip must be >= 1, got {self.relinearizeSkip}")
        if not (np.isfinite(self.wildfireThreshold) and self.wildfireThreshold >= 0):
            raise InputError(f"wildfireThreshold must be finite and >= 0, got {self.wildfireThreshold}")
        if self.relinearizePolicy not in ("variable", "global"):
            raise InputError(f"relinearizePolicy must be 'variable' or 'global', got {self.relinearizePolicy!r}")
        if isinstance(self.relinearizeThreshold, dict) and self.relinearizePolicy != "variable":
            raise InputError("per-type relinearization thresholds go with relinearizePolicy 'variable'")
        if self.optimizer not in OPTIMIZERS:
            raise InputError(f"optimizer must be one of {', '.join(OPTIMIZERS)}, got {self.optimizer!r}")
        if not (0 < self.minDelta <= self.maxDelta < np.inf and self.stepSize > 1 and np.isfinite(self.stepSize)
                and 0 <= self.sufficientDecreaseCoeff < np.inf):
            raise InputError("the line search needs 0 < minDelta <= maxDelta, stepSize > 1 and "
                             f"sufficientDecreaseCoeff >= 0, all finite, got {self.minDelta}, {self.maxDelta}, "
                             f"{self.stepSize}, {self.sufficientDecreaseCoeff}")
        if not (np.isfinite(self.initialDelta) and self.initialDelta > 0):
            raise InputError(f"initialDelta must be finite and > 0, got {self.initialDelta}")
        if self.adaptationMode not in ADAPTATION_MODES:
            raise InputError(f"adaptationMode must be one of {', '.join(ADAPTATION_MODES)}, got {self.adaptationMode!r}")
        if not (np.isfinite(self.adaptiveReorderThreshold) and self.adaptiveReorderThreshold > 1.0):
            raise InputError(f"adaptiveReorderThreshold must be finite and > 1, got {self.adaptiveReorderThreshold}")
        self.relinearizeSkip = int(self.relinearizeSkip)

    @classmethod
    def from_isam2(cls, params: gtsam.ISAM2Params) -> "SmootherParams":
        """The values of a ``gtsam.ISAM2Params`` the smoother honours.

        ``relinearizeSkip``, ``enableRelinearization``, ``evaluateNonlinearError``,
        ``enableDetailedResults``, ``enableAdaptiveReorder`` and ``adaptiveReorderThreshold``
        are read through GTSAM's accessors.  Its Python API has setters only for the
        relinearization threshold (``setRelinearizeThreshold``: a number or an
        ``ISAM2ThresholdMap``) and the optimization parameters (``setOptimizationParams``:
        Gauss–Newton's or Dogleg's, with their wildfire threshold, Dogleg's initial Delta and
        adaptation mode): those are read from what ``params.print()`` writes, to 6
        significant digits (``std::cout``'s precision); ``ISAM2DoglegLineSearchParams``, which
        ``print()`` does not write, as they were given to ``setOptimizationParams``
        (:func:`record_optimization_params`).  Refused: ``enablePartialRelinearizationCheck``
        (it chooses what is relinearized by the cliques of ISAM2's Bayes tree, which this
        factor does not have) and ``findUnusedFactorSlots`` (factor indices here are never
        reused).  The other
        fields (``factorization``, ``cacheLinearizedFactors``, ``keyFormatter``) concern how
        ISAM2 computes, not what: the smoother has no counterpart to them.
        """
        text = _printed(params)
        fields = dict(re.findall(r"^(?:optimizationParams:\s*)?(\w+):\s*(\S+)", text, re.M))
        if params.enablePartialRelinearizationCheck:
            raise InputError("enablePartialRelinearizationCheck is not supported: it checks ISAM2's cliques, "
                             "which the smoother's factor does not have")
        if params.findUnusedFactorSlots:
            raise InputError("findUnusedFactorSlots is not supported: the smoother never reuses a factor index")
        threshold = fields.get("relinearizeThreshold")
        if threshold == "{mapped}":
            threshold = _printed_thresholds(text)
        elif threshold is not None:
            threshold = float(threshold)
        if threshold is None:
            raise InputError("could not read relinearizeThreshold from gtsam.ISAM2Params.print(): give a "
                             "SmootherParams instead")
        common = dict(relinearizeThreshold=threshold, relinearizeSkip=int(params.relinearizeSkip),
                      enableRelinearization=bool(params.enableRelinearization),
                      evaluateNonlinearError=bool(params.evaluateNonlinearError),
                      enableDetailedResults=bool(params.enableDetailedResults),
                      enableAdaptiveReorder=bool(params.enableAdaptiveReorder),
                      adaptiveReorderThreshold=float(params.adaptiveReorderThreshold))
        return cls(**common, **_optimization(params, fields))

    def threshold_of(self, key: int, dim: int):
        """The relinearization threshold of ``key``: a number, or its vector (dim,) of a
        per-type map (InputError when the map has none of its symbol's character or one of
        another dimension)."""
        t = self.relinearizeThreshold
        if not isinstance(t, dict):
            return t
        c = chr(gtsam.Symbol(int(key)).chr())
        v = t.get(c)
        if v is None:
            raise InputError(f"the relinearization threshold map has no entry for {c!r} "
                             f"(key {gtsam.DefaultKeyFormatter(int(key))})")
        if v.shape[0] != dim:
            raise InputError(f"the relinearization threshold of {c!r} has {v.shape[0]} components, its "
                             f"variables {dim}")
        return v


def _optimization(params: gtsam.ISAM2Params, fields: dict) -> dict:
    """The optimization parameters of ``params``: Gauss–Newton's and Dogleg's as ``print()``
    writes them; the line search's (which ``print()`` does not write) as
    ``setOptimizationParams`` was given them (:func:`record_optimization_params`)."""
    kind = fields.get("type")
    if kind == "ISAM2GaussNewtonParams" and "wildfireThreshold" in fields:
        return dict(optimizer="GaussNewton", wildfireThreshold=float(fields["wildfireThreshold"]))
    if kind == "ISAM2DoglegParams" and {"wildfireThreshold", "initialDelta", "adaptationMode"} <= set(fields):
        return dict(optimizer="Dogleg", wildfireThreshold=float(fields["wildfireThreshold"]),
                    initialDelta=float(fields["initialDelta"]), adaptationMode=fields["adaptationMode"])
    line_search = RECORDED.get(params)
    if line_search is not None:
        return dict(optimizer="DoglegLineSearch", **line_search)
    raise InputError("could not read the optimization parameters of this gtsam.ISAM2Params (GTSAM's Python "
                     "API cannot read ISAM2DoglegLineSearchParams back when they were set before lie_factors."
                     "incremental was imported): give a SmootherParams instead")


#: The line-search parameters given to each ``gtsam.ISAM2Params`` by ``setOptimizationParams``.
RECORDED: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def record_optimization_params() -> None:
    """Make ``gtsam.ISAM2Params.setOptimizationParams`` remember ``ISAM2DoglegLineSearchParams``
    (in :data:`RECORDED`), which GTSAM's Python API can set but neither read nor print; it
    calls GTSAM's own setter first, and changes nothing else."""
    original = gtsam.ISAM2Params.setOptimizationParams
    if getattr(original, "records_line_search", False):
        return

    def setOptimizationParams(self, optimizationParams):
        original(self, optimizationParams)
        if isinstance(optimizationParams, gtsam.ISAM2DoglegLineSearchParams):
            p = optimizationParams
            RECORDED[self] = dict(minDelta=float(p.getMinDelta()), maxDelta=float(p.getMaxDelta()),
                                  stepSize=float(p.getStepSize()),
                                  sufficientDecreaseCoeff=float(p.getSufficientDecreaseCoeff()),
                                  wildfireThreshold=float(p.getWildfireThreshold()))
        else:
            RECORDED.pop(self, None)

    setOptimizationParams.records_line_search = True
    setOptimizationParams.__doc__ = original.__doc__
    gtsam.ISAM2Params.setOptimizationParams = setOptimizationParams


record_optimization_params()


def _printed(params: gtsam.ISAM2Params) -> str:
    """What ``params.print()`` writes (GTSAM's wrapper sends C++'s ``std::cout`` to
    ``sys.stdout``), the optimization parameters' included."""
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        params.print()
    return text.getvalue()


def _printed_thresholds(text: str) -> dict:
    """The per-type thresholds ``print()`` lists under ``relinearizeThreshold: {mapped}``, as
    ``'x' -> [0.1 0.2 0.3 ]`` lines."""
    return {c: np.array(v.split(), dtype=np.float64) for c, v in re.findall(r"^\s*'(.)' -> \[([^\]]*)\]", text, re.M)}


@dataclass
class UpdateResult:
    """What an update did, under ``gtsam.ISAM2Result``'s getters: variables re-eliminated and
    relinearized, nodes in the factor's tree (``getCliques``: one per variable; ISAM2's cliques
    group variables), whether everything was reordered, factors assembled into the
    re-eliminated fronts (``getFactorsRecalculated``), the new factors' indices, the keys
    taken out with no factor left (``getUnusedKeys``), the keys of new and removed factors and
    of ``extraReelimKeys`` (``getObservedKeys``), those of removed factors
    (``getKeysWithRemovedFactors``), the observed and relinearized keys (``getMarkedKeys``),
    whether an adaptive reordering was triggered, the factor's entries
    (``getTreeNnz``, with ``enableDetailedResults``), and the errors before and after
    (with ``evaluateNonlinearError``, else None)."""

    variablesReeliminated: int
    variablesRelinearized: int
    cliques: int
    reordered: bool
    factorsRecalculated: int = 0
    newFactorsIndices: list = field(default_factory=list)
    unusedKeys: list = field(default_factory=list)
    observedKeys: list = field(default_factory=list)
    keysWithRemovedFactors: list = field(default_factory=list)
    markedKeys: list = field(default_factory=list)
    batchReorderTriggered: bool = False
    treeNnz: int = 0
    errorBefore: float | None = None
    errorAfter: float | None = None

    def getVariablesReeliminated(self) -> int:
        return self.variablesReeliminated

    def getVariablesRelinearized(self) -> int:
        return self.variablesRelinearized

    def getCliques(self) -> int:
        return self.cliques

    def getFactorsRecalculated(self) -> int:
        return self.factorsRecalculated

    def getNewFactorsIndices(self) -> list:
        return list(self.newFactorsIndices)

    def getUnusedKeys(self) -> gtsam.KeySet:
        return gtsam.KeySet(self.unusedKeys)

    def getObservedKeys(self) -> list:
        return list(self.observedKeys)

    def getKeysWithRemovedFactors(self) -> gtsam.KeySet:
        return gtsam.KeySet(self.keysWithRemovedFactors)

    def getMarkedKeys(self) -> gtsam.KeySet:
        return gtsam.KeySet(self.markedKeys)

    def getBatchReorderTriggered(self) -> bool:
        return self.batchReorderTriggered

    def getTreeNnz(self) -> int:
        return self.treeNnz

    def getErrorBefore(self) -> float | None:
        return self.errorBefore

    def getErrorAfter(self) -> float | None:
        return self.errorAfter

    def print(self, s: str = "") -> None:
        """ISAM2Result's print: its counts, one per line."""
        print(f"{s}ISAM2Result: reeliminated {self.variablesReeliminated}, relinearized "
              f"{self.variablesRelinearized}, cliques {self.cliques}, factors recalculated "
              f"{self.factorsRecalculated}")
