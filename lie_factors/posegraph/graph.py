"""A pose graph as arrays: the one representation the g2o reader, the initializers, the batch
problem and the command line share.

A GTSAM graph is made from it only where one is needed (:meth:`PoseGraph.factor_graph`:
GTSAM's optimizers and initializers, writing a g2o file), and any GTSAM graph of
Between/Prior factors on Pose2, Pose3 or Similarity3 becomes one
(:meth:`PoseGraph.from_gtsam`).  Numpy only (GTSAM is imported by those two
methods): the numba-free paths (``--backend native``, the input check) use it.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..kernels import registry
from ..kernels import validate as _validate
from . import topology

__all__ = ["PRIOR_VARIANCES", "GROUPS", "is_loop_closure", "prior_information", "PoseGraph"]

if TYPE_CHECKING:
    import gtsam

    from .landmarks import Landmarks

#: Variances of the prior GTSAM's examples put on the first pose (Pose2SLAMExample_g2o.py,
#: Pose3SLAMExample_g2o.py; lago's own), in each group's tangent order.  Similarity3: Pose3's,
#: and the log-scale as tight as the rotation.
PRIOR_VARIANCES = {
    "Pose2": np.array([1e-6, 1e-6, 1e-8]),
    "Pose3": np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4]),
    "Similarity3": np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4, 1e-6]),
}

#: The groups a pose graph can hold (GTSAM type names).
GROUPS = tuple(PRIOR_VARIANCES)

#: No priors given: ``__post_init__`` puts empty arrays of the group's shapes in their place.
_NO_PRIOR = np.zeros(0)


def is_loop_closure(key1, key2):
    """Whether an edge between poses ``key1`` and ``key2`` is a loop closure: |key1 − key2| ≠ 1
    (the consecutive ones are odometry).  Scalars or arrays.

    The one definition of a loop closure: robust losses go on the loop closures,
    GNC takes the odometry and the priors as known inliers, and the outlier
    benchmark plants false ones.
    """
    return np.abs(np.asarray(key1, dtype=np.int64) - np.asarray(key2, dtype=np.int64)) != 1


def prior_information(group: str) -> np.ndarray:
    """(n, n): the information diag(1/σ²) of :data:`PRIOR_VARIANCES` for ``group``."""
    return np.diag(1.0 / PRIOR_VARIANCES[group])


@dataclass
class PoseGraph:
    """A pose graph as arrays, in GTSAM's conventions (what ``readG2o`` would build from a file).

    ``group``: Pose2, Pose3 or Similarity3 (m×m matrices, n-dimensional
    tangent: 3×3/3, 4×4/6, 4×4/7).  ``keys`` (P,) int64: every pose key,
    sorted.  ``edge_keys`` (E, 2) int64, ``measured`` (E, m, m) and
    ``information`` (E, n, n): the between factors, measured Z ≈ X₁⁻¹·X₂, error
    Log(Z⁻¹·X₁⁻¹·X₂), information in GTSAM's tangent order (the noise model is
    ``noiseModel.Gaussian.Information(information)``).  ``vertices`` (P, m, m):
    the initial poses the source gives (a file's vertices) in key order, or None.
    ``lines`` (E,): where each edge came from — its line in the file
    (:func:`lie_factors.g2o.read_arrays`) or its factor index in the graph
    (:meth:`from_gtsam`) — or None.

    ``prior_keys`` (Q,), ``prior_measured`` (Q, m, m), ``prior_information``
    (Q, n, n): prior factors, error Log(P⁻¹·X); none by default.  The factor
    order of every graph made from a PoseGraph is the edges, then the priors,
    then the landmark measurements.

    ``landmarks``: the file's landmarks (:class:`~lie_factors.posegraph.landmarks.Landmarks`,
    GTSAM's factors), or None.  ``name`` and ``path``: the file it was read from, if any.
    """

    group: str
    keys: np.ndarray
    edge_keys: np.ndarray
    measured: np.ndarray
    information: np.ndarray
    vertices: np.ndarray | None
    lines: np.ndarray | None
    prior_keys: np.ndarray = dataclasses.field(default_factory=lambda: _NO_PRIOR)
    prior_measured: np.ndarray = dataclasses.field(default_factory=lambda: _NO_PRIOR)
    prior_information: np.ndarray = dataclasses.field(default_factory=lambda: _NO_PRIOR)
    landmarks: "Landmarks | None" = None
    name: str = ""
    path: str = ""

    def __post_init__(self):
        if self.group not in GROUPS:
            raise ValueError(f"group: a pose graph holds {', '.join(GROUPS)}, got {self.group!r}")
        g = registry.group(self.group)
        if self.prior_keys is None or self.prior_keys is _NO_PRIOR:
            self.prior_keys = np.zeros(0, dtype=np.int64)
            self.prior_measured = np.zeros((0, g.mat, g.mat))
            self.prior_information = np.zeros((0, g.dim, g.dim))

    # ------------------------------------------------------------------ facts
    @property
    def info(self) -> registry.GroupInfo:
        """The group's facts (tangent dimension ``dim``, matrix size ``mat``, ...)."""
        return registry.group(self.group)

    @property
    def is3d(self) -> bool:
        return self.group != "Pose2"

    @property
    def pose_count(self) -> int:
        return len(self.keys)

    @property
    def edge_count(self) -> int:
        return len(self.edge_keys)

    @property
    def landmark_count(self) -> int:
        """Landmark variables (0 without landmarks)."""
        return 0 if self.landmarks is None else self.landmarks.count

    @property
    def observation_count(self) -> int:
        """Landmark measurements (0 without landmarks)."""
        return 0 if self.landmarks is None else int(self.landmarks.factors.size())

    def describe(self) -> str:
        """``"name: SE(3), N poses, M edges[, K landmarks, L landmark measurements]"``."""
        lms = (f", {self.landmark_count} landmarks, {self.observation_count} landmark measurements"
               if self.observation_count else "")
        return f"{self.name or 'pose graph'}: {self.info.label}, {self.pose_count} poses, {self.edge_count} edges{lms}"

    def loop_closures(self) -> np.ndarray:
        """Indices of the edges that are loop closures (:func:`is_loop_closure`)."""
        k = np.asarray(self.edge_keys, dtype=np.int64).reshape(-1, 2)
        return np.flatnonzero(is_loop_closure(k[:, 0], k[:, 1])).astype(np.int64)

    def index(self, keys) -> np.ndarray:
        """Positions of ``keys`` in :attr:`keys`; ``ValueError`` naming the first key not there."""
        keys = np.asarray(keys, dtype=np.int64)
        pos = np.searchsorted(self.keys, keys)
        if len(self.keys):
            bad = (pos >= len(self.keys)) | (self.keys[np.minimum(pos, len(self.keys) - 1)] != keys)
        else:
            bad = np.ones(keys.shape, dtype=bool)
        if np.any(bad):
            raise ValueError(f"key {int(keys[bad][0])} is not among the pose keys")
        return pos

    # ----------------------------------------------------------- new graphs
    def with_prior(self, key: int, element: np.ndarray, information: np.ndarray) -> "PoseGraph":
        """This graph with one more prior: on ``key``, element (m, m), information (n, n)."""
        return dataclasses.replace(
            self, prior_keys=np.append(self.prior_keys, np.int64(key)),
            prior_measured=np.concatenate([self.prior_measured, np.asarray(element, dtype=np.float64)[None]]),
            prior_information=np.concatenate([self.prior_information,
                                              np.asarray(information, dtype=np.float64)[None]]))

    def anchored(self) -> "PoseGraph":
        """This graph, or, without any prior, with one at the identity on the smallest key.

        GTSAM's initializers need a prior (else the orientation system is
        singular); its examples put this one (:data:`PRIOR_VARIANCES`).
        """
        if len(self.prior_keys):
            return self
        return self.with_prior(int(self.keys[0]), np.eye(self.info.mat), prior_information(self.group))

    def with_first_prior(self) -> "PoseGraph":
        """This graph, or, without any prior, with the prior a run puts on its first pose.

        The prior pins the smallest key at its vertex (the identity without
        vertices), fixing the gauge, with the variances of GTSAM's examples
        (:data:`PRIOR_VARIANCES`).
        """
        if len(self.prior_keys):
            return self
        first = np.eye(self.info.mat) if self.vertices is None else self.vertices[0]
        return self.with_prior(int(self.keys[0]), first, prior_information(self.group))

    def tree_poses(self, root_key: int, root_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(poses (P, m, m), reached (P,)): ``root_pose`` on ``root_key``, every pose the edges reach
        from it composed along a breadth-first spanning tree (:func:`topology.bfs_tree`: each pose
        through the fewest measurements); the others are left as the identity.

        Edge i→j with measurement Z means X_j = X_i·Z, hence X_i = X_j·Z⁻¹.
        """
        P, m = len(self.keys), self.info.mat
        ij = self.index(self.edge_keys.reshape(-1)).reshape(-1, 2)
        root = int(self.index([root_key])[0])
        parent, edge = topology.bfs_tree(P, ij[:, 0], ij[:, 1], root)
        step = np.broadcast_to(np.eye(m), (P, m, m)).copy()
        child = np.flatnonzero(edge >= 0)
        e = edge[child]
        forward = ij[e, 0] == parent[child]
        step[child] = np.where(forward[:, None, None], self.measured[e], np.linalg.inv(self.measured[e]))
        rel, on_tree = topology.along_tree(parent, step, root, np.matmul)
        poses = np.broadcast_to(np.eye(m), (P, m, m)).copy()
        poses[on_tree] = np.asarray(root_pose, dtype=np.float64) @ rel[on_tree]
        poses[root] = root_pose
        return poses, on_tree

    @functools.cached_property
    def start_poses(self) -> np.ndarray:
        """(P, m, m): the vertices, or, without any, the edges composed along a spanning tree from
        the identity on the first pose (a pose they do not reach stays at the identity)."""
        if self.vertices is not None:
            return self.vertices
        return self.tree_poses(int(self.keys[0]), np.eye(self.info.mat))[0]

    @functools.cached_property
    def initial(self) -> "gtsam.Values":
        """:attr:`start_poses` and the landmarks (:meth:`~lie_factors.posegraph.landmarks.Landmarks.placed`)
        as ``gtsam.Values``."""
        from ..interop import values_from_matrices

        return self.with_landmarks(values_from_matrices(self.group, self.keys, self.start_poses))

    def with_landmarks(self, poses: "gtsam.Values") -> "gtsam.Values":
        """``poses`` and the landmarks placed from them (``poses`` itself without landmarks)."""
        return poses if self.landmarks is None else self.landmarks.placed(poses)

    def with_edges(self, edges) -> "PoseGraph":
        """The same poses and priors with only the edges ``edges`` (indices or a mask)."""
        e = np.arange(len(self.edge_keys))[edges]
        return dataclasses.replace(self, edge_keys=self.edge_keys[e], measured=self.measured[e],
                                   information=self.information[e],
                                   lines=None if self.lines is None else self.lines[e])

    def renumbered(self) -> "PoseGraph":
        """The same graph with keys 0 … P−1 (pose k is the k-th smallest key)."""
        return dataclasses.replace(self, keys=np.arange(len(self.keys), dtype=np.int64),
                                   edge_keys=self.index(self.edge_keys.reshape(-1)).reshape(-1, 2),
                                   prior_keys=self.index(self.prior_keys))

    # ------------------------------------------------------------- checking
    def validate(self) -> "PoseGraph":
        """Raise ``ValueError`` unless the arrays are a well-formed pose graph; returns self.

        Shapes; keys sorted and distinct; every factor's keys among them; no edge
        from a pose to itself; measured, prior and vertex elements of the group
        (rotation block orthonormal, last row); information symmetric positive
        definite.
        """
        g = self.info
        keys = np.asarray(self.keys)
        if keys.ndim != 1 or not len(keys):
            raise ValueError(f"keys: expected a non-empty (P,) array, got shape {keys.shape}")
        if np.any(np.diff(keys) <= 0):
            raise ValueError("keys: expected increasing (sorted, distinct) keys")
        E = len(self.edge_keys)
        if np.shape(self.edge_keys) != (E, 2):
            raise ValueError(f"edge_keys: expected shape (E, 2), got {np.shape(self.edge_keys)}")
        self.index(np.asarray(self.edge_keys).reshape(-1))
        self.index(self.prior_keys)
        if E and np.any(self.edge_keys[:, 0] == self.edge_keys[:, 1]):
            k = int(np.argmax(self.edge_keys[:, 0] == self.edge_keys[:, 1]))
            raise ValueError(f"edge_keys: edge {k} joins pose {int(self.edge_keys[k, 0])} to itself")
        Q = len(self.prior_keys)
        _elements(self.measured, E, g, "measured")
        _elements(self.prior_measured, Q, g, "prior_measured")
        if self.vertices is not None:
            _elements(self.vertices, len(keys), g, "vertices")
        _information(self.information, E, g.dim, "information")
        _information(self.prior_information, Q, g.dim, "prior_information")
        return self

    # ----------------------------------------------------------------- GTSAM
    @classmethod
    def from_gtsam(cls, graph, group: str | None = None, keys=None) -> "PoseGraph":
        """The pose graph of a ``gtsam.NonlinearFactorGraph`` of Between/Prior factors.

        Factors on Pose2, Pose3 or Similarity3, GTSAM's own or
        :mod:`lie_factors.factors`' (anything with two keys and ``measured()``,
        or one key and ``prior()``); the information of a noise model is RᵀR of
        its square root R, of a robust model's Gaussian part.  ``lines``: each
        edge's factor index.  ``group``/``keys``: the group and the pose keys when
        the graph may have no edge (keys must cover every factor's).  Raises
        :class:`~lie_factors.errors.InputError` (one line) for any other
        factor, a mix of groups, a noise model without finite information, or no
        between factor where ``group`` is not given.
        """
        import gtsam

        kinds = [(getattr(gtsam, name), name) for name in GROUPS]
        edges: list[tuple] = []
        priors: list[tuple] = []
        seen: set[str] = set()
        for k in range(graph.size()):
            f = graph.at(k)
            if f is None:  # a removed factor leaves a null slot
                continue
            fkeys = list(f.keys())
            value = (f.measured() if len(fkeys) == 2 and hasattr(f, "measured") else
                     f.prior() if len(fkeys) == 1 and hasattr(f, "prior") else None)
            kind = next((name for cls, name in kinds if isinstance(value, cls)), None)
            if kind is None or value is None:
                raise InputError(f"factor {k} ({type(f).__name__}) is not a Between or Prior factor on "
                                     "Pose2/Pose3/Similarity3; a pose graph has no other")
            model = f.noiseModel()
            if isinstance(model, gtsam.noiseModel.Robust):
                model = model.noise()  # least squares on the Gaussian part
            R = model.R()
            if not np.all(np.isfinite(R)):
                raise InputError(f"factor {k}: its noise model has no finite information (constrained?)")
            seen.add(kind)
            (edges if len(fkeys) == 2 else priors).append((k, fkeys, value.matrix(), R.T @ R))
        if len(seen) > 1:
            raise InputError("the graph mixes " + " and ".join(sorted(seen)) + " factors")
        if group is None:
            if not edges:
                raise InputError("the graph has no between factors on Pose2/Pose3/Similarity3")
            group = seen.pop()
        elif seen and seen != {group}:
            raise InputError(f"the graph has {seen.pop()} factors, not {group}")
        g = registry.group(group)
        used = [key for _, fkeys, _, _ in edges + priors for key in fkeys]
        all_keys = np.unique(np.asarray(used + ([] if keys is None else list(keys)), dtype=np.int64))
        if keys is not None and len(all_keys) != len(np.unique(np.asarray(keys, dtype=np.int64))):
            raise InputError("the graph has factors on keys not among the pose keys given")

        def stack(items, nkeys):
            if not items:
                return (np.zeros(0, dtype=np.int64), np.zeros((0, nkeys), dtype=np.int64),
                        np.zeros((0, g.mat, g.mat)), np.zeros((0, g.dim, g.dim)))
            slots, fk, M, info = zip(*items)
            return (np.array(slots, dtype=np.int64), np.array(fk, dtype=np.int64),
                    np.array(M, dtype=np.float64), np.array(info, dtype=np.float64))

        slots, edge_keys, measured, information = stack(edges, 2)
        _, pkeys, pmeasured, pinfo = stack(priors, 1)
        return cls(group, all_keys, edge_keys.reshape(-1, 2), measured, information, None, slots,
                   pkeys.reshape(-1), pmeasured, pinfo)

    def factor_graph(self, factors=None, robust=None, robust_all: bool = False):
        """A ``gtsam.NonlinearFactorGraph``: one between factor per edge, one prior factor per prior,
        then the landmark measurements (GTSAM's own factors with ``gtsam``; with ours, the ready
        factors equal to them, :func:`lie_factors.expressions.ready.from_gtsam`).

        ``factors``: the namespace of the factor classes, ``gtsam`` (default) or
        :mod:`lie_factors.factors` (both name them ``BetweenFactorPose3``, ...).
        Noise models are ``noiseModel.Gaussian.Information`` (a Diagonal one where
        the information is diagonal, as ``readG2o`` makes them); edges with equal
        information share one model object (the factors' and the batch solver's
        per-model caches then read it once).  ``robust``: an m-estimator
        (``gtsam.noiseModel.mEstimator``) wrapped around the loop closures' models
        (:meth:`loop_closures`; every edge's with ``robust_all``), one
        ``noiseModel.Robust`` per shared Gaussian model.
        """
        import gtsam

        from ..interop import to_gtsam

        F = gtsam if factors is None else factors
        Between = getattr(F, f"BetweenFactor{self.group}")
        Prior = getattr(F, f"PriorFactor{self.group}")
        graph = gtsam.NonlinearFactorGraph()
        E = len(self.edge_keys)
        if E:
            models = _shared_models(self.information)
            if robust is not None:
                wrap = np.ones(E, dtype=bool) if robust_all else np.isin(np.arange(E), self.loop_closures())
                robust_of = {}
                for k in np.flatnonzero(wrap).tolist():
                    model = models[k]
                    if id(model) not in robust_of:
                        robust_of[id(model)] = gtsam.noiseModel.Robust.Create(robust, model)
                    models[k] = robust_of[id(model)]
            for (i, j), M, model in zip(self.edge_keys.tolist(), self.measured, models):
                graph.add(Between(i, j, to_gtsam(self.group, M), model))
        for key, M, info in zip(self.prior_keys.tolist(), self.prior_measured, self.prior_information):
            graph.add(Prior(key, to_gtsam(self.group, M), gtsam.noiseModel.Gaussian.Information(info)))
        if self.landmarks is not None:
            if F is gtsam:
                graph.push_back(self.landmarks.factors)
            else:  # ours: GTSAM's landmark measurements as the ready factors equal to them
                from ..expressions.ready import from_gtsam

                fs = self.landmarks.factors
                for i in range(fs.size()):
                    graph.add(from_gtsam(fs.at(i)))
        return graph


def _shared_models(information: np.ndarray) -> list:
    """One ``noiseModel.Gaussian.Information`` per distinct information matrix, listed per edge."""
    import gtsam

    if len(information) > 1 and information.strides[0] == 0:  # one matrix broadcast to every edge
        model = gtsam.noiseModel.Gaussian.Information(information[0])
        return [model] * len(information)
    flat = np.ascontiguousarray(information.reshape(len(information), -1))
    unique, first, inverse = np.unique(flat, axis=0, return_index=True, return_inverse=True)
    made = [gtsam.noiseModel.Gaussian.Information(information[k]) for k in first.tolist()]
    return [made[u] for u in inverse.reshape(-1).tolist()]


def _elements(X, count: int, g: registry.GroupInfo, name: str) -> None:
    arr = _validate.square(X, g.mat, name)
    if arr.shape != (count, g.mat, g.mat):
        raise ValueError(f"{name}: expected shape ({count}, {g.mat}, {g.mat}), got {arr.shape}")
    _validate.rotation_block(arr, name, g.rot_dim)
    last = "[" + ", ".join(["0"] * (g.mat - 1)) + (", s]" if g.corner == registry.POSITIVE else ", 1]")
    _validate.bottom_row(arr, name, last, last_positive=g.corner == registry.POSITIVE)


def _information(info, count: int, d: int, name: str) -> None:
    if isinstance(info, np.ndarray) and info.ndim == 3 and len(info) > 1 and info.strides[0] == 0:
        info = info[:1]  # one matrix broadcast to every edge: check it once
        count = 1
    arr = _validate.square(info, d, name)
    if arr.shape != (count, d, d):
        raise ValueError(f"{name}: expected shape ({count}, {d}, {d}), got {arr.shape}")
    if count and np.max(np.abs(arr - np.swapaxes(arr, 1, 2))) > 1e-9 * max(1.0, float(np.max(np.abs(arr)))):
        raise ValueError(f"{name}: information matrices must be symmetric")
    if count:
        try:
            np.linalg.cholesky(arr)  # raises unless every one is positive definite (cheaper than eigvalsh)
        except np.linalg.LinAlgError:
            raise ValueError(f"{name}: information matrices must be positive definite") from None
