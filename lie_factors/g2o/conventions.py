"""The g2o format's own conventions: a record's numbers as GTSAM's elements, information and keys.

Conventions that are GTSAM's, never touched by us: g2o writes SE(3)
information as [t, R]; ``readG2o`` permutes ``EDGE_SE3:QUAT`` information to
GTSAM's [ω, v] (a file diag(100·I₃, 25·I₃) yields diag(25·I₃, 100·I₃));
``EDGE3`` information is taken as is.  Landmark ``j`` is the key
``gtsam.symbol('l', j)``, pose ``i`` the key ``i``.  Cartesian landmark
measurements become ``BearingRangeFactor`` s with the information mapped
exactly to first order, Λ_br = Jᵀ Λ_xyz J with J = [r·B, u] (B the bearing's
tangent basis, u = p/r) — what ``readG2o`` does for ``EDGE_SE3_TRACKXYZ``
(checked to 1e-13 on random information matrices), and what we do for
``LANDMARK2`` in 2-D (B = (−u_y, u_x)).  Rotations are built as GTSAM's reader
builds them: ``Rot3::Quaternion`` (Eigen's normalize-then-convert) and
``Rot3::Ypr``.

Sim(3) records (g2o's ``types_seven_dof_expmap``, written by ORB-SLAM-style
systems) are read and written by us, not by GTSAM, which does not know them.
g2o's ``Sim3`` (R, t, s) acts as p ↦ s·R·p + t, its vertex estimate is the
world→camera transform S_iw, and its edge measurement is S_ji = S_jw·S_iw⁻¹ with
error log(S_ji·S_iw·S_jw⁻¹).  What the file holds is the 7-vector
``log(S_iw⁻¹)`` (vertex: camera→world) or ``log(S_ji⁻¹)`` (edge), in g2o's
tangent order [ω, υ, σ] with exp(ω, υ, σ) = (exp(ω×), W·υ, e^σ), i.e. the
matrix exponential of [[ω× + σI, υ], [0, 0]].  The conversion to GTSAM:

* element: g2o (R, t, s) is GTSAM's ``Similarity3(R, t/s, s)`` — the same
  similarity, since GTSAM's matrix [[R, t/s], [0, 1/s]] is g2o's [[sR, t], [0, 1]]
  divided by s (a homogeneous matrix means the same map after scaling);
* tangent: [[ω×, υ], [0, −σ]] (GTSAM's ``Hat``) = [[ω× + σI, υ], [0, 0]] − σI₄,
  and σI₄ commutes with everything, so GTSAM's ``Expmap([ω, υ, σ])`` is g2o's
  exp of the same 7 numbers, divided by e^σ: *the file's vector is GTSAM's
  Similarity3 tangent, unchanged*;
* poses: camera→world S_iw⁻¹ is the GTSAM pose X_i (body→world, as everywhere
  in GTSAM), and S_ji⁻¹ = S_iw·S_jw⁻¹ = X_i⁻¹·X_j is the ``measured`` of
  ``BetweenFactorSimilarity3(i, j, ...)``;
* errors and information: g2o's error log(S_ji·S_iw·S_jw⁻¹) = log(Z⁻¹·X_i⁻¹·X_j)
  is GTSAM's between error, so the 7×7 information (upper triangle, row-major)
  is used as is, without permutation.

So a vertex becomes ``Similarity3(sim3.exp(v))`` and is written as
``sim3.log(X.matrix())``; we use the exact exp/log of :mod:`lie_factors.sim3`
(g2o's own ``Sim3(Vector7)`` treats |σ| < 1e-5 as σ = 0 in W, which moves t by
up to |σ|/2 relative).  :mod:`lie_factors.sim3` is numba code: it is imported
only when a Sim(3) record is converted, so the input check of a small file
stays free of numba.  The vertex's four camera values (focal lengths and
principal point, unused by pose graphs) are checked for being numbers and
dropped; we write g2o's defaults ``1 1 0 0``.
"""

from __future__ import annotations

import math
import sys

import numpy as np

import gtsam

from .records import RECORDS, Rows, same_rows, upper_to_symmetric
from .rotations import rot2, rot3_quaternion, rot3_ypr


def landmark_key(j: int) -> int:
    """GTSAM's key of landmark ``j`` (``readG2o`` uses ``symbol('l', j)``)."""
    return gtsam.symbol("l", int(j))


def _bearing_jacobian(u: np.ndarray, r: float) -> np.ndarray:
    """J = ∂p/∂(θ, r) = [r·(−u_y, u_x), u] of the 2-D point p = r·u."""
    return np.array([[-r * u[1], u[0]], [r * u[0], u[1]]])


def bearing_range_information_2d(p: np.ndarray, info: np.ndarray) -> np.ndarray:
    """Information of (bearing, range) from that of a 2-D point ``p`` (2,), ``info`` (2, 2).

    Λ_br = Jᵀ Λ J with J = ∂p/∂(θ, r) = [r·(−u_y, u_x), u], u = p/r: the 2-D
    form of what ``readG2o`` does for ``EDGE_SE3_TRACKXYZ``.
    """
    r = float(np.hypot(p[0], p[1]))
    u = np.asarray(p, dtype=float) / r
    J = _bearing_jacobian(u, r)
    return J.T @ info @ J


def point_information_2d(bearing: float, range_: float, info_br: np.ndarray) -> np.ndarray:
    """Inverse of :func:`bearing_range_information_2d`: Λ_xy = J⁻ᵀ Λ_br J⁻¹."""
    u = np.array([math.cos(bearing), math.sin(bearing)])
    Jinv = np.linalg.inv(_bearing_jacobian(u, range_))
    return Jinv.T @ info_br @ Jinv


# --------------------------------------------------------------------------- #
# Rows of a pose or edge record → group elements and information
# --------------------------------------------------------------------------- #

#: g2o writes SE(3) information as [t, R]; GTSAM's Pose3 tangent is [ω, v].
_SE3_INFO_ORDER = np.array([3, 4, 5, 0, 1, 2])


def _sim3_exp(v: np.ndarray) -> np.ndarray:
    """GTSAM's Similarity3 matrix of a Sim(3) record's [ω, υ, σ]: (7,) → (4, 4), (N, 7) → (N, 4, 4)."""
    from .. import sim3  # numba: loaded only when a Sim(3) record is converted

    return sim3.exp(v)


def elements(rows: Rows) -> np.ndarray:
    """The group element of every row of a pose or edge record, shape (N, m, m).

    The numbers ``gtsam.readG2o`` builds (quaternions normalized as Eigen does,
    ``Rot3::Ypr``, ``Rot2::fromAngle``); Sim(3) records by :func:`similarity3_from_g2o`'s rule.
    """
    rec = RECORDS[rows.tag]
    v = rows.values
    N = len(v)
    if rec.group_name == "Similarity3":
        return _sim3_exp(np.ascontiguousarray(v[:, :7]))
    if rec.dim == 2:
        X = np.zeros((N, 3, 3))
        X[:, :2, :2] = rot2(v[:, 2])
        X[:, 0, 2], X[:, 1, 2], X[:, 2, 2] = v[:, 0], v[:, 1], 1.0
        return X
    if "qw" in rec.values and "numba" in sys.modules:  # compiled only where numba is loaded already
        from .compiled import quaternion_poses

        return quaternion_poses(v)
    X = np.zeros((N, 4, 4))
    if "qw" in rec.values:
        X[:, :3, :3] = rot3_quaternion(v[:, 3:7])
    else:  # VERTEX3 / EDGE3: x y z roll pitch yaw
        X[:, :3, :3] = rot3_ypr(v[:, 5], v[:, 4], v[:, 3])
    X[:, :3, 3] = v[:, :3]
    X[:, 3, 3] = 1.0
    return X


def information(rows: Rows) -> np.ndarray:
    """Information matrices of a record's rows in GTSAM's tangent order, (N, n, n).

    Rows that all state the same matrix (the usual case) share it: the result is then one
    (n, n) matrix broadcast to (N, n, n), read-only.
    """
    rec = RECORDS[rows.tag]
    # readG2o permutes EDGE_SE3:QUAT information [t, R] → [ω, v]
    order = _SE3_INFO_ORDER if rec.tag == "EDGE_SE3:QUAT" else None
    upper = rows.values[:, len(rec.values):]
    if len(upper) > 1 and same_rows(upper):
        one = upper_to_symmetric(upper[:1], rec.info_dim, order)
        return np.broadcast_to(one, (len(upper),) + one.shape[1:])
    return upper_to_symmetric(upper, rec.info_dim, order)


# --------------------------------------------------------------------------- #
# Sim(3): one record's 7 numbers ↔ gtsam.Similarity3 (derivation above)
# --------------------------------------------------------------------------- #

def similarity3_from_g2o(v) -> gtsam.Similarity3:
    """The GTSAM element of a g2o Sim(3) record's 7 numbers [ω, υ, σ]: ``Expmap`` of them.

    Shapes: ``v`` (7,).  Exact (``lie_factors.sim3.exp``).
    """
    return gtsam.Similarity3(_sim3_exp(np.asarray(v, dtype=np.float64)))


def similarity3_to_g2o(X: gtsam.Similarity3) -> np.ndarray:
    """The 7 numbers g2o writes for GTSAM element ``X``: its ``Logmap`` [ω, u, λ], shape (7,)."""
    from .. import sim3  # numba: loaded only when a Sim(3) record is written

    return sim3.log(np.asarray(X.matrix(), dtype=np.float64))
