"""What the front door returns: :class:`Result` for every batch run, :class:`ReplayResult` for a replay.

A result holds the estimate twice over, built on first use from whichever the
run produced: as arrays (``keys`` (n,), ``poses`` (n, m, m), the pose
variables in key order) and as ``gtsam.Values`` (``values``: every variable,
landmarks included, each of the type it was given).  An estimate without a pose
variable (cameras and points, say) has no ``poses``: its ``keys`` are every
variable's and ``covariances()`` is every variable's, by key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from .errors import InputError
from .kernels import registry

if TYPE_CHECKING:
    import gtsam

    from .posegraph.graph import PoseGraph

__all__ = ["Result", "ReplayResult"]


@dataclass(repr=False, eq=False)
class Result:
    """One optimization: the estimate, its errors, what it took.

    ``error`` and ``initial_error``: GTSAM's graph error ½·Σ‖whitened residual‖²
    at the estimate and at the start (Σ ρ for robust factors; under GNC,
    ``error`` is GNC's weighted cost Σ w_k·½‖R_k e_k‖²).  ``errors``: the error
    after each iteration, ``errors[0]`` the initial one (GNC: the initial error
    and the final cost).  ``iterations`` (GNC: outer iterations),
    ``converged``, ``seconds`` (the optimization: set-up and iterations, not
    reading, initializing or compiling), ``timings`` (seconds by step).

    ``outliers`` (k,) and ``rejected_by``, where rejection ran: the rejected
    edges (indices into the pose graph's edges) and the stage that rejected
    each (``gate``, ``clique``, ``gnc`` or ``final``; None for plain GNC).
    ``robust_status``, where rejection ran: ``{"status": "ok" | "uncertain", "reasons":
    [...]}``, why the verdict may be wrong (:func:`lie_factors.robust.rejection.uncertainty`;
    named apart from ``robust``, the loss of ``--robust``).
    ``init`` and ``init_seconds``: the initializer that chose the start
    (:mod:`lie_factors.initialization`), ``init_inliers_only``: whether it used
    the odometry and the prior alone.  ``backend``: ``batch``, ``dropin`` or
    ``native``; ``factors``: the size of the graph optimized.  ``pose_graph``: the graph optimized (what :func:`lie_factors.write_g2o`
    writes), None for a GTSAM graph.
    """

    error: float
    initial_error: float
    iterations: int
    converged: bool
    seconds: float
    errors: list[float] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    outliers: np.ndarray | None = None
    rejected_by: dict[int, str] | None = None
    robust_status: dict | None = None
    init: str | None = None
    init_seconds: float = 0.0
    init_inliers_only: bool | None = None
    backend: str | None = None
    factors: int = 0
    robust: str | None = None
    gnc: str | None = None
    pose_graph: "PoseGraph | None" = None
    _keys: np.ndarray | None = None
    _poses: np.ndarray | None = None
    _group: str | None = None
    _values: "gtsam.Values | None" = None
    _build_values: Callable[[], "gtsam.Values"] | None = None
    _start: Any = None
    _start_poses: np.ndarray | None = None
    _marginals_of: Callable[[], Any] | None = None  # → lie_factors.batch.marginals.Marginals
    _marginals: Any = None

    # ------------------------------------------------------------ the estimate
    @property
    def values(self) -> "gtsam.Values":
        """The estimate as ``gtsam.Values``: every variable, landmarks included."""
        if self._values is None:
            if self._build_values is not None:
                self._values = self._build_values()
            else:
                from .interop import values_from_matrices

                assert self._group is not None and self._keys is not None and self._poses is not None
                values = values_from_matrices(self._group, self._keys, self._poses)
                self._values = values if self.pose_graph is None else self.pose_graph.with_landmarks(values)
        return self._values

    @property
    def keys(self) -> np.ndarray:
        """(n,) int64: the keys of the pose variables, increasing; every variable's where the
        estimate holds no pose variable (:attr:`group` None)."""
        self._ensure_arrays()
        assert self._keys is not None
        return self._keys

    @property
    def poses(self) -> np.ndarray:
        """(n, m, m): the pose variables' matrices, in :attr:`keys` order (m = 3 for Pose2, 4 otherwise).
        :class:`~lie_factors.errors.InputError` where the estimate holds no pose variable."""
        self._ensure_arrays()
        if self._poses is None:
            raise InputError(_NO_POSES)
        return self._poses

    @property
    def group(self) -> str | None:
        """GTSAM's name of the poses' group: ``Pose2``, ``Pose3``, ``Rot3``, ``Similarity2``,
        ``Similarity3``; None where the estimate holds no pose variable."""
        self._ensure_arrays()
        return self._group

    def _ensure_arrays(self) -> None:
        if self._keys is not None and (self._poses is not None or self._group is None):
            return
        from .interop import matrices_from_values

        values = self.values
        self._group, self._keys = _pose_variables(values)
        if self._group is not None:
            self._poses = matrices_from_values(values, self._group, self._keys)

    @property
    def start_poses(self) -> np.ndarray:
        """(n, m, m): the start of the pose variables, in :attr:`keys` order (InputError, as
        :attr:`poses`, where there is none)."""
        if self._start_poses is None:
            from .interop import matrices_from_values

            if self.group is None:
                raise InputError(_NO_POSES)
            self._start_poses = matrices_from_values(self.start, self.group, self.keys)
        return self._start_poses

    @property
    def start(self) -> Any:
        """The values the optimization started from (``gtsam.Values``)."""
        if callable(self._start):
            self._start = self._start()
        return self._start

    # ------------------------------------------------------------ uncertainty
    @property
    def marginals(self) -> Any:
        """The :class:`~lie_factors.batch.marginals.Marginals` at the estimate, computed on first
        use: the graph optimized (rejected edges left out), linearized at the estimate and
        factored by the batch solver's sparse Cholesky (GTSAM's ``Marginals`` where CHOLMOD is
        not installed)."""
        if self._marginals is None:
            if self._marginals_of is None:
                raise InputError("this result does not know the graph it estimates: use "
                                 "lie_factors.Marginals(graph, result.values)")
            self._marginals = self._marginals_of()
        return self._marginals

    def covariance(self, key) -> np.ndarray:
        """(d, d): the marginal covariance of ``key``'s variable at the estimate, in its tangent
        coordinates in GTSAM's order (Pose2 [x, y, θ], Pose3 [ω, v], Similarity3 [ω, u, λ]);
        ``gtsam.Marginals(graph, values).marginalCovariance(key)``."""
        return self.marginals.marginalCovariance(key)

    def covariances(self, keys=None) -> "np.ndarray | dict[int, np.ndarray]":
        """(n, d, d): :meth:`covariance` of each of ``keys`` (default: every pose, :attr:`keys`),
        all of one dimension d.  Where the estimate holds no pose variable, the default is
        every variable's, as ``{key: (d, d)}`` in key order (a camera's d is not a point's)."""
        if keys is None and self.group is None:
            marginals = self.marginals
            return {int(k): marginals.marginalCovariance(k) for k in self.keys.tolist()}
        return self.marginals.covariances(self.keys if keys is None else keys)

    # ------------------------------------------------------------ reporting
    def to_dict(self) -> dict:
        """The run's figures as JSON types (``lie-factors posegraph --json``'s fields after the graph's)."""
        d = {"iterations": int(self.iterations), "initial_error": float(self.initial_error),
             "final_error": float(self.error), "seconds": float(self.seconds),
             "converged": bool(self.converged), "init": self.init or "file",
             "init_seconds": float(self.init_seconds)}
        if self.robust is not None:
            d["robust"] = self.robust
        if self.gnc is not None:
            d["gnc"] = self.gnc
        if self.outliers is not None:
            d["outliers"] = [int(k) for k in self.outliers]
        if self.rejected_by is not None:
            d["rejected_by"] = {str(k): v for k, v in sorted(self.rejected_by.items())}
        if self.robust_status is not None:
            d["robust_status"] = {"status": self.robust_status["status"],
                                  "reasons": list(self.robust_status["reasons"])}
        if self.init_inliers_only is not None:
            d["init_inliers_only"] = bool(self.init_inliers_only)
        return d

    def __repr__(self) -> str:
        poses = "" if self._poses is None and self._values is None and self._build_values is None else \
            f"{len(self.keys)} {self.group or 'variables, no pose'}, "
        rejected = "" if self.outliers is None else f", {len(self.outliers)} rejected"
        state = "converged" if self.converged else "not converged"
        return (f"<{type(self).__name__}: {poses}error {self.initial_error:.6g} -> {self.error:.6g}, "
                f"{self.iterations} iterations, {state}, {self.seconds:.3f} s{rejected}>")


@dataclass(repr=False, eq=False)
class ReplayResult(Result):
    """An online replay (:func:`lie_factors.replay`): :class:`Result`'s fields (``error``: the whole
    graph's error at the final estimate; ``iterations``: the updates), and

    ``updates``; ``update_seconds`` (their sum: each update and the read-back of the new
    pose's estimate), ``update_p50``, ``update_p99`` (median and 99th percentile per
    update), ``times`` (each update's seconds); ``relinearizations`` and ``reorderings``
    (the smoother's counts; None for GTSAM's ISAM2).
    """

    updates: int = 0
    update_seconds: float = 0.0
    update_p50: float = 0.0
    update_p99: float = 0.0
    times: np.ndarray | None = None
    relinearizations: int | None = None
    reorderings: int | None = None

    def to_dict(self) -> dict:
        return {"incremental": True, "updates": int(self.updates), "update_seconds": float(self.update_seconds),
                "update_p50": float(self.update_p50), "update_p99": float(self.update_p99),
                "seconds": float(self.seconds), "final_error": float(self.error),
                "relinearizations": None if self.relinearizations is None else int(self.relinearizations),
                "reorderings": None if self.reorderings is None else int(self.reorderings),
                **{k: v for k, v in Result.to_dict(self).items()
                   if k in ("gnc", "outliers", "rejected_by", "robust_status")}}

    def __repr__(self) -> str:
        return (f"<ReplayResult: {self.updates} updates in {self.update_seconds:.3f} s "
                f"(p99 {self.update_p99 * 1e3:.3f} ms), final error {self.error:.6g}>")


_NO_POSES = ("the estimate holds no Pose2, Pose3, Rot3, Similarity2 or Similarity3 variable, so it has no "
             "poses: read its variables from result.values (result.keys lists them)")


def _pose_variables(values: "gtsam.Values") -> tuple[str | None, np.ndarray]:
    """(group, keys): the group most of ``values``' group-element variables belong to (Pose3 and
    Pose2 found by GTSAM's ``allPose3s``/``allPose2s``, the others key by key), and their keys;
    (None, every key) where none belongs to a group."""
    import gtsam

    found: dict[str, list[int]] = {
        "Pose3": list(gtsam.utilities.allPose3s(values).keys()),
        "Pose2": list(gtsam.utilities.allPose2s(values).keys()),
    }
    rest = set(int(k) for k in values.keys()) - set(found["Pose3"]) - set(found["Pose2"])
    for info in registry.GROUPS.values():
        if info.gtsam in found or not rest:
            continue
        read = getattr(values, f"at{info.gtsam}")
        found[info.gtsam] = [k for k in rest if _reads(read, k)]
    found = {g: keys for g, keys in found.items() if keys}
    if not found:
        return None, np.array(sorted(int(k) for k in values.keys()), dtype=np.int64)
    group = max(found, key=lambda g: len(found[g]))
    return group, np.array(sorted(found[group]), dtype=np.int64)


def _reads(read, key: int) -> bool:
    try:
        read(key)
        return True
    except RuntimeError:
        return False
