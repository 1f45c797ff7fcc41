"""``gtsam`` with lie_factors' factors: ``import lie_factors.dropin as gtsam`` is the whole change.

Everything ``gtsam`` has is here under the same name, except:

* ``BetweenFactor{Rot3,Pose2,Pose3,Similarity2,Similarity3}`` and
  ``PriorFactor{...}``: :mod:`lie_factors.factors`' classes (same arguments);
* GTSAM's functions and classes that pick factors by their C++ class
  (``writeG2o``, ``save2D``, ``InitializePose3``, ``lago``, ``fastSync*``,
  ``ShonanAveraging2``/``3``) and its file readers (``readG2o``, ``load2D``,
  ``load3D``, ``parse2DFactors``, ``parse3DFactors``):
  :mod:`lie_factors.optimizers.compat`'s, which accept those factors (the
  readers return them);
* GTSAM's optimizers, where :mod:`lie_factors.optimizers` has a drop-in for
  them (:data:`REPLACED` lists every replaced name and where it comes from).

Assigning these names into ``gtsam``'s own namespace (``for name in REPLACED:
setattr(gtsam, name, getattr(lie_factors.dropin, name))``) swaps them into a
code base whose modules each ``import gtsam``: the drop-ins hold GTSAM's own
classes (see :mod:`lie_factors.optimizers`), so they never call themselves.

Submodules stay reachable as attributes (``gtsam.noiseModel``,
``gtsam.symbol_shorthand``, ``gtsam.utils``, ``gtsam.imuBias``,
``gtsam.utilities``, ...): they are GTSAM's own.  ``from gtsam.X import Y``
and ``import gtsam.X as Y`` lines need no change (nothing in GTSAM's
submodules is replaced; ``lie_factors.dropin`` is a module, not a package);
``import gtsam`` and ``from gtsam import ...`` lines become ``import
lie_factors.dropin as gtsam`` and ``from lie_factors.dropin import ...``.

Values, noise models, geometry and GTSAM's other factors are GTSAM's objects,
so a graph may mix our factors with GTSAM's and a user's own CustomFactors.
"""

import importlib as _importlib

import gtsam as _gtsam
from gtsam import *  # noqa: F401,F403  (gtsam's whole namespace, replaced names below)

from . import factors as _factors
from . import optimizers as _optimizers

# Submodules are looked up on gtsam at each use (module __getattr__ below), not copied: importing
# the Python module ``gtsam.symbol_shorthand`` rebinds gtsam's attribute from the compiled
# submodule of that name, and a copy would go stale.
for _name in [_n for _n, _v in globals().items() if isinstance(_v, type(_gtsam)) and not _n.startswith("_")]:
    del globals()[_name]

#: replaced name → the module its object comes from
REPLACED: dict[str, str] = {}


def _replace(name: str, module) -> None:
    globals()[name] = getattr(module, name)
    REPLACED[name] = module.__name__


for _name in _factors.__all__:
    if _name.startswith(("BetweenFactor", "PriorFactor")):
        _replace(_name, _factors)

# The compat functions, and whatever optimizer drop-ins lie_factors.optimizers
# exports (LevenbergMarquardtOptimizer, ISAM2, ...), where GTSAM has the name.
for _name in dir(_optimizers):
    if not _name.startswith("_") and hasattr(_gtsam, _name) and not isinstance(
            getattr(_optimizers, _name), type(_gtsam)):
        _replace(_name, _optimizers)

del _name

#: ``from lie_factors.dropin import *`` gives what ``from gtsam import *`` gives (with ours in place).
__all__ = [_n for _n in dir(_gtsam) if not _n.startswith("_")]


def __getattr__(name: str):
    """Everything else from gtsam, submodules included (imported on first use, as ``gtsam.X`` is)."""
    if name.startswith("__") and name.endswith("__"):
        # Module machinery is this module's own: forwarding gtsam's __path__
        # would make ``import lie_factors.dropin.utils`` load a second copy of
        # gtsam.utils under another name.
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    try:
        return getattr(_gtsam, name)
    except AttributeError:
        pass
    try:
        return _importlib.import_module(f"gtsam.{name}")
    except ModuleNotFoundError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None


def __dir__():
    return sorted(set(globals()) | set(dir(_gtsam)))
