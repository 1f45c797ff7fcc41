"""Where LM starts, on a pose graph held as arrays: :mod:`lie_factors.initialization.relaxation`'s initializers.

The same methods and the same ``auto`` order as :func:`lie_factors.initialization.initialize`
(``chordal``: GTSAM's InitializePose3, a 2-D graph as a planar Pose3 graph;
``lago``: GTSAM's lago, diagonal noise only; ``file``: the file's vertices),
run on :class:`lie_factors.pose_graph.PoseGraph` plus the prior
:mod:`lie_factors.app.run` puts on the first pose, with no GTSAM factor
object (numpy and CHOLMOD, no numba).  They agree with GTSAM's to 1e-9
(tests/test_relaxation.py, tests/test_g2o_arrays.py).

:func:`initialize` returns None where it does not apply — ``spanning-tree``,
Similarity3 graphs, no cvxopt, or ``auto`` when none of its array methods runs — and the
caller then uses GTSAM's path (:func:`lie_factors.initialization.initialize`),
which has every method; the reasons gathered here go with it.
"""

from __future__ import annotations

import time

import numpy as np

from ..kernels.elements import pose2_matrices
from . import Initialization, InitializationError, auto_order, odometric_path_complete

#: GTSAM's ``Gaussian::Information(M, smart=true)`` (what readG2o builds) makes a
#: Diagonal model when every off-diagonal entry is at most this (checkIfDiagonal).
GTSAM_DIAGONAL_TOL = 1e-9

#: Methods this module runs; the rest go through GTSAM's path.
ARRAY_METHODS = ("chordal", "lago", "file")


def _xytheta(X: np.ndarray) -> np.ndarray:
    """Pose2 matrices (N, 3, 3) → [x, y, θ] (N, 3)."""
    return np.stack([X[:, 0, 2], X[:, 1, 2], np.arctan2(X[:, 1, 0], X[:, 0, 0])], axis=1)


def _diagonal_as_gtsam(a, prior_information: np.ndarray):
    """(edge information, prior information) as GTSAM's Diagonal models hold them, or raise
    the reason LAGO does not apply (GTSAM's path says the same)."""
    info = a.information
    off = np.abs(info - np.einsum("kii->ki", info)[:, :, None] * np.eye(3))
    full = np.flatnonzero(off.max(axis=(1, 2)) > GTSAM_DIAGONAL_TOL)
    if full.size:
        i, j = a.edge_keys[full[0]]
        raise InitializationError(f"LAGO needs diagonal noise models; edge {i}-{j} has a full covariance")
    diag = np.einsum("kii->ki", info)[:, :, None] * np.eye(3)  # what Diagonal::Precisions keeps
    pdiag = np.einsum("kii->ki", prior_information)[:, :, None] * np.eye(3)
    return diag, pdiag


def _run(name: str, a, prior_key: int, prior_element: np.ndarray, prior_information: np.ndarray):
    from . import relaxation  # cvxopt (CHOLMOD) and numpy; loaded only by array initialization

    if name == "file":
        if a.vertices is None:
            raise InitializationError("no initial values given (the file has no vertices)")
        return a.vertices
    n = len(a.keys)
    i = np.searchsorted(a.keys, a.edge_keys[:, 0])
    j = np.searchsorted(a.keys, a.edge_keys[:, 1])
    p = np.searchsorted(a.keys, np.array([prior_key]))
    Z, pZ, pI = a.measured, prior_element[None], prior_information[None]
    if a.group == "Pose2":  # relaxation's 2-D form [x, y, θ], θ = Pose2::theta() = atan2(s, c)
        Z, pZ = _xytheta(Z), _xytheta(pZ)
    try:
        if name == "lago":
            if a.group != "Pose2":
                raise InitializationError(f"LAGO is for Pose2 graphs; this one is {a.group}")
            info, pinfo = _diagonal_as_gtsam(a, pI)
            x = relaxation.lago_pose2(n, i, j, Z, info, p, pZ, pinfo, keys=a.keys,
                                      use_odometric_path=odometric_path_complete(a.keys, a.edge_keys))
            return pose2_matrices(x)
        if a.group == "Pose3":
            return relaxation.initialize_pose3(n, i, j, Z, a.information, p, pZ, pI)
        return pose2_matrices(relaxation.chordal_pose2(n, i, j, Z, a.information, p, pZ, pI))
    except relaxation.RelaxationError as exc:
        raise InitializationError(str(exc)) from None


def initialize(a, method: str, prior_key: int, prior_element: np.ndarray, prior_information: np.ndarray):
    """(Initialization with ``values=None``, poses (P, m, m) in ``a.keys`` order), or (None, skipped).

    ``a``: :class:`lie_factors.pose_graph.PoseGraph` (Pose2 or Pose3); the prior
    on ``prior_key``: element (m, m) and information (n, n).  ``method`` as
    :func:`lie_factors.initialization.initialize`; raises
    :class:`~lie_factors.initialization.InitializationError` when a named method
    cannot run.  (None, skipped) hands over to GTSAM's path with the reasons
    ``auto`` gathered so far.
    """
    from . import relaxation

    if a.group not in ("Pose2", "Pose3") or method == "spanning-tree" or not relaxation.cholmod_available():
        return None, []  # GTSAM's path (its own initializers without cvxopt's CHOLMOD)
    t0 = time.perf_counter()
    order = auto_order(a.is3d, a.vertices is not None, a.group) if method == "auto" else [method]
    skipped: list[tuple[str, str]] = []
    for name in order:
        if name not in ARRAY_METHODS:
            return None, skipped
        try:
            X = _run(name, a, prior_key, prior_element, prior_information)
        except InitializationError as exc:
            if method != "auto":
                raise InitializationError(f"{name}: {exc}") from None
            skipped.append((name, str(exc)))
            continue
        if not np.isfinite(X).all():
            reason = "the result is not finite"
            if method != "auto":
                raise InitializationError(f"{name}: {reason}")
            skipped.append((name, reason))
            continue
        return Initialization(None, name, time.perf_counter() - t0, skipped), X
    return None, skipped
