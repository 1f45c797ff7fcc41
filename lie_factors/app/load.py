"""A g2o file ready for a run: resolved, checked, its pose graph on arrays, its landmarks as GTSAM reads them.

1. :func:`lie_factors.g2o.resolve_dataset` — a path, or the name of a file shipped
   with GTSAM (``sphere2500.txt``) found with ``gtsam.findExampleDataFile``.
2. :func:`lie_factors.g2o.check_g2o` — our own vectorized check of every line, so a
   bad file gives ``file:line: what was expected`` instead of GTSAM silently
   skipping lines (``readG2o`` drops every edge after a ``#`` comment, for instance).
3. The pose graph (:class:`lie_factors.pose_graph.PoseGraph`): read into arrays by
   :func:`lie_factors.g2o.read_arrays` where the file is poses and pose–pose edges
   (every pose with a vertex, or none); otherwise (landmark records, 2-D files
   where some poses have no vertex) GTSAM reads the file (:func:`lie_factors.g2o.read_g2o`),
   its pose–pose factors become the PoseGraph and its landmark measurements stay
   GTSAM's factors (:class:`Landmarks`), used as they are by every backend.

No GTSAM graph of the poses is made here: backends build theirs
(:meth:`PoseGraph.factor_graph`) when they need one.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from dataclasses import dataclass

import gtsam
import numpy as np

from ..g2o import arrays_supported, check_g2o, read_arrays, read_g2o, resolve_dataset
from ..initialization import spanning_tree
from ..kernels.elements import matrices_from_values, values_from_matrices
from ..pose_graph import PoseGraph, prior_information


def is_landmark_key(key: int) -> bool:
    return gtsam.Symbol(int(key)).chr() != 0


def pose_keys(values: gtsam.Values) -> list[int]:
    """Sorted pose keys of ``values`` (plain ids; landmarks are ``symbol('l', j)``)."""
    return sorted(k for k in values.keys() if not is_landmark_key(k))


def landmark_keys(values: gtsam.Values) -> list[int]:
    return sorted(k for k in values.keys() if is_landmark_key(k))


@dataclass
class Landmarks:
    """The landmark records of a file, as GTSAM reads them.

    ``factors``: the landmark measurements (GTSAM's BearingRangeFactor2D/3D, pose
    key → landmark key ``symbol('l', j)``); ``vertices``: the landmarks with a
    vertex line, at it; ``with_vertex``: their keys; ``count``: how many
    landmarks there are.  The others are placed from their first measurement
    (:meth:`placed`).
    """

    factors: gtsam.NonlinearFactorGraph
    vertices: gtsam.Values
    with_vertex: frozenset
    is3d: bool
    count: int

    @staticmethod
    def place(f, poses: gtsam.Values):
        """Where the 2-D bearing–range measurement ``f`` puts its landmark, seen from ``poses``."""
        pose_key = next(int(x) for x in f.keys() if not is_landmark_key(x))
        br = f.measured()
        theta, r = br.bearing().theta(), br.range()
        return poses.atPose2(pose_key).transformFrom(np.array([r * math.cos(theta), r * math.sin(theta)]))

    def placed(self, poses: gtsam.Values) -> gtsam.Values:
        """``poses`` and every landmark: at its vertex, else placed from its first measurement
        seen from ``poses`` (``readG2o`` does this for ``BR``/``LANDMARK`` from the pose it had at
        that line; we do it from the given poses, and for ``LANDMARK2``).  3-D measurements
        always have landmark vertices (GTSAM requires them)."""
        values = gtsam.Values(poses)
        values.insert(self.vertices)
        if self.is3d:
            return values
        for k in range(self.factors.size()):
            f = self.factors.at(k)
            point_key = next(int(x) for x in f.keys() if is_landmark_key(x))
            if not values.exists(point_key):
                values.insert(point_key, self.place(f, values))
        return values


@dataclass
class Dataset:
    """A checked g2o file: its pose graph on arrays (``graph``), and its landmarks if it has some.

    ``graph``: the poses and pose–pose edges (no prior); its ``vertices`` are the
    file's, None if the file has no pose vertex (GTSAM's reader: for a 2-D file
    where some poses have none, GTSAM's odometry chaining; the identity for
    poses seen only in landmark measurements).  Every run puts one prior on the
    first pose (:meth:`posed`).  The file's parsed records are not kept: ``graph``
    holds the numbers.
    """

    path: str
    name: str
    graph: PoseGraph
    landmarks: Landmarks | None = None

    @property
    def group(self) -> str:
        """GTSAM type of the poses: Pose2, Pose3 or Similarity3."""
        return self.graph.group

    @property
    def is3d(self) -> bool:
        return self.graph.is3d

    @property
    def first_key(self) -> int:
        """The smallest pose key: it gets the prior."""
        return int(self.graph.keys[0])

    @property
    def initialized_from_edges(self) -> bool:
        """The file has no pose vertex: its poses start along a spanning tree of its edges."""
        return self.graph.vertices is None

    @property
    def poses(self) -> int:
        return len(self.graph.keys)

    @property
    def edges(self) -> int:
        return len(self.graph.edge_keys)

    @property
    def landmark_count(self) -> int:
        return 0 if self.landmarks is None else self.landmarks.count

    @property
    def observations(self) -> int:
        return 0 if self.landmarks is None else int(self.landmarks.factors.size())

    def describe(self) -> str:
        """``"name: SE(3), N poses, M edges[, K landmarks, L landmark measurements]"``: the
        first line a run prints (batch and incremental alike)."""
        lms = (f", {self.landmark_count} landmarks, {self.observations} landmark measurements"
               if self.observations else "")
        return f"{self.name}: {self.graph.info.label}, {self.poses} poses, {self.edges} edges{lms}"

    def posed(self) -> PoseGraph:
        """The graph a run optimizes: the file's edges and a prior on the first pose.

        The prior pins the first pose at its vertex (the identity for files without
        vertices), fixing the gauge, with the variances of GTSAM's examples
        (:data:`lie_factors.pose_graph.PRIOR_VARIANCES`).
        """
        g = self.graph
        first = np.eye(g.info.mat) if g.vertices is None else g.vertices[0]
        return g.with_prior(self.first_key, first, prior_information(self.group))

    @functools.cached_property
    def start_poses(self) -> np.ndarray:
        """(P, m, m): the file's vertices, or, without any, the edges composed along a spanning tree
        from the identity on the first pose (a pose they do not reach stays at the identity)."""
        if self.graph.vertices is not None:
            return self.graph.vertices
        return spanning_tree.compose(self.graph, self.first_key, np.eye(self.graph.info.mat))[0]

    @functools.cached_property
    def initial(self) -> gtsam.Values:
        """:attr:`start_poses` and the landmarks (:meth:`Landmarks.placed`) as ``gtsam.Values``."""
        poses = values_from_matrices(self.group, self.graph.keys, self.start_poses)
        return poses if self.landmarks is None else self.landmarks.placed(poses)

    def with_landmarks(self, poses: gtsam.Values) -> gtsam.Values:
        """``poses`` and the landmarks placed from them (``poses`` itself in a pose graph)."""
        return poses if self.landmarks is None else self.landmarks.placed(poses)

    def native_graph(self) -> gtsam.NonlinearFactorGraph:
        """The file's factors as GTSAM's own (no prior): what :func:`lie_factors.g2o.write_g2o` writes."""
        graph = self.graph.factor_graph()
        if self.landmarks is not None:
            graph.push_back(self.landmarks.factors)
        return graph


def load(dataset: str) -> Dataset:
    """Resolve, check and read ``dataset``; raise :class:`~lie_factors.errors.PoseGraphError` if unusable."""
    path = resolve_dataset(dataset)
    summary = check_g2o(path)
    name = os.path.basename(path)
    if arrays_supported(summary):
        return Dataset(path, name, read_arrays(summary))
    graph, landmarks = _read_with_gtsam(path, summary)
    return Dataset(path, name, graph, landmarks)


def _read_with_gtsam(path: str, summary) -> tuple[PoseGraph, Landmarks | None]:
    """(pose graph, landmarks or None) of a file as ``gtsam.readG2o`` reads it."""
    graph, initial = read_g2o(path, summary)
    between, landmarks = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    for k in range(graph.size()):
        f = graph.at(k)
        (landmarks if any(is_landmark_key(key) for key in f.keys()) else between).add(f)
    pg = PoseGraph.from_gtsam(between, summary.group, summary.pose_ids)
    if len(summary.pose_vertex_ids):
        # readG2o's values: the vertices, 2-D poses without one chained from odometry; a pose
        # seen only in landmark measurements starts at the identity, as in GTSAM's reader.
        X = np.broadcast_to(np.eye(pg.info.mat), (len(pg.keys),) + (pg.info.mat,) * 2).copy()
        have = np.array([initial.exists(int(k)) for k in pg.keys], dtype=bool)
        X[have] = matrices_from_values(initial, pg.group, pg.keys[have])
        pg = dataclasses.replace(pg, vertices=X)
    if not summary.landmark_ids:
        return pg, None
    with_vertex = frozenset(gtsam.symbol("l", int(j)) for j in summary.landmark_vertex_ids.tolist())
    vertices = gtsam.Values()
    for key in sorted(with_vertex):
        vertices.insert(key, initial.atPoint3(key) if summary.is3d else initial.atPoint2(key))
    return pg, Landmarks(landmarks, vertices, with_vertex, summary.is3d, len(summary.landmark_ids))
