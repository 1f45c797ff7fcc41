"""Drop-ins for ``gtsam.ISAM2`` and ``gtsam.IncrementalFixedLagSmoother`` whose factor
callbacks never receive a copy of the whole ``Values``.

Change the import, nothing else::

    from lie_factors.optimizers import ISAM2          # instead of gtsam.ISAM2
    isam = ISAM2(gtsam.ISAM2Params())
    isam.update(graph, initial)
    pose = isam.calculateEstimatePose3(7)

Why GTSAM's own is slow with Python factors: a ``gtsam.CustomFactor`` callback
is called from C++ with a ``const Values&``. pybind11 turns that argument into
a Python object by *copying* the whole ``Values`` (every callback, so the cost
of an update grows with the size of the graph times the number of factors
relinearized), unless a Python object already wraps that very C++ ``Values``:
then it hands over that object. ISAM2 linearizes every factor at its own
linearization point θ (the member ``theta_``, after inserting ``newTheta``:
new factors, relinearized factors, the marginalization of
``marginalizeLeaves``), and ``getLinearizationPoint()`` returns a wrapper of
that very object (a reference, kept alive with its ISAM2). These classes are
GTSAM's own classes (subclasses: same constructors, params, methods, overloads
and results), whose methods that can evaluate factors hold that wrapper while
GTSAM runs and drop it afterwards (held permanently, the wrapper and the
optimizer would keep each other alive through pybind11's ``keep_alive``, which
the garbage collector cannot see).

What a callback receives, then (``tests/optimizers/test_optimizers_isam2.py`` counts it):

- ``ISAM2.update``, ``marginalizeLeaves``: ISAM2's linearization point, the
  same object in every callback (with the default Gauss–Newton params).
- ``ISAM2Params.evaluateNonlinearError = True``: GTSAM would evaluate
  ``errorBefore``/``errorAfter`` on ``calculateEstimate()``, a C++ temporary
  (a copy per callback). The drop-in switches that flag off for the call and
  evaluates both errors itself on Values Python owns (the same factors, the
  same points; summed in another order, so they agree to rounding), and returns
  GTSAM's result with those two errors (a ``gtsam.ISAM2Result`` subclass).
- ``ISAM2DoglegParams`` still copies: the trust-region test evaluates the
  error at the trial point ``θ ⊕ δ``, a C++ temporary no Python object can
  wrap (the error at θ itself is on the held object). Gauss–Newton params
  (the default) have no such evaluation.
- A user's own ``gtsam.CustomFactor`` in the same graph gets the same object:
  it needs nothing, but it must treat ``values`` as read-only (it is ISAM2's
  own state, not a private copy; C++ declares it ``const``) and must not keep
  it past the callback expecting a snapshot (it is the live linearization
  point, which later updates move). GTSAM's own factors never went through
  Python.

``IncrementalFixedLagSmoother`` runs one ISAM2 (``update`` then
``marginalizeLeaves``): the same trick applies, to its ``getLinearizationPoint()``.
The internal ISAM2 that ``getISAM2()`` returns is GTSAM's own class: calling
its ``update`` directly bypasses the smoother's drop-in, and with
``evaluateNonlinearError`` that ISAM2 evaluates its two errors on copies.

``BatchFixedLagSmoother`` has no drop-in here: its Levenberg–Marquardt loop
linearizes at its member θ (holdable), but evaluates the error of the start
and of every trial step on a local ``Values evalpoint = theta_.retract(δ)``
inside C++, which no Python object can wrap, so every error callback would
still copy the window's ``Values``. Use :mod:`lie_factors.optimizers`' batch
optimizers on the window, or ``IncrementalFixedLagSmoother``.
"""

from __future__ import annotations

import functools

from gtsam import gtsam  # the compiled extension: GTSAM's own classes, whatever is assigned into the package

__all__ = ["ISAM2", "IncrementalFixedLagSmoother"]


def _holding_theta(method):
    """Wrap a GTSAM method so that a wrapper of the linearization point is alive while it runs.

    pybind11 hands a callback's ``const Values&`` over as an existing Python
    object when one wraps that address; ``theta`` is such an object for
    ``getLinearizationPoint()``'s ``Values``. It is a local: it dies when the
    call returns or raises (``del`` also clears it from a traceback's frame).
    """

    @functools.wraps(method)
    def call(self, *args, **kwargs):
        theta = self.getLinearizationPoint()
        try:
            return method(self, *args, **kwargs)
        finally:
            del theta

    return call


def _wrap(cls, base, names):
    for name in names:
        setattr(cls, name, _holding_theta(getattr(base, name)))
    return cls


def _estimate_methods(base) -> list[str]:
    # calculateEstimate reads the delta, which ISAM2 may refresh first (with
    # Dogleg params that refresh evaluates factors); holding θ costs little.
    return [n for n in dir(base) if n.startswith("calculate") and callable(getattr(base, n))]


#: ISAM2Result's getters other than the two errors (a :class:`_Result` forwards them).
_RESULT_GETTERS = [n for n in dir(gtsam.ISAM2Result)
                   if n.startswith("get") and n not in ("getErrorBefore", "getErrorAfter")]

_UPDATE_ARGS = ("newFactors", "newTheta", "removeFactorIndices", "constrainedKeys", "noRelinKeys",
                "extraReelimKeys", "force_relinearize")


class _Result(gtsam.ISAM2Result):
    """GTSAM's ISAM2Result of an update, with errorBefore/errorAfter evaluated from Python
    (``evaluateNonlinearError``): every getter answers as the wrapped result does."""

    def __init__(self, result: gtsam.ISAM2Result, before: float, after: float):
        super().__init__()
        self._result, self._before, self._after = result, before, after

    def getErrorBefore(self) -> float:
        return self._before

    def getErrorAfter(self) -> float:
        return self._after

    def print(self, str: str = "") -> None:  # noqa: A002 (GTSAM's argument name)
        self._result.print(str)
        print(f"errorBefore: {self._before}\nerrorAfter: {self._after}")


def _forward(name):
    def get(self, *args, **kwargs):
        return getattr(self._result, name)(*args, **kwargs)

    get.__name__ = name
    return get


for _name in _RESULT_GETTERS:
    setattr(_Result, _name, _forward(_name))


def _update_arguments(args, kwargs):
    """(newFactors, newTheta, removeFactorIndices, forceFullSolve) of either update overload."""
    if len(args) == 3 and isinstance(args[2], gtsam.ISAM2UpdateParams) or "updateParams" in kwargs:
        bound = dict(zip(("newFactors", "newTheta", "updateParams"), args), **kwargs)
        up = bound["updateParams"]
        return bound["newFactors"], bound["newTheta"], list(up.removeFactorIndices), bool(up.forceFullSolve)
    bound = dict(zip(_UPDATE_ARGS, args), **kwargs)
    return (bound.get("newFactors", gtsam.NonlinearFactorGraph()), bound.get("newTheta", gtsam.Values()),
            list(bound.get("removeFactorIndices", [])), False)


class ISAM2(gtsam.ISAM2):
    """``gtsam.ISAM2`` whose factor callbacks receive ISAM2's own linearization point.

    Same constructors (``ISAM2()``, ``ISAM2(params)``, ``ISAM2(other)``),
    methods and overloads as ``gtsam.ISAM2``; ``update`` (both overloads, any
    keyword form), ``calculateEstimate*``, ``calculateBestEstimate``,
    ``getDelta`` and ``marginalizeLeaves*`` run GTSAM's code with the
    linearization point's wrapper held (module docstring). Results are GTSAM's:
    identical to ``gtsam.ISAM2`` on the same factors.
    """


def _update(self, *args, **kwargs):
    """GTSAM's update; with ``evaluateNonlinearError`` the two errors are evaluated here on
    Values Python owns (GTSAM would evaluate them on a C++ temporary: a copy per callback)."""
    params = self.params()  # a reference to ISAM2's own params
    if not params.evaluateNonlinearError:
        return gtsam.ISAM2.update(self, *args, **kwargs)
    new_factors, new_theta, removed, full = _update_arguments(args, kwargs)
    # GTSAM's errorBefore: the factors after this update's additions and removals, at the
    # current estimate with the new variables at their initial values.
    estimate = self.calculateBestEstimate() if full else self.calculateEstimate()
    estimate.insert(new_theta)
    factors = self.getFactorsUnsafe()
    before = factors.error(estimate) + new_factors.error(estimate)
    for i in set(removed):
        if 0 <= i < factors.size() and factors.at(i) is not None:
            before -= factors.at(i).error(estimate)
    del estimate
    params.evaluateNonlinearError = False
    try:
        result = gtsam.ISAM2.update(self, *args, **kwargs)
    finally:
        params.evaluateNonlinearError = True
    estimate = self.calculateEstimate()
    after = self.getFactorsUnsafe().error(estimate)
    return _Result(result, float(before), float(after))


ISAM2.update = _update
_wrap(ISAM2, ISAM2, ["update"])
_wrap(ISAM2, gtsam.ISAM2,
      ["getDelta", "marginalizeLeaves", "marginalizeLeavesWithIndices",
       *_estimate_methods(gtsam.ISAM2)])


class IncrementalFixedLagSmoother(gtsam.IncrementalFixedLagSmoother):
    """``gtsam.IncrementalFixedLagSmoother`` whose factor callbacks receive its ISAM2's
    linearization point (``update``, which runs ISAM2's update and marginalizeLeaves,
    and ``calculateEstimate*``). Same constructors and methods as GTSAM's."""


_wrap(IncrementalFixedLagSmoother, gtsam.IncrementalFixedLagSmoother,
      ["update", "getDelta", *_estimate_methods(gtsam.IncrementalFixedLagSmoother)])
