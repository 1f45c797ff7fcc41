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
  (wildfire back-substitution, marginal covariances); :mod:`~lie_factors.incremental.factor_reading`
  (what the factor answers: δ, Λ⁻¹'s blocks, the conditionals' error).

The smoother:

* :mod:`~lie_factors.incremental.smoother`: :class:`Smoother`, ISAM2's interface
  (``update``, ``calculateEstimate``, ``marginalCovariance``, …) on GTSAM graphs
  or on arrays: the update path, relinearization, the estimate;
* :mod:`~lie_factors.incremental.params`: :class:`SmootherParams` (ISAM2's, read
  from a ``gtsam.ISAM2Params`` too) and :class:`UpdateResult`;
* :mod:`~lie_factors.incremental.factor_arrays`: the smoother's variables and
  factors as arrays, by group and kind (:class:`FactorArrays`: a replay's, set
  up once);
* :mod:`~lie_factors.incremental.gtsam_objects`: GTSAM's factor graphs and
  Values read into those arrays, the factors GTSAM keeps linearized, GTSAM's
  objects made back;
* :mod:`~lie_factors.incremental.undo`: what an update changed, put back if it fails;
* :mod:`~lie_factors.incremental.update_args`, :mod:`~lie_factors.incremental.removal`:
  ISAM2's other update arguments, factors and variables taken out;
  :mod:`~lie_factors.incremental.marginalize`: ``marginalizeLeaves``;
  :mod:`~lie_factors.incremental.queries`: what the smoother answers (estimates,
  marginals, errors); :mod:`~lie_factors.incremental.reports`: ``UpdateResult``'s
  fields; :mod:`~lie_factors.incremental.dogleg`: ISAM2's Dogleg steps;
* :mod:`~lie_factors.incremental.fixed_lag`: :class:`IncrementalFixedLagSmoother`,
  GTSAM's fixed-lag smoother on :class:`Smoother`.

The replay: :mod:`~lie_factors.incremental.replay`, the online replay of a pose
graph (``from lie_factors.incremental.replay import replay``: the function is
not one of the package's names, which the submodule of the same name would
replace once imported).

``import lie_factors.incremental`` alone loads neither numba nor GTSAM: its names
are imported on first use.
"""

from ..util.lazy import exports

_EXPORTS = {
    "BlockFactor": "cholesky", "UpdateStats": "cholesky",
    "FactorArrays": "factor_arrays", "Smoother": "smoother", "SmootherParams": "params",
    "UpdateResult": "params", "IncrementalFixedLagSmoother": "fixed_lag", "JointMarginal": "queries",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = exports(__name__, _EXPORTS)
