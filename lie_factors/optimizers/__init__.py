"""Drop-ins for GTSAM's optimizers under which CustomFactor callbacks never receive a copy of ``Values``,
and for GTSAM's functions that look for its own factor classes.

Why the optimizers exist: a ``gtsam.CustomFactor`` callback is called from C++ with a
``const Values&``.  pybind11 turns that reference into a Python object by
*copying the whole Values* into a new wrapper, unless a Python object already
wraps that very C++ ``Values``, in which case it hands over that object.
Inside GTSAM's own optimizers the linearization point and every trial point
are C++-only objects, so every callback of every factor copies the whole
graph's values: the cost grows with the square of the graph.

The drop-ins run GTSAM's algorithms step for step, but keep every ``Values``
they linearize or evaluate in a Python object they hold, so that each
callback receives that object.  GTSAM still linearizes
(``graph.linearize``), evaluates (``graph.error``), retracts and eliminates;
only the loop is in Python.  Changing the import is the whole change::

    from lie_factors.optimizers import LevenbergMarquardtOptimizer
    result = LevenbergMarquardtOptimizer(graph, initial, params).optimize()

Modules: :mod:`.nonlinear` (Levenberg–Marquardt, Gauss–Newton, Dogleg);
:mod:`.isam2` (ISAM2, IncrementalFixedLagSmoother: GTSAM's own, holding the
linearization point while they update);
:mod:`.compat` (``writeG2o``, ``readG2o``, ``InitializePose3``, ``lago``: GTSAM's
functions and classes that pick factors by their C++ class, made to accept ours,
and its file readers, made to return ours).

However a user swaps them in (the import line, ``import lie_factors.dropin as
gtsam``, or assignment into GTSAM's namespace, ``gtsam.ISAM2 = ISAM2``, for a code
base whose modules each ``import gtsam``), they behave the same:

* they take GTSAM's classes and functions from its compiled extension
  (``gtsam.gtsam``, which ``gtsam/__init__.py`` re-exports), never from the
  package's namespace, so a drop-in assigned there is never what it calls
  (``ISAM2.update`` calling itself), whenever lie_factors is imported;
* GTSAM's Python utilities accept them: ``gtsam.utils.logging_optimizer`` looks up
  an optimizer class's params class in a dict keyed by GTSAM's classes, to which
  ours are added with theirs;
* they accept whatever GTSAM's optimizers accept: where their loop cannot run
  (a linear solver or an ordering the wrapper does not expose), the constructor
  returns GTSAM's own optimizer (:func:`.nonlinear.runs_in_python`).
"""

from . import compat
from .compat import InitializePose3, lago, readG2o, writeG2o  # noqa: F401

# compat's other replacements of GTSAM's names, which depend on the GTSAM version
# (fastSync*, ShonanAveraging2/3, load2D, parse3DFactors, ...).
globals().update({_name: getattr(compat, _name) for _name in compat.GTSAM_NAMES})
from .nonlinear import LevenbergMarquardtOptimizer, GaussNewtonOptimizer, DoglegOptimizer
from .isam2 import ISAM2, IncrementalFixedLagSmoother


def _fit_gtsam_utilities() -> None:
    """Add our optimizer classes to ``gtsam.utils.logging_optimizer``'s params lookup.

    ``optimize_using(OptimizerClass, hook, graph, initial)`` without params looks up
    ``OPTIMIZER_PARAMS_MAP[OptimizerClass]``, a dict keyed by GTSAM's classes, which
    raises KeyError for ours. GTSAM versions without that utility need nothing.
    """
    try:
        from gtsam.utils import logging_optimizer
    except ImportError:
        return
    table = getattr(logging_optimizer, "OPTIMIZER_PARAMS_MAP", None)
    if isinstance(table, dict):
        for cls in (LevenbergMarquardtOptimizer, GaussNewtonOptimizer, DoglegOptimizer):
            table.setdefault(cls, cls._params_type)


_fit_gtsam_utilities()
