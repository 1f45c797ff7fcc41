"""lie-factors: closed-form Lie-group kernels, GTSAM factors built on them, and solvers that beat GTSAM's.

The front door (``import lie_factors as lf``)::

    pg = lf.read_g2o("intel.g2o")            # a PoseGraph: arrays, GTSAM's conventions
    result = lf.optimize(pg)                   # the default command: start, then the batch solver
    result = lf.optimize(pg, gnc="tls")        # false loop closures: result.outliers, result.rejected_by
    result = lf.optimize(graph, initial, params)   # any gtsam.NonlinearFactorGraph
    lf.write_g2o(result, "optimized.g2o")
    lf.write_trajectory(result, "optimized.tum")        # TUM or KITTI, for evo
    lf.evaluate(result, "data/groundtruth/city10000.tum")   # ATE and RPE, as evo computes them
    bad = lf.corrupt(pg, fraction=0.2, kind="group", seed=1)   # false loop closures: bad.graph, bad.planted
    result.covariances()                       # (n, d, d) marginal covariances, GTSAM's tangent order
    replay = lf.replay(pg)                     # online, through the incremental smoother
    isam = lf.Smoother()                       # gtsam.ISAM2's interface
    lf.sweep("spec.toml", "results.csv")       # many graphs, corruptions, seeds, methods on Dask

Every option of ``lie-factors posegraph`` is a keyword of the same name
(``docs/api.md``). The kernels (tangent orderings are GTSAM's, ``docs/conventions.md``):

- :mod:`lie_factors.so3` (Rot3, [ω]), :mod:`lie_factors.se3` (Pose3, [ω, v]),
  :mod:`lie_factors.se2` (Pose2, [x, y, θ]), :mod:`lie_factors.sim2`
  (Similarity2, [x, y, θ, λ]), :mod:`lie_factors.sim3` (Similarity3, [ω, u, λ]):
  hat, vee, exp, log, ad, Ad, dexp, dlog.
- :mod:`lie_factors.quaternion`, :mod:`lie_factors.dual_quaternion`: exp/log.
- :mod:`lie_factors.factors`: Between/Prior factors; :mod:`lie_factors.optimizers` and
  :mod:`lie_factors.dropin`: drop-ins for GTSAM's optimizers.

Importing the package loads neither numba nor GTSAM: its names are imported on first use.
"""

from .util.lazy import exports

__version__ = "0.1.0"

#: Public name → the submodule defining it.
_EXPORTS = {
    "read_g2o": "files", "write_g2o": "files",
    "read_trajectory": "files", "write_trajectory": "files", "trajectory_of": "files",
    "evaluate": "files", "write_covariances": "files", "read_covariances": "files",
    "Trajectory": "evaluation.trajectory", "Evaluation": "evaluation.metrics",
    "Marginals": "batch.marginals",
    "corrupt": "corruption", "write_corruption": "corruption", "Corruption": "corruption",
    "optimize": "solve", "replay": "solve",
    "sweep": "sweeps", "sweep_summary": "sweeps", "plot_sweep": "sweeps",
    "Result": "result", "ReplayResult": "result",
    "PoseGraph": "posegraph.graph",
    "Smoother": "incremental", "SmootherParams": "incremental", "IncrementalFixedLagSmoother": "incremental",
    "Events": "events",
    "factor": "expressions", "KindFactor": "expressions",
    "LieFactorsError": "errors", "InputError": "errors", "InitializationError": "errors",
    "NotPositiveDefinite": "errors", "IndeterminantLinearSystem": "errors",
}

__all__ = sorted(_EXPORTS)

__getattr__, _dir = exports(__name__, _EXPORTS)


def __dir__() -> list[str]:
    return sorted(set(__all__) | {"__version__"})
