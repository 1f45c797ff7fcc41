"""Landmarks of a pose graph, as GTSAM reads them: their measurements stay GTSAM's factors.

A g2o file's landmark records (2-D ``LANDMARK``/``BR``/``LANDMARK2``, 3-D
``EDGE_SE3_XYZ`` and their vertices) are read by GTSAM's reader; every backend
uses the measurements as GTSAM built them (``BearingRangeFactor2D``/``3D``).
Landmark keys are ``symbol('l', j)``; pose keys are plain ids.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np

__all__ = ["is_landmark_key", "pose_keys", "landmark_keys", "Landmarks"]


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
