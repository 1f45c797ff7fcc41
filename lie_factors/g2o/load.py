"""A g2o file as one :class:`~lie_factors.posegraph.graph.PoseGraph`: resolved, checked, read.

No GTSAM graph of the poses is made here: whoever needs one builds it
(:meth:`PoseGraph.factor_graph`).
"""

from __future__ import annotations

import dataclasses
import os

import gtsam
import numpy as np

from ..interop import matrices_from_values
from ..posegraph.graph import PoseGraph
from ..posegraph.landmarks import Landmarks, is_landmark_key
from .check import check_g2o
from .dataset import resolve_dataset
from .read import arrays_supported, read_arrays, read_with_gtsam


def read_pose_graph(dataset: str) -> PoseGraph:
    """The pose graph of a g2o file: resolved (a path, or the name of a file shipped with GTSAM),
    every line checked, then read.

    A file of poses and pose–pose edges (every pose with a vertex, or none) is read into
    arrays (:func:`read_arrays`, no GTSAM object); any other (landmark records, a 2-D file
    where some poses have no vertex) is read by GTSAM (:func:`read_with_gtsam`): its
    pose–pose factors become the arrays and its landmark measurements stay GTSAM's factors
    (``landmarks``). ``name`` and ``path`` say which file it was.

    Raises :class:`~lie_factors.errors.InputError` with ``file:line: what was expected``
    for a malformed file.
    """
    path = resolve_dataset(dataset)
    summary = check_g2o(path)
    name = os.path.basename(path)
    if arrays_supported(summary):
        graph, landmarks = read_arrays(summary), None
    else:
        graph, landmarks = _read_with_gtsam(path, summary)
    return dataclasses.replace(graph, landmarks=landmarks, name=name, path=path)


def _read_with_gtsam(path: str, summary) -> tuple[PoseGraph, Landmarks | None]:
    """(pose graph, landmarks or None) of a file as ``gtsam.readG2o`` reads it."""
    graph, initial = read_with_gtsam(path, summary)
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
