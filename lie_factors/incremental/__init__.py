"""Online smoothing: an incremental block Cholesky factor and a smoother with ISAM2's interface.

The block factor:

* :mod:`~lie_factors.incremental.cholesky`: :class:`BlockFactor`, the factor of a
  growing problem of whitened Jacobian blocks, updated all or nothing;
* :mod:`~lie_factors.incremental.structures`: its state, namedtuples of arrays
  the compiled kernels take whole;
* the kernels: :mod:`~lie_factors.incremental.storage` (variables, factors,
  pool compaction), :mod:`~lie_factors.incremental.marking` (the columns an
  update changes, the graph they are ordered on),
  :mod:`~lie_factors.incremental.elimination` (their re-elimination: the
  :mod:`~lie_factors.incremental.symbolic` pass, then the numeric one on dense
  :mod:`~lie_factors.incremental.fronts`), :mod:`~lie_factors.incremental.substitution`
  (wildfire back-substitution, marginal covariances).

The smoother:

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
