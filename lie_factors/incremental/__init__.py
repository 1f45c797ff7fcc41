"""Online smoothing: an incremental block Cholesky factor and a smoother with ISAM2's interface.

* :mod:`~lie_factors.incremental.elimination`: the compiled kernels (marking the
  columns an update changes, their re-elimination on top of the cached update
  matrices of the subtrees below, wildfire back-substitution, marginals);
* :mod:`~lie_factors.incremental.cholesky`: :class:`BlockFactor`, the factor of a
  growing problem of whitened Jacobian blocks, updated all or nothing;
* :mod:`~lie_factors.incremental.smoother`: :class:`Smoother`, ISAM2's interface
  (``update``, ``calculateEstimate``, ``marginalCovariance``, …) on GTSAM graphs
  or on arrays.

``import lie_factors.incremental`` alone loads neither numba nor GTSAM: its names
are imported on first use.
"""

from ..util.lazy import exports

_EXPORTS = {
    "BlockFactor": "cholesky", "UpdateStats": "cholesky",
    "FactorArrays": "smoother", "Smoother": "smoother", "SmootherError": "smoother", "SmootherParams": "smoother",
    "UpdateResult": "smoother",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = exports(__name__, _EXPORTS)
