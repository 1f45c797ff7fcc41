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

What a callback receives, then (``tests/test_optimizers_isam2.py`` counts it):

- ``ISAM2.update``, ``marginalizeLeaves``: ISAM2's linearization point, the
  same object in every callback (with the default Gauss–Newton params).
- Two GTSAM code paths evaluate factors on a C++ temporary that Python cannot
  reach, so they still copy: ``ISAM2Params.evaluateNonlinearError = True``
  (``errorBefore``/``errorAfter`` are computed on ``calculateEstimate()``, a
  temporary) and ``ISAM2DoglegParams`` (the trust-region test evaluates the
  error at the trial point ``θ ⊕ δ``, a temporary; the error at θ itself is
  on the held object). Both are off by default.
- A user's own ``gtsam.CustomFactor`` in the same graph gets the same object:
  it needs nothing, but it must treat ``values`` as read-only (it is ISAM2's
  own state, not a private copy; C++ declares it ``const``) and must not keep
  it past the callback expecting a snapshot (it is the live linearization
  point, which later updates move). GTSAM's own factors never went through
  Python.

``IncrementalFixedLagSmoother`` runs one ISAM2 (``update`` then
``marginalizeLeaves``): the same trick applies, to its ``getLinearizationPoint()``.
The internal ISAM2 that ``getISAM2()`` returns is GTSAM's own class: calling
its ``update`` directly bypasses the smoother's drop-in.

``BatchFixedLagSmoother`` has no drop-in here: its Levenberg–Marquardt loop
linearizes at its member θ (holdable), but evaluates the error of the start
and of every trial step on a local ``Values evalpoint = theta_.retract(δ)``
inside C++, which no Python object can wrap, so every error callback would
still copy the window's ``Values``. Use :mod:`lie_factors.optimizers`' batch
optimizers on the window, or ``IncrementalFixedLagSmoother``.
"""

from __future__ import annotations

import functools

import gtsam

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
    # Dogleg params that refresh evaluates factors); holding θ costs ~0.2 µs.
    return [n for n in dir(base) if n.startswith("calculate") and callable(getattr(base, n))]


class ISAM2(gtsam.ISAM2):
    """``gtsam.ISAM2`` whose factor callbacks receive ISAM2's own linearization point.

    Same constructors (``ISAM2()``, ``ISAM2(params)``, ``ISAM2(other)``),
    methods and overloads as ``gtsam.ISAM2``; ``update`` (both overloads, any
    keyword form), ``calculateEstimate*``, ``calculateBestEstimate``,
    ``getDelta`` and ``marginalizeLeaves*`` run GTSAM's code with the
    linearization point's wrapper held (module docstring). Results are GTSAM's:
    identical to ``gtsam.ISAM2`` on the same factors.
    """


_wrap(ISAM2, gtsam.ISAM2,
      ["update", "getDelta", "marginalizeLeaves", "marginalizeLeavesWithIndices",
       *_estimate_methods(gtsam.ISAM2)])


class IncrementalFixedLagSmoother(gtsam.IncrementalFixedLagSmoother):
    """``gtsam.IncrementalFixedLagSmoother`` whose factor callbacks receive its ISAM2's
    linearization point (``update``, which runs ISAM2's update and marginalizeLeaves,
    and ``calculateEstimate*``). Same constructors and methods as GTSAM's."""


_wrap(IncrementalFixedLagSmoother, gtsam.IncrementalFixedLagSmoother,
      ["update", "getDelta", *_estimate_methods(gtsam.IncrementalFixedLagSmoother)])
