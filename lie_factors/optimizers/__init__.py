"""Drop-ins for GTSAM's optimizers whose factor callbacks never receive a copied ``Values``
(see each module's docstring)."""

from .isam2 import ISAM2, IncrementalFixedLagSmoother
