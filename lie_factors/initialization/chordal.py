"""GTSAM's chordal initializer (``InitializePose3``) on arrays: chordal relaxation of the
rotations, then one Gauss–Newton step on the poses.

The same result as GTSAM's on the graph of between and prior factors the
:class:`~lie_factors.posegraph.graph.PoseGraph` describes (to ~1e-10;
tests/initialization/test_relaxation.py), with no factor object: numpy for the rotation
relaxation, the batch solver (:mod:`lie_factors.batch`: the factors' kernels,
numba) for the Gauss–Newton step, CHOLMOD for the sparse solves.

* :func:`rotations` (``computeOrientationsChordal`` + ``normalizeRelaxedRotations``):
  unknowns r_i ∈ R⁹ (the rows of R_i); each edge asks R_i R_ij = R_j, linear in
  the rows: R_ij r_j^(k) = r_i^(k) for k = 1, 2, 3, weighted by the first
  diagonal entry of the edge's upper-triangular square-root information,
  √information[0, 0] (GTSAM whitens e₁ with the noise model and uses the result
  as a precision); the anchor's rows are e₁, e₂, e₃ with weight 1.  The three
  row systems share one matrix and are solved together.  Each 3×3 result is
  projected to SO(3) by SVD (``Rot3::ClosestTo``: U diag(1, 1, det UVᵀ) Vᵀ).
* :func:`initialize` (``InitializePose3::initialize``): from poses (R_i, 0) and
  the anchor at the identity with a unit prior, one Gauss–Newton iteration of
  the between factors (error Log(Z⁻¹ X_i⁻¹ X_j), the Jacobians of
  ``Pose3::between`` and ``Pose3::Logmap``), X_i ← X_i Exp(δ_i).

A Pose2 graph goes through it as the planar Pose3 graph of
:mod:`lie_factors.initialization.planar` (GTSAM has no Pose2 chordal
initializer), computed without leaving the plane: the planar rotations' chordal
rows are weighted by θ's information (what the planar graph gives ω_x), and
SE(2) is the subgroup of SE(3) that graph lives in — its Log, its Jacobians and
its Gauss–Newton step, whose out-of-plane part decouples and is zero, are the
in-plane block of SE(3)'s — so the step is taken in SE(2) directly.

The anchor and priors as in :mod:`lie_factors.initialization.anchor`.
"""

from __future__ import annotations

import numpy as np

from ..batch.graph import Problem
from ..batch.solvers import CholmodSolver
from ..batch.system import LinearSystem
from ..errors import InitializationError, NotPositiveDefinite
from ..interop import pose2_matrices
from ..posegraph.graph import PoseGraph
from . import anchor, sparse


def _closest_rotation(M: np.ndarray) -> np.ndarray:
    """SO(3) nearest to each M (K, 3, 3) in the Frobenius norm: U diag(1, 1, det UVᵀ) Vᵀ."""
    U, _, Vt = np.linalg.svd(M)
    det = np.linalg.det(U @ Vt)
    U[:, :, 2] *= det[:, None]
    return U @ Vt


def _relaxed(n, ii, jj, Rz, w) -> np.ndarray:
    """Rotations (n + 1, 3, 3) of the anchored edge list (anchor n, identity)."""
    N = n + 1
    # Each edge's rows √w·(−r_i + R r_j): H has w on the diagonal blocks of i and j (RᵀR = I)
    # and −w R at (i, j); the anchor's prior, precision 1, asks its rows to be e_k.
    sw = np.sqrt(w)[:, None, None]
    prior = np.zeros(3 * N)
    prior[3 * n:] = 1.0
    rhs = np.zeros((3 * N, 3))
    rhs[3 * n:, :] = np.eye(3)  # anchor rows = e_k
    X = sparse.solve_edges(N, ii, jj, -sw * np.eye(3), sw * Rz, prior, rhs)
    # Column k holds row k of every rotation: M_i[k, c] = X[3i + c, k].
    M = np.swapaxes(X.reshape(N, 3, 3), 1, 2)
    return _closest_rotation(M)


def _anchored_rotations(pg: PoseGraph):
    """(n, i, j, Z, information, rotations (n + 1, 3, 3)) of a checked, anchored Pose2/Pose3 graph."""
    n, ii, jj, Z, info = anchor.anchored_edges(pg)
    if pg.group == "Pose3":
        Rz, w = Z[:, :3, :3], np.sqrt(info[:, 0, 0])
    else:  # the planar graph's rotations about z; its ω_x information is θ's
        Rz = np.zeros((len(Z), 3, 3))
        Rz[:, :2, :2] = Z[:, :2, :2]
        Rz[:, 2, 2] = 1.0
        w = np.sqrt(info[:, 2, 2])
    # GTSAM whitens e₁ with the noise model, R·e₁, and takes its first entry as the rotation
    # precision: R[0, 0] of the upper-triangular R with RᵀR = information, √information[0, 0].
    return n, ii, jj, Z, info, _relaxed(n, ii, jj, Rz, w)


def rotations(pg: PoseGraph) -> np.ndarray:
    """GTSAM's ``InitializePose3::computeOrientationsChordal`` + ``normalizeRelaxedRotations``:
    the rotations (P, 3, 3) of a Pose3 graph (about z for a Pose2 graph), in key order."""
    anchor.require(pg, ("Pose2", "Pose3"), "GTSAM's chordal initializer")
    return _anchored_rotations(anchor.prepared(pg))[5][:-1]


def _pose_step(problem: Problem) -> np.ndarray:
    """One Gauss–Newton iteration of the anchored between factors (the anchor n, the last
    pose, with a unit prior at the identity) from the poses ``problem`` starts at: the poses
    (n + 1, m, m).

    The between factors are :mod:`lie_factors.factors`' (error Log(Z⁻¹ X_i⁻¹ X_j)
    and its exact Jacobians: GTSAM's ``between`` times ``LogmapDerivative``),
    linearized and assembled by the batch solver's loops, solved by CHOLMOD;
    X_i ← X_i Exp(δ_i).
    """
    system = LinearSystem(problem)
    system.linearize_assemble()
    try:
        delta = CholmodSolver(system).solve(None)
    except NotPositiveDefinite as exc:
        raise InitializationError(str(exc)) from None
    (X,) = problem.retract(delta)[0].values()
    return X


def initialize(pg: PoseGraph) -> np.ndarray:
    """GTSAM's ``InitializePose3.initialize(graph)``: the poses (P, m, m) of a Pose3 graph, or of a
    Pose2 graph as its planar Pose3 graph (module docstring), in key order.

    Raises ``ValueError`` for malformed arrays, :class:`~lie_factors.errors.InitializationError`
    where GTSAM's would fail (another group, a pose with no path to a prior, an
    indeterminate system).
    """
    anchor.require(pg, ("Pose2", "Pose3"), "GTSAM's chordal initializer")
    n, ii, jj, Z, info, R = _anchored_rotations(anchor.prepared(pg))
    R[n] = np.eye(3)  # GTSAM starts the anchor at the identity (its relaxed rotation is dropped)
    if pg.group == "Pose3":
        X = np.zeros((n + 1, 4, 4))
        X[:, :3, :3] = R
        X[:, 3, 3] = 1.0
    else:
        X = pose2_matrices(np.stack([np.zeros(n + 1), np.zeros(n + 1), np.arctan2(R[:, 1, 0], R[:, 0, 0])], 1))
    m, d = X.shape[1], 6 if pg.group == "Pose3" else 3
    problem = Problem.from_pose_graph(PoseGraph(pg.group, np.arange(n + 1), np.stack([ii, jj], axis=1), Z, info,
                                                None, None, np.array([n]), np.eye(m)[None], np.eye(d)[None]), X)
    del ii, jj, Z, info, R, X  # the problem holds what the step needs; its factor comes next
    return _pose_step(problem)[:n]
