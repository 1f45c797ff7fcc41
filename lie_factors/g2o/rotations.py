"""Rotations as ``gtsam.readG2o`` builds them from a record's numbers: ``Rot2::fromAngle``,
``Rot3::Quaternion`` (Eigen's normalize-then-convert) and ``Rot3::Ypr``, over arrays of rows."""

from __future__ import annotations

import numpy as np


def rot2(theta: np.ndarray) -> np.ndarray:
    """Rot2::fromAngle(θ) as (N, 2, 2) matrices."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack((np.stack((c, -s), -1), np.stack((s, c), -1)), -2)


def quaternion_rotation(x, y, z, w):
    """The 9 entries of Rot3::Quaternion(w, x, y, z), row by row; scalars or arrays alike.

    ``readG2o``'s normalization, f = 1 / √(w² + x² + y² + z²) summed in that order and
    each component times f, then Eigen's ``toRotationMatrix`` products 2x·w, 2x·x, ...:
    the same operations in the same order, so the same bits as ``readG2o`` (tested).
    The numpy reading and the compiled one (:mod:`.compiled`) both run this.
    """
    f = 1.0 / np.sqrt(w * w + x * x + y * y + z * z)
    x, y, z, w = x * f, y * f, z * f, w * f
    tx, ty, tz = 2 * x, 2 * y, 2 * z
    twx, twy, twz = tx * w, ty * w, tz * w
    txx, txy, txz = tx * x, ty * x, tz * x
    tyy, tyz, tzz = ty * y, tz * y, tz * z
    return (1 - (tyy + tzz), txy - twz, txz + twy,
            txy + twz, 1 - (txx + tzz), tyz - twx,
            txz - twy, tyz + twx, 1 - (txx + tyy))


def rot3_quaternion(q: np.ndarray) -> np.ndarray:
    """:func:`quaternion_rotation` of rows ``q`` = (qx, qy, qz, qw), shape (N, 3, 3)."""
    x, y, z, w = q.T
    return np.stack(quaternion_rotation(x, y, z, w), -1).reshape(len(q), 3, 3)


def rot3_ypr(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Rot3::Ypr(yaw, pitch, roll) = Rz(yaw)·Ry(pitch)·Rx(roll), shape (N, 3, 3)."""
    cx, sx, cy, sy, cz, sz = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))
    R = np.empty((len(yaw), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 0, 2] = cy * cz, sx * sy * cz - cx * sz, cx * sy * cz + sx * sz
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = cy * sz, sx * sy * sz + cx * cz, cx * sy * sz - sx * cz
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = -sy, sx * cy, cx * cy
    return R
