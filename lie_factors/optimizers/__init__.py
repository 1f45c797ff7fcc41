"""Drop-ins for GTSAM's optimizers and for GTSAM's functions that look for its own factor classes.

Same names, arguments and results as GTSAM's; they run lie_factors' factors.
"""

from .compat import InitializePose3, lago, readG2o, writeG2o  # noqa: F401
