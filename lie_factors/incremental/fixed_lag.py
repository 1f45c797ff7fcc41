"""A fixed-lag smoother on the incremental smoother: GTSAM's ``IncrementalFixedLagSmoother``.

Each variable carries a timestamp; after every update, the variables older
than the newest timestamp less the lag are marginalized out
(:meth:`~lie_factors.incremental.smoother.Smoother.marginalizeLeaves`), so
that the smoother holds a window of the latest ``smootherLag`` seconds and a
linear summary of everything before.  As GTSAM's does, each update first
orders the variables to marginalize before every other (``constrainedKeys``:
group 0, the others group 1) and re-eliminates every node whose separator
holds one of them (``extraReelimKeys``), so that they are leaves when they are
marginalized; then the update runs, then the marginalization.

When.  GTSAM's marginalizes on every update; this one leaves the marginalization for later
while nothing could tell.  Marginalizing changes no estimate in the window (the
conditionals above already hold what the marginal factors carry); what it changes is which
variables the next relinearization check may move: GTSAM's holds the marginalized
variables' separators from then on.  So before an update that checks relinearization
(every ``relinearizeSkip``-th) this one holds the keys that left and every variable a factor
joins to one of them (:func:`~lie_factors.incremental.marginalize.hold_for_later`: the same
variables), and marginalizes them all at once later: when they are as many as the window's
keys (a bound on the tree's size), or before an update that removes factors, re-adds one of
them or gives one a timestamp, or a read that could see them (the whole estimate, the
factors, the linearization point, δ, a marginal covariance, the smoother inside, or one of
those keys), after one re-elimination that makes them leaves
(:func:`~lie_factors.incremental.marginalize.marginalize_late`).  A new factor on one of them
is refused as the smoother refuses a factor on a key it does not hold.  Each key is then
marginalized at the linearization point GTSAM's would have used, and every estimate in the
window is the same; the updates in between are plain updates (no constrained ordering), and
one re-elimination and marginalization of many keys costs less than one per update.

::

    smoother = IncrementalFixedLagSmoother(2.0)       # a lag of 2 s, ISAM2's default parameters
    smoother.update(graph, values, {key: t, ...})     # new factors, values, each new key's time
    smoother.calculateEstimatePose3(key)

Differences from GTSAM's: factor indices are never reused (GTSAM's smoother turns
on ``findUnusedFactorSlots`` by default), so ``factorsToRemove`` takes the indices
:meth:`getISAM2Result` reported when the factors were added, as with GTSAM's.
"""

from __future__ import annotations

import bisect

import gtsam
import numpy as np

from ..batch.graph import key_name
from ..errors import InputError
from .array_path import update_read
from .gtsam_objects import VALUE_TYPES, read_update
from .marginalize import hold_for_later, marginalize_late
from .relinearization import checks_next
from .removal import keys_used, no_value
from .smoother import Smoother
from .update_args import PLAIN, read_args


class FixedLagSmootherResult:
    """What an update reports (``gtsam.FixedLagSmootherResult``'s getters): GTSAM's incremental
    smoother reports one iteration and no error."""

    def __init__(self):
        self.iterations, self.intermediateSteps, self.nonlinearVariables, self.linearVariables = 1, 0, 0, 0
        self.error = 0.0

    def getIterations(self) -> int:
        return self.iterations

    def getIntermediateSteps(self) -> int:
        return self.intermediateSteps

    def getNonlinearVariables(self) -> int:
        return self.nonlinearVariables

    def getLinearVariables(self) -> int:
        return self.linearVariables

    def getError(self) -> float:
        return self.error


class IncrementalFixedLagSmoother:
    """GTSAM's ``IncrementalFixedLagSmoother(smootherLag, parameters)`` on :class:`Smoother`
    (module docstring); ``parameters``: a ``gtsam.ISAM2Params`` or a
    :class:`~lie_factors.incremental.params.SmootherParams` (default ISAM2's)."""

    def __init__(self, smootherLag: float = 0.0, parameters=None):
        self._lag = _lag(smootherLag)
        self.isam = Smoother(parameters)
        self._time: dict[int, float] = {}  # key → timestamp
        self._order: list[tuple[float, int]] = []  # (timestamp, key), sorted
        self._result = None
        self._pending: dict = {}  # keys past the lag whose marginalization is left for later, in order
        self._held = 0  # how many of them are held (the first)

    # ---------------------------------------------------------------- the lag
    def smootherLag(self) -> float:
        return self._lag

    def setSmootherLag(self, smootherLag: float) -> None:
        self._lag = _lag(smootherLag)

    def timestamps(self) -> dict:
        """Every key's timestamp (``FixedLagSmoother::timestamps``)."""
        return dict(self._time)

    def _keys_before(self, t: float) -> list:
        return [k for _, k in self._order[:bisect.bisect_left(self._order, (t, -1))]]

    # ---------------------------------------------------------------- updates
    def update(self, newFactors=None, newTheta=None, timestamps=None, factorsToRemove=()) -> FixedLagSmootherResult:
        """Add factors, values and the new keys' timestamps (a dict or a
        ``FixedLagSmootherKeyTimestampMap``), take ``factorsToRemove`` out, then marginalize
        every variable older than the newest timestamp less the lag (module docstring: when)."""
        stamps = _stamps(timestamps)
        isam = self.isam
        nf = read_update(newFactors, newTheta, isam._setup)
        removal = list(factorsToRemove)
        order = self._order
        saved = [(k, self._time.get(k)) for k in stamps]
        for k, t in stamps.items():
            old = self._time.get(k)
            if old is not None:
                order.remove((old, k))
            self._time[k] = t
            bisect.insort(order, (t, k))
        try:
            now = order[-1][0] if order else -np.finfo(float).max
            # a key with a timestamp and no value is no variable: left out of the order's groups
            variables, new_keys = isam.var, set(nf.keys)
            old_keys = [k for k in self._keys_before(now - self._lag) if k in variables or k in new_keys]
            used = keys_used(nf)
            # the keys that leave are marginalized later (module docstring) unless this update
            # could tell; those left so far are held before an update that checks relinearization
            late = not removal and all(k in variables and k not in used for k in old_keys)
            pending = self._pending
            if pending:
                _refuse_gone(nf, (used - new_keys) & pending.keys())
            if pending and (not late or len(pending) >= len(self._time)
                            or not pending.keys().isdisjoint(new_keys | set(stamps))):
                self._flush()
            elif len(pending) > self._held and checks_next(isam):
                hold_for_later(isam, list(pending)[self._held:])
                self._held = len(pending)
            args = read_args(removal) if removal else PLAIN
            if old_keys and not late:
                extra = isam.row_subtree_keys([k for k in old_keys if k in variables])
                args = read_args(removal, self._first(old_keys, new_keys), None, extra)
            self._result = update_read(isam, nf, args)
        except BaseException:
            for k, t in saved:  # the timestamps as they were
                order.remove((self._time.pop(k), k))
                if t is not None:
                    self._time[k] = t
                    bisect.insort(order, (t, k))
            raise
        if late:
            self._pending.update(dict.fromkeys(old_keys))
        elif old_keys:
            isam.marginalizeLeaves(old_keys)
        for k in old_keys:
            t = self._time.pop(k)
            order.remove((t, k))
        return FixedLagSmootherResult()

    def _first(self, old_keys: list, new_keys=()) -> dict:
        """GTSAM's fixed-lag grouping (``constrainedKeys``): ``old_keys`` in group 0, before every
        other key with a timestamp that is a variable (or one of ``new_keys``) in group 1."""
        variables = self.isam.var
        constrained = {k: 1 for k in self._time if k in variables or k in new_keys}
        constrained.update(dict.fromkeys(old_keys, 0))
        return constrained

    def _flush(self) -> None:
        """Marginalize the keys left for later (module docstring)."""
        keys, self._pending, self._held = list(self._pending), {}, 0
        if keys:
            marginalize_late(self.isam, keys, self._first(keys))

    # ---------------------------------------------------------------- reading
    def calculateEstimate(self, key=None):
        self._flush_for(key)
        return self.isam.calculateEstimate(key)

    def _flush_for(self, key=None) -> None:
        """Marginalize what is left for later before a read of ``key`` (of everything: None)
        could see it; the estimate of a key in the window is the same either way."""
        if self._pending and (key is None or not isinstance(key, (int, np.integer)) or key in self._pending):
            self._flush()

    def params(self):
        return self.isam.params()

    def getFactors(self) -> gtsam.NonlinearFactorGraph:
        self._flush_for()
        return self.isam.getFactorsUnsafe()

    def getLinearizationPoint(self) -> gtsam.Values:
        self._flush_for()
        return self.isam.getLinearizationPoint()

    def getDelta(self) -> gtsam.VectorValues:
        self._flush_for()
        return self.isam.getDelta()

    def marginalCovariance(self, key) -> np.ndarray:
        self._flush_for()
        return self.isam.marginalCovariance(key)

    def getISAM2Result(self):
        """The report of the last update of the smoother inside."""
        return self._result

    def getISAM2(self) -> Smoother:
        """The smoother inside (what was left to marginalize, marginalized)."""
        self._flush_for()
        return self.isam

    def print(self, s: str = "IncrementalFixedLagSmoother:\n") -> None:
        print(f"{s}  smoother lag: {self._lag}")

    def equals(self, other, tol: float = 1e-9) -> bool:
        """Same lag and timestamps, and estimates equal to ``tol``."""
        if not isinstance(other, IncrementalFixedLagSmoother) or abs(self._lag - other._lag) >= tol:
            return False
        return self._order == other._order and self.calculateEstimate().equals(other.calculateEstimate(), tol)


def _refuse_gone(nf, gone: set) -> None:
    """The error the smoother gives a new factor on a key it does not hold, for a factor of the
    update ``nf`` on one of ``gone`` (keys marginalized, some of them late)."""
    for (_, name), entry in nf.arrays.items():
        for k in entry["keys"].ravel().tolist():
            if k in gone:
                raise no_value(f"{name} factor", k)
    for f, keys in nf.native:
        for k in keys:
            if k in gone:
                raise no_value(type(f).__name__, k)


def _lag(value) -> float:
    try:
        lag = float(value)
    except (TypeError, ValueError):
        raise InputError(f"smootherLag: expected a number of seconds, got {type(value).__name__}") from None
    if not (np.isfinite(lag) and lag >= 0):
        raise InputError(f"smootherLag must be finite and >= 0, got {value}")
    return lag


def _stamps(timestamps) -> dict:
    if timestamps is None:
        return {}
    try:
        items = list(timestamps.items())
    except AttributeError:
        raise InputError("timestamps: expected a dict (or FixedLagSmootherKeyTimestampMap) of key → time, "
                         f"got {type(timestamps).__name__}") from None
    out = {}
    for k, t in items:
        t = float(t)
        if not np.isfinite(t):
            raise InputError(f"timestamps: the time of key {key_name(int(k))} is not finite")
        out[int(k)] = t
    return out


def _typed(type_name: str):
    def typed(self, key):
        self._flush_for(key)
        return getattr(self.isam, f"calculateEstimate{type_name}")(key)
    typed.__name__ = typed.__qualname__ = f"calculateEstimate{type_name}"
    typed.__doc__ = f"The estimate of ``key``, a ``gtsam.{type_name}``."
    return typed


for _type in VALUE_TYPES:
    setattr(IncrementalFixedLagSmoother, f"calculateEstimate{_type}", _typed(_type))
