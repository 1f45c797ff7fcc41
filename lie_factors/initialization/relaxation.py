"""GTSAM's pose-graph initializers on arrays: chordal relaxation + one Gauss–Newton step (3-D), LAGO (2-D).

No numba and no GTSAM factor objects: numpy for the per-edge algebra, CHOLMOD
(through cvxopt, the batch solver's dependency) for the sparse solves.  Each
function gives what GTSAM's initializer gives on the graph of
``BetweenFactorPose3/Pose2`` factors ``(i[e], j[e], measured[e],
Gaussian.Information(information[e]))`` followed by the priors
``PriorFactorPose3/Pose2(prior_index[p], prior_measured[p],
Gaussian.Information(prior_information[p]))``, in that order (the order
LAGO's spanning tree depends on; ``lie_factors.app.run`` puts its prior
after the edges too).  Without priors, one at the identity on pose 0 (the
smallest key) with the variances of GTSAM's Pose3SLAMExample_g2o.py /
lago's own: Pose3 (1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4), Pose2 (1e-6, 1e-6,
1e-8).

Shapes (E edges, P priors, n poses indexed 0..n-1; tangent orders GTSAM's):

* 3-D: ``measured`` (E, 4, 4), ``information`` (E, 6, 6) on [ω, v];
  ``prior_measured`` (P, 4, 4), ``prior_information`` (P, 6, 6); result (n, 4, 4).
* 2-D: ``measured`` (E, 3) as [x, y, θ] (or (E, 3, 3) matrices),
  ``information`` (E, 3, 3) on [x, y, θ]; priors likewise; result (n, 3) as [x, y, θ].

What GTSAM does (InitializePose.h, InitializePose3.cpp, lago.cpp) and so what
these do:

* Every prior becomes a between factor from a fictitious pose at the identity
  (GTSAM's ``kAnchorKey``), which alone gets a prior.
* :func:`chordal_rotations` (``computeOrientationsChordal``): unknowns r_i ∈ R⁹
  (the rows of R_i); each edge asks R_i R_ij = R_j, linear in the rows:
  R_ij r_j^(k) = r_i^(k) for k = 1, 2, 3, weighted by the first diagonal entry
  of the edge's upper-triangular square-root information, √information[0, 0]
  (GTSAM whitens e₁ with the noise model and uses the result as a precision);
  the anchor's rows are e₁, e₂, e₃ with weight 1.  The three row systems share
  one matrix and are solved together.  Each 3×3 result is projected to SO(3)
  by SVD (``Rot3::ClosestTo``: U diag(1, 1, det UVᵀ) Vᵀ).
* :func:`initialize_pose3` (``InitializePose3::initialize``): from poses
  (R_i, 0) and the anchor at the identity with a unit prior, one Gauss–Newton
  iteration of the between factors (error Log(Z⁻¹ X_i⁻¹ X_j), Jacobians of
  ``Pose3::between``), X_i ← X_i Exp(δ_i).
* :func:`lago_pose2` (``lago::initialize``): a spanning tree (the odometric
  path k → k+1 by key, or Kruskal's tree over the factors in order), each loop
  edge's angle moved by the multiple of 2π that closes its cycle along the tree,
  the linear least squares of the angles (anchor fixed at 0, weights 1/σ_θ²),
  then the linear least squares of the positions with the angles fixed.
* :func:`chordal_pose2`: the planar graph as a Pose3 graph
  (:func:`pose2_information_to_pose3`) through :func:`initialize_pose3`,
  read back as (x, y, yaw): what :mod:`lie_factors.initialization` does for a 2-D
  graph with full covariances.

Errors: :class:`lie_factors.initialization.InitializationError`-compatible
:class:`RelaxationError` (a ``PoseGraphError``) for graphs that cannot be
initialized (disconnected, indeterminate); ``ValueError`` for malformed arrays.
"""

from __future__ import annotations

import numpy as np

from ..kernels import validate as _validate
from ..errors import PoseGraphError

#: Variances of the prior put on pose 0 when none is given (GTSAM's g2o examples).
DEFAULT_PRIOR_VARIANCES_3D = np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4])
DEFAULT_PRIOR_VARIANCES_2D = np.array([1e-6, 1e-6, 1e-8])
#: lago's prior on the anchor pose in its position step (lago.cpp ``priorPose2Noise``).
_LAGO_ANCHOR_VARIANCES = np.array([1e-6, 1e-6, 1e-8])


class RelaxationError(PoseGraphError):
    """The graph cannot be initialized (not connected to a prior, indeterminate system)."""


# --------------------------------------------------------------------------- #
# Input checks
# --------------------------------------------------------------------------- #

def _indices(a, n: int, name: str) -> np.ndarray:
    arr = np.asarray(a)
    if arr.ndim != 1:
        raise ValueError(f"{name}: expected shape (E,), got {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            raise ValueError(f"{name}: pose indices must be integers")
    arr = arr.astype(np.int64)
    if arr.size and (arr.min() < 0 or arr.max() >= n):
        raise ValueError(f"{name}: pose index out of range 0..{n - 1}")
    return arr


def _information(info, E: int, d: int, name: str) -> np.ndarray:
    arr = _validate.square(info, d, name)
    if arr.shape != (E, d, d):
        raise ValueError(f"{name}: expected shape ({E}, {d}, {d}), got {arr.shape}")
    if E and np.max(np.abs(arr - np.swapaxes(arr, 1, 2))) > 1e-9 * max(1.0, float(np.max(np.abs(arr)))):
        raise ValueError(f"{name}: information matrices must be symmetric")
    if E:
        try:
            np.linalg.cholesky(arr)  # raises unless every one is positive definite (3× faster than eigvalsh)
        except np.linalg.LinAlgError:
            raise ValueError(f"{name}: information matrices must be positive definite") from None
    return arr


def _poses3(T, E: int, name: str) -> np.ndarray:
    arr = _validate.square(T, 4, name)
    if arr.shape != (E, 4, 4):
        raise ValueError(f"{name}: expected shape ({E}, 4, 4), got {arr.shape}")
    _validate.rotation_block(arr, name, 3)
    _validate.bottom_row(arr, name, "[0, 0, 0, 1]")
    return arr


def _poses2(x, E: int, name: str) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim == 3 and arr.shape[1:] == (3, 3):
        arr = _validate.square(arr, 3, name)
        _validate.rotation_block(arr, name, 2)
        _validate.bottom_row(arr, name, "[0, 0, 1]")
        arr = np.stack([arr[:, 0, 2], arr[:, 1, 2], np.arctan2(arr[:, 1, 0], arr[:, 0, 0])], axis=1)
    arr = _validate.tangent(arr, 3, name)
    if arr.shape != (E, 3):
        raise ValueError(f"{name}: expected shape ({E}, 3) [x, y, θ] or ({E}, 3, 3), got {arr.shape}")
    return arr


def _graph(n, i, j, measured, information, prior_index, prior_measured, prior_information, is3d):
    """Checked arrays: (n, i, j, Z, info, pi, pZ, pinfo), the default prior filled in."""
    n = int(n)
    if n < 1:
        raise ValueError(f"n: need at least one pose, got {n}")
    i = _indices(i, n, "i")
    j = _indices(j, n, "j")
    if i.shape != j.shape:
        raise ValueError(f"i, j: shapes differ ({i.shape} vs {j.shape})")
    if np.any(i == j):
        raise ValueError(f"i, j: edge {int(np.argmax(i == j))} joins a pose to itself")
    E = i.size
    d, poses = (6, _poses3) if is3d else (3, _poses2)
    Z = poses(measured, E, "measured")
    info = _information(information, E, d, "information")
    if prior_index is None:
        if prior_measured is not None or prior_information is not None:
            raise ValueError("prior_measured/prior_information given without prior_index")
        pi = np.zeros(1, dtype=np.int64)
        pZ = np.eye(4)[None] if is3d else np.zeros((1, 3))
        pinfo = np.diag(1.0 / (DEFAULT_PRIOR_VARIANCES_3D if is3d else DEFAULT_PRIOR_VARIANCES_2D))[None]
    else:
        pi = _indices(np.atleast_1d(prior_index), n, "prior_index")
        P = pi.size
        if prior_measured is None or prior_information is None:
            raise ValueError("prior_index needs prior_measured and prior_information")
        pZ = poses(np.asarray(prior_measured, dtype=np.float64).reshape((P,) + Z.shape[1:]), P, "prior_measured")
        pinfo = _information(np.asarray(prior_information, dtype=np.float64).reshape(P, d, d), P, d,
                             "prior_information")
        if P == 0:
            raise RelaxationError("no prior: give at least one, or none at all for GTSAM's default on pose 0")
    _check_connected(n, i, j, pi)
    return n, i, j, Z, info, pi, pZ, pinfo


def _check_connected(n: int, i: np.ndarray, j: np.ndarray, roots: np.ndarray) -> None:
    """Every pose must reach a prior through edges (else the relaxations are singular)."""
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    chain = np.zeros(max(n - 1, 0), dtype=bool)
    step = hi - lo == 1
    chain[lo[step]] = True
    if chain.all():  # an odometry chain through 0..n-1 (the usual case): connected, no search needed
        return
    # Breadth-first over a CSR adjacency (a Python loop: only graphs without a full chain get here).
    src = np.concatenate([i, j])
    dst = np.concatenate([j, i])
    order = np.argsort(src, kind="stable")
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(src, minlength=n), out=indptr[1:])
    nbrs = dst[order].tolist()
    ptr = indptr.tolist()
    seen = bytearray(n)
    queue = [int(r) for r in roots]
    for r in queue:
        seen[r] = 1
    for u in queue:  # grows while iterating
        for v in nbrs[ptr[u]:ptr[u + 1]]:
            if not seen[v]:
                seen[v] = 1
                queue.append(v)
    if len(queue) < n:
        lost = bytes(seen).index(0)
        raise RelaxationError(f"graph is not connected: pose {lost} has no path to a prior "
                              f"({n - len(queue)} of {n} poses unreachable)")


# --------------------------------------------------------------------------- #
# Sparse symmetric positive definite solve (CHOLMOD through cvxopt)
# --------------------------------------------------------------------------- #

def cholmod_available() -> bool:
    """Whether cvxopt (CHOLMOD) imports: the solver every function here needs."""
    try:
        import cvxopt.cholmod  # noqa: F401
    except ImportError:
        return False
    return True


def solve_spd(n: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """x with A x = rhs, A (n × n) symmetric positive definite given by its lower triangle.

    ``rows``, ``cols``, ``vals`` (K,): triplets with rows ≥ cols, duplicates summed;
    ``rhs`` (n,) or (n, m).  CHOLMOD's sparse Cholesky (AMD ordering).  Raises
    :class:`RelaxationError` if A is not positive definite.
    """
    from cvxopt import cholmod, matrix, spmatrix

    A = spmatrix(matrix(np.ascontiguousarray(vals, dtype=np.float64)),
                 matrix(np.ascontiguousarray(rows, dtype=np.int64)),
                 matrix(np.ascontiguousarray(cols, dtype=np.int64)), (n, n))
    b = np.asarray(rhs, dtype=np.float64)
    B = matrix(b.reshape(n, -1).copy(order="F"))
    try:
        cholmod.linsolve(A, B, uplo="L")
    except ArithmeticError as exc:
        raise RelaxationError(f"the linear system is not positive definite (CHOLMOD: {exc})") from None
    x = np.array(B).reshape(b.shape)
    if not np.all(np.isfinite(x)):
        raise RelaxationError("the linear system is singular (non-finite solution)")
    return x


def _block_triplets(r: np.ndarray, c: np.ndarray, blocks: np.ndarray, d: int):
    """Triplets of the d×d ``blocks`` (K, d, d) at block rows ``r`` and columns ``c`` (K,)."""
    a = np.arange(d)
    rows = (r[:, None, None] * d + a[None, :, None]) + np.zeros((1, 1, d), dtype=np.int64)
    cols = (c[:, None, None] * d + a[None, None, :]) + np.zeros((1, d, 1), dtype=np.int64)
    return rows.ravel(), cols.ravel(), blocks.ravel()


def _scatter_add(index: np.ndarray, values: np.ndarray, N: int) -> np.ndarray:
    """out[k] = Σ values[e] over e with index[e] = k: (E, ...) → (N, ...) (bincount per entry; np.add.at is slow)."""
    flat = values.reshape(values.shape[0], -1)
    out = np.empty((N, flat.shape[1]))
    for c in range(flat.shape[1]):
        out[:, c] = np.bincount(index, weights=flat[:, c], minlength=N)
    return out.reshape((N,) + values.shape[1:])


def _lower_block_triplets(i, j, Hij, d):
    """Lower-triangle triplets of off-diagonal blocks H[i, j] = Hij (and H[j, i] = Hijᵀ)."""
    swap = i < j  # store (max, min): the block at (j, i) is Hijᵀ
    r = np.where(swap, j, i)
    c = np.where(swap, i, j)
    B = np.where(swap[:, None, None], np.swapaxes(Hij, 1, 2), Hij)
    return _block_triplets(r, c, B, d)


def _diag_lower_triplets(D: np.ndarray, d: int):
    """Lower-triangle triplets of the diagonal blocks D (n, d, d)."""
    n = D.shape[0]
    a, b = np.tril_indices(d)
    base = np.arange(n)[:, None] * d
    return (base + a).ravel(), (base + b).ravel(), D[:, a, b].ravel()


# --------------------------------------------------------------------------- #
# SO(3) / SE(3) on stacks of matrices (numpy; the GN step's Log and Exp)
# --------------------------------------------------------------------------- #

def _skew(w: np.ndarray) -> np.ndarray:
    W = np.zeros(w.shape[:-1] + (3, 3))
    W[..., 0, 1], W[..., 0, 2], W[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    W[..., 1, 0], W[..., 2, 0], W[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    return W


def _rot_log(R: np.ndarray) -> np.ndarray:
    """(K, 3, 3) → (K, 3): ω with Exp(ω) = R, |ω| ≤ π.

    θ = atan2(|s|, c) with s = vee(R − Rᵀ)/2 = sin θ·a and c = (tr R − 1)/2;
    ω = θ/sin θ · s while c ≥ 0; for c < 0 (θ > π/2) the axis from the
    symmetric part (R + Rᵀ)/2 − c I = (1 − c) a aᵀ, its sign from s, since s
    loses the axis near π.
    """
    s = 0.5 * np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    c = 0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0)
    sn = np.linalg.norm(s, axis=1)
    th = np.arctan2(sn, c)
    out = np.empty_like(s)
    small = sn < 1e-8  # θ/sin θ = 1 + θ²/6 to double precision below here
    f = np.where(small, 1.0 + th * th / 6.0, th / np.where(sn > 0, sn, 1.0))
    out[:] = f[:, None] * s
    big = c < 0.0
    if np.any(big):
        Rb, cb, sb, tb = R[big], c[big], s[big], th[big]
        S = 0.5 * (Rb + np.swapaxes(Rb, 1, 2)) - cb[:, None, None] * np.eye(3)
        S /= (1.0 - cb)[:, None, None]  # = a aᵀ
        k = np.argmax(np.diagonal(S, axis1=1, axis2=2), axis=1)
        rows = np.arange(k.size)
        col = S[rows, :, k]  # a a_k
        a = col / np.sqrt(col[rows, k])[:, None]
        sign = np.where(np.einsum("ki,ki->k", a, sb) < 0.0, -1.0, 1.0)
        out[big] = (sign * tb)[:, None] * a
    return out


def _so3_coeffs(th: np.ndarray):
    """A = sin θ/θ, B = (1 − cos θ)/θ², C = (θ − sin θ)/θ³ (series below θ = 1e-2)."""
    t2 = th * th
    small = th < 1e-2
    ts = np.where(small, 1.0, th)
    A = np.where(small, 1.0 - t2 / 6.0 + t2 * t2 / 120.0, np.sin(ts) / ts)
    B = np.where(small, 0.5 - t2 / 24.0 + t2 * t2 / 720.0, 2.0 * np.sin(0.5 * ts) ** 2 / (ts * ts))
    C = np.where(small, 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0, (ts - np.sin(ts)) / ts ** 3)
    return A, B, C


def _pose3_log(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Log of (R, t) stacks (K, 3, 3), (K, 3) → (K, 6) [ω, v] with v = V(ω)⁻¹ t.

    V⁻¹ = I − ½ W + (1 − (θ/2) cot(θ/2))/θ² · W², W = ω× (series below θ = 1e-2).
    """
    w = _rot_log(R)
    th = np.linalg.norm(w, axis=1)
    small = th < 1e-2
    ts = np.where(small, 1.0, th)
    t2 = th * th
    half = 0.5 * ts
    d = np.where(small, 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0,
                 (1.0 - half * np.cos(half) / np.sin(half)) / (ts * ts))
    wt = np.cross(w, t)
    v = t - 0.5 * wt + d[:, None] * np.cross(w, wt)
    return np.concatenate([w, v], axis=1)


def _pose3_logmap_derivative(x: np.ndarray) -> np.ndarray:
    """GTSAM's ``Pose3::LogmapDerivative`` for stacks x (K, 6) [ω, v] → (K, 6, 6): the inverse right Jacobian.

    J_r(x)⁻¹ = [[J⁻¹, 0], [−J⁻¹ Q J⁻¹, J⁻¹]] with J⁻¹ = I + ½ W + d W² (W = ω×,
    d as in :func:`_pose3_log`) the inverse right Jacobian of SO(3) and
    Q = Q_l(−ω, −v), Q_l the lower-left block of SE(3)'s left Jacobian
    (Barfoot, State Estimation for Robotics, Eq. 7.86; ours is [ω, v] ordered):
    Q_l = ½ V + a (W V + V W + W V W) + b (W² V + V W² − 3 W V W)
          + c (W V W² + W² V W),  V = v×,
    a = (θ − sin θ)/θ³, b = (θ² + 2 cos θ − 2)/(2θ⁴), c = (2θ − 3 sin θ + θ cos θ)/(2θ⁵)
    (series below θ = 0.1).
    """
    w, v = -x[:, :3], -x[:, 3:]
    th = np.linalg.norm(w, axis=1)
    t2 = th * th
    small = th < 0.1
    ts = np.where(small, 1.0, th)
    sn, cs = np.sin(ts), np.cos(ts)
    a = np.where(small, 1 / 6 - t2 / 120 + t2 ** 2 / 5040 - t2 ** 3 / 362880, (ts - sn) / ts ** 3)
    b = np.where(small, 1 / 24 - t2 / 720 + t2 ** 2 / 40320 - t2 ** 3 / 3628800,
                 (ts * ts + 2 * cs - 2) / (2 * ts ** 4))
    c = np.where(small, 1 / 120 - t2 / 2520 + t2 ** 2 / 120960 - t2 ** 3 / 9979200,
                 (2 * ts - 3 * sn + ts * cs) / (2 * ts ** 5))
    W, Vx = _skew(w), _skew(v)
    W2 = W @ W
    WV, VW, WVW = W @ Vx, Vx @ W, W @ Vx @ W
    Q = (0.5 * Vx + a[:, None, None] * (WV + VW + WVW)
         + b[:, None, None] * (W @ WV + VW @ W - 3 * WVW)
         + c[:, None, None] * (WVW @ W + W @ WVW))
    th_r = np.linalg.norm(x[:, :3], axis=1)
    half = 0.5 * np.where(th_r < 1e-2, 1.0, th_r)
    d = np.where(th_r < 1e-2, 1 / 12 + th_r ** 2 / 720 + th_r ** 4 / 30240,
                 (1 - half * np.cos(half) / np.sin(half)) / (4 * half * half))
    Wr = _skew(x[:, :3])
    Jinv = np.eye(3) + 0.5 * Wr + d[:, None, None] * (Wr @ Wr)
    out = np.zeros((x.shape[0], 6, 6))
    out[:, :3, :3] = out[:, 3:, 3:] = Jinv
    out[:, 3:, :3] = -Jinv @ Q @ Jinv
    return out


def _rot_exp_V(w: np.ndarray):
    """Exp(ω) and V(ω) = Σ W^k/(k+1)! for stacks (K, 3) → (K, 3, 3), (K, 3, 3)."""
    th = np.linalg.norm(w, axis=1)
    A, B, C = _so3_coeffs(th)
    W = _skew(w)
    W2 = W @ W
    eye = np.eye(3)
    R = eye + A[:, None, None] * W + B[:, None, None] * W2
    V = eye + B[:, None, None] * W + C[:, None, None] * W2
    return R, V


def _closest_rotation(M: np.ndarray) -> np.ndarray:
    """SO(3) nearest to each M (K, 3, 3) in the Frobenius norm: U diag(1, 1, det UVᵀ) Vᵀ."""
    U, _, Vt = np.linalg.svd(M)
    det = np.linalg.det(U @ Vt)
    U[:, :, 2] *= det[:, None]
    return U @ Vt


# --------------------------------------------------------------------------- #
# 3-D: chordal relaxation, then one Gauss–Newton step on the poses
# --------------------------------------------------------------------------- #

def _with_anchor(n, i, j, Z, info, pi, pZ, pinfo):
    """Edges with the priors as edges from the anchor (index n), in GTSAM's order."""
    ii = np.concatenate([i, np.full(pi.size, n, dtype=np.int64)])
    jj = np.concatenate([j, pi])
    return ii, jj, np.concatenate([Z, pZ]), np.concatenate([info, pinfo])


def _chordal(n, ii, jj, Rz, w) -> np.ndarray:
    """Rotations (n + 1, 3, 3) of the anchored edge list (anchor n, identity)."""
    N = n + 1
    # H = Σ w (−e_i + R e_j)ᵀ(·) per row system: diagonal w on i and j (RᵀR = I), −w R at (i, j).
    deg = np.bincount(ii, weights=w, minlength=N) + np.bincount(jj, weights=w, minlength=N)
    deg[n] += 1.0  # the anchor's prior, precision 1
    d = np.arange(3 * N)
    r1, c1, v1 = _lower_block_triplets(ii, jj, -w[:, None, None] * Rz, 3)
    rows = np.concatenate([d, r1])
    cols = np.concatenate([d, c1])
    vals = np.concatenate([np.repeat(deg, 3), v1])
    rhs = np.zeros((3 * N, 3))
    rhs[3 * n:, :] = np.eye(3)  # anchor rows = e_k
    X = solve_spd(3 * N, rows, cols, vals, rhs)
    # Column k holds row k of every rotation: M_i[k, c] = X[3i + c, k].
    M = np.swapaxes(X.reshape(N, 3, 3), 1, 2)
    return _closest_rotation(M)


def chordal_rotations(n, i, j, measured, information, prior_index=None, prior_measured=None,
                      prior_information=None) -> np.ndarray:
    """GTSAM's ``InitializePose3::computeOrientationsChordal`` + ``normalizeRelaxedRotations`` on arrays.

    Arguments as :func:`initialize_pose3`; returns the rotations (n, 3, 3).
    """
    n, i, j, Z, info, pi, pZ, pinfo = _graph(n, i, j, measured, information, prior_index, prior_measured,
                                             prior_information, True)
    ii, jj, ZZ, II = _with_anchor(n, i, j, Z, info, pi, pZ, pinfo)
    return _chordal(n, ii, jj, ZZ[:, :3, :3], _rotation_weights(II))[:n]


def _rotation_weights(info: np.ndarray) -> np.ndarray:
    # GTSAM whitens e₁ with the noise model, R·e₁, and takes its first entry as the rotation
    # precision: R[0, 0] of the upper-triangular R with RᵀR = information, i.e. √information[0, 0].
    return np.sqrt(info[:, 0, 0])


def _pose_step(n, ii, jj, Z, info, R) -> np.ndarray:
    """One Gauss–Newton iteration from poses (R_k, 0), anchor n at the identity with a unit prior.

    Between factor error e = Log(Z⁻¹ X_i⁻¹ X_j) with GTSAM's Jacobians: those of
    ``Pose3::between``, H_i = −Ad(hx⁻¹) = −diag(R_ijᵀ, R_ijᵀ) at zero
    translations and H_j = I, times the error's own, ``LogmapDerivative(e)``.
    Returns the poses (n + 1, 4, 4).
    """
    N = n + 1
    E = ii.size
    Rij = np.swapaxes(R[ii], 1, 2) @ R[jj]
    Rz, tz = Z[:, :3, :3], Z[:, :3, 3]
    RzT = np.swapaxes(Rz, 1, 2)
    e = _pose3_log(RzT @ Rij, -np.einsum("kij,kj->ki", RzT, tz))
    M = _pose3_logmap_derivative(e)
    MTI = np.swapaxes(M, 1, 2) @ info
    K = MTI @ M  # H_j = M: H_jᵀ Λ H_j
    Me = np.einsum("kab,kb->ka", MTI, e)  # H_jᵀ Λ e
    del M, MTI  # (E, 6, 6) temporaries: 50 MB per 10⁵ edges each
    P = np.zeros((E, 6, 6))
    P[:, :3, :3] = Rij
    P[:, 3:, 3:] = Rij
    PI = P @ K  # −H_iᵀ Λ H_j, since H_i = −M Pᵀ
    D = _scatter_add(ii, PI @ np.swapaxes(P, 1, 2), N) + _scatter_add(jj, K, N)
    del K
    D[n] += np.eye(6)  # the anchor's unit prior
    g = _scatter_add(ii, np.einsum("kab,kb->ka", P, Me), N) - _scatter_add(jj, Me, N)  # −Hᵀ Λ e
    del P
    r0, c0, v0 = _diag_lower_triplets(D, 6)
    r1, c1, v1 = _lower_block_triplets(ii, jj, -PI, 6)
    del PI, D
    rows, cols, vals = np.concatenate([r0, r1]), np.concatenate([c0, c1]), np.concatenate([v0, v1])
    del r0, r1, c0, c1, v0, v1
    delta = solve_spd(6 * N, rows, cols, vals, g.ravel()).reshape(N, 6)
    dR, V = _rot_exp_V(delta[:, :3])
    T = np.zeros((N, 4, 4))
    T[:, :3, :3] = R @ dR
    T[:, :3, 3] = np.einsum("kab,kb->ka", R @ V, delta[:, 3:])
    T[:, 3, 3] = 1.0
    return T


def initialize_pose3(n, i, j, measured, information, prior_index=None, prior_measured=None,
                     prior_information=None) -> np.ndarray:
    """GTSAM's ``InitializePose3.initialize(graph)`` on arrays: (n, 4, 4) poses.

    ``n``: number of poses (indices 0..n-1); ``i``, ``j`` (E,): the edges' pose
    indices; ``measured`` (E, 4, 4): Z_e ≈ X_i⁻¹ X_j; ``information`` (E, 6, 6)
    on GTSAM's Pose3 tangent [ω, v]; ``prior_index`` (P,), ``prior_measured``
    (P, 4, 4), ``prior_information`` (P, 6, 6), or all None for a prior at the
    identity on pose 0.  Chordal relaxation of the rotations, then one
    Gauss–Newton step on the full poses (module docstring).
    """
    n, i, j, Z, info, pi, pZ, pinfo = _graph(n, i, j, measured, information, prior_index, prior_measured,
                                             prior_information, True)
    ii, jj, ZZ, II = _with_anchor(n, i, j, Z, info, pi, pZ, pinfo)
    R = _chordal(n, ii, jj, ZZ[:, :3, :3], _rotation_weights(II))
    R[n] = np.eye(3)  # GTSAM starts the anchor at the identity (its relaxed rotation is dropped)
    return _pose_step(n, ii, jj, ZZ, II, R)[:n]


# --------------------------------------------------------------------------- #
# 2-D: chordal as a planar Pose3 graph, and LAGO
# --------------------------------------------------------------------------- #

def pose2_information_to_pose3(info2: np.ndarray) -> np.ndarray:
    """(..., 3, 3) information on Pose2's [x, y, θ] → (..., 6, 6) on Pose3's [ω, v] for planar edges.

    The in-plane block as given ([x, y, θ] → [v_x, v_y, ω_z]); the out-of-plane
    components (ω_x, ω_y, v_z) decoupled, with θ's and x's information.  The
    chordal relaxation weighs each edge by its ω_x information, so ω_x gets θ's:
    the weights are then the edge's rotation precision, as for a 3-D graph.
    """
    info2 = np.asarray(info2, dtype=np.float64)
    idx = [3, 4, 2]  # x, y, θ → v_x, v_y, ω_z
    info3 = np.zeros(info2.shape[:-2] + (6, 6))
    info3[..., np.array(idx)[:, None], np.array(idx)[None, :]] = info2
    info3[..., 0, 0] = info3[..., 1, 1] = info2[..., 2, 2]
    info3[..., 5, 5] = info2[..., 0, 0]
    return info3


def _planar_pose3(x: np.ndarray) -> np.ndarray:
    """[x, y, θ] (K, 3) → planar Pose3 matrices (K, 4, 4)."""
    c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
    T = np.zeros((x.shape[0], 4, 4))
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s, s, c
    T[:, 2, 2] = T[:, 3, 3] = 1.0
    T[:, 0, 3], T[:, 1, 3] = x[:, 0], x[:, 1]
    return T


def chordal_pose2(n, i, j, measured, information, prior_index=None, prior_measured=None,
                  prior_information=None) -> np.ndarray:
    """A Pose2 graph through :func:`initialize_pose3` as a planar Pose3 graph: (n, 3) [x, y, θ].

    Arguments as :func:`lago_pose2` (any positive definite information).  For
    planar measurements and decoupled out-of-plane information the relaxation
    keeps every rotation about z and the pose step keeps z = 0, so (x, y, yaw)
    of the result is the chordal initialization of the Pose2 graph (GTSAM has
    no chordal initializer for Pose2).
    """
    n, i, j, Z, info, pi, pZ, pinfo = _graph(n, i, j, measured, information, prior_index, prior_measured,
                                             prior_information, False)
    T = initialize_pose3(n, i, j, _planar_pose3(Z), pose2_information_to_pose3(info), pi, _planar_pose3(pZ),
                         pose2_information_to_pose3(pinfo))
    return np.stack([T[:, 0, 3], T[:, 1, 3], np.arctan2(T[:, 1, 0], T[:, 0, 0])], axis=1)


def _odometric_tree(keys, ii, jj, n):
    """lago's ``findOdometricPath``: parent[k + 1] = k along consecutive keys (first edge wins),
    the smallest such key (or the first factor's smaller key) hangs from the anchor (index n).
    Returns parent (n + 1,) with -1 where a pose has none."""
    parent = np.full(n + 1, -1, dtype=np.int64)
    kk = np.append(keys, -1)  # the anchor's key plays no part in "consecutive" (GTSAM's 99999999)
    ka, kb = kk[ii], kk[jj]
    lo = np.where(ka <= kb, ii, jj)
    hi = np.where(ka <= kb, jj, ii)
    anchor_edge = (ii == n) | (jj == n)
    # GTSAM takes min/max of the keys themselves; the anchor key 99999999 is the larger one.
    lo = np.where(anchor_edge, np.where(ii == n, jj, ii), lo)
    hi = np.where(anchor_edge, n, hi)
    consecutive = ~anchor_edge & (kk[hi] - kk[lo] == 1)
    idx = np.nonzero(consecutive)[0]
    first = idx[np.unique(hi[idx], return_index=True)[1]]  # emplace: the first edge per child wins
    parent[hi[first]] = lo[first]
    mins = [lo[0]] + ([lo[idx[np.argmin(kk[lo[idx]])]]] if idx.size else [])
    min_node = min(mins, key=lambda v: kk[v])
    if parent[min_node] < 0:
        parent[min_node] = n
    parent[n] = n
    return parent


def _kruskal_tree(ii, jj, n):
    """lago's ``findMinimumSpanningTree``: Kruskal over the factors in order (equal weights),
    then the tree rooted at the anchor (index n).  Returns parent (n + 1,)."""
    root = list(range(n + 1))

    def find(a):
        while root[a] != a:
            root[a] = root[root[a]]
            a = root[a]
        return a

    adj: list[list[int]] = [[] for _ in range(n + 1)]
    count = 0
    for a, b in zip(ii.tolist(), jj.tolist()):
        ra, rb = find(a), find(b)
        if ra != rb:
            root[ra] = rb
            adj[a].append(b)
            adj[b].append(a)
            count += 1
            if count == n:
                break
    parent = np.full(n + 1, -1, dtype=np.int64)
    parent[n] = n
    stack = [n]
    while stack:
        u = stack.pop()
        for v in adj[u]:
            if parent[v] < 0:
                parent[v] = u
                stack.append(v)
    return parent


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles to (−π, π] as GTSAM's Rot2(θ).theta() does (atan2 of sin and cos)."""
    return np.arctan2(np.sin(a), np.cos(a))


def _lago_orientations(n, keys, ii, jj, dth, w, use_odometric_path) -> np.ndarray:
    """lago's ``computeOrientations`` on the anchored edges (anchor n): angles (n + 1,), anchor's 0.

    ``dth`` (E,) the measured angles, ``w`` (E,) their weights 1/σ_θ².
    """
    N = n + 1

    # --- the spanning tree and each pose's angle along it from the anchor
    parent = _odometric_tree(keys, ii, jj, n) if use_odometric_path else _kruskal_tree(ii, jj, n)
    fwd = parent[jj] == ii  # edge i → j is the tree edge into j (tested second in GTSAM)
    bwd = parent[ii] == jj  # into i, tested first
    in_tree = bwd | fwd
    child = np.where(bwd, ii, jj)
    delta = np.where(bwd, -dth, dth)
    tree_edges = np.nonzero(in_tree)[0]
    first = tree_edges[np.unique(child[tree_edges], return_index=True)[1]]  # first edge per child wins
    step = np.full(N, np.nan)
    step[child[first]] = delta[first]
    step[n] = 0.0
    theta_tree = _sum_to_root(parent, step, n)
    if np.isnan(theta_tree).any():
        lost = int(np.nonzero(np.isnan(theta_tree))[0][0])
        where = f"pose {int(keys[lost])}" if lost < n else "the anchor"
        if use_odometric_path:  # GTSAM's lago throws (map::at) here
            raise RelaxationError(f"LAGO's odometric path (consecutive keys, its first key hung from the prior) "
                                  f"does not reach {where}; use_odometric_path=False takes Kruskal's tree")
        raise RelaxationError(f"LAGO's spanning tree does not reach {where}")

    # --- loop edges regularized by the multiple of 2π closing their cycle; angles by linear LS
    chord = ~in_tree
    k = np.round((dth + theta_tree[ii] - theta_tree[jj]) / (2 * np.pi))
    d_reg = np.where(chord, dth - 2 * k * np.pi, dth)
    # θ_j − θ_i = d, weight w; the anchor's θ is fixed at 0 (lago's prior has sigma 0).
    free = np.arange(N) != n
    idx_of = np.cumsum(free) - 1
    both = free[ii] & free[jj]
    diag = (np.bincount(ii[free[ii]], weights=w[free[ii]], minlength=N)
            + np.bincount(jj[free[jj]], weights=w[free[jj]], minlength=N))[free]
    g = (np.bincount(jj[free[jj]], weights=(w * d_reg)[free[jj]], minlength=N)
         - np.bincount(ii[free[ii]], weights=(w * d_reg)[free[ii]], minlength=N))[free]
    a, b = idx_of[ii[both]], idx_of[jj[both]]
    rows = np.concatenate([np.arange(n), np.maximum(a, b)])
    cols = np.concatenate([np.arange(n), np.minimum(a, b)])
    theta = solve_spd(n, rows, cols, np.concatenate([diag, -w[both]]), g)
    return np.append(theta, 0.0)


def lago_pose2(n, i, j, measured, information, prior_index=None, prior_measured=None,
               prior_information=None, keys=None, use_odometric_path=True) -> np.ndarray:
    """GTSAM's ``lago.initialize(graph, useOdometricPath)`` on arrays: (n, 3) poses [x, y, θ].

    ``measured`` (E, 3) [x, y, θ] (or (E, 3, 3)); ``information`` (E, 3, 3) on
    [x, y, θ], diagonal (LAGO uses the sigmas of diagonal noise models);
    priors as for :func:`initialize_pose3` in Pose2 form; ``keys`` (n,) the
    poses' keys, increasing (default 0..n-1): the odometric path follows
    consecutive keys.  With ``use_odometric_path`` the path k → k+1 must reach
    every pose from the one on the first factor (or the smallest key joined
    by a consecutive edge), which hangs from a prior; else Kruskal's tree.
    θ of the result is in (−π, π].
    """
    n, i, j, Z, info, pi, pZ, pinfo = _graph(n, i, j, measured, information, prior_index, prior_measured,
                                             prior_information, False)
    for name, a in (("information", info), ("prior_information", pinfo)):
        off = a - np.einsum("kii->ki", a)[:, :, None] * np.eye(3)
        if np.any(off != 0.0):
            first = int(np.argmax(np.any(off != 0, axis=(1, 2))))
            raise RelaxationError(f"LAGO needs diagonal noise models; {name}[{first}] is a full matrix")
    keys = np.arange(n, dtype=np.int64) if keys is None else np.asarray(keys, dtype=np.int64)
    if keys.shape != (n,) or np.any(np.diff(keys) <= 0):
        raise ValueError(f"keys: expected ({n},) increasing integers")
    ii, jj, ZZ, II = _with_anchor(n, i, j, Z, info, pi, pZ, pinfo)
    N = n + 1
    dth = ZZ[:, 2]
    th = _lago_orientations(n, keys, ii, jj, dth, II[:, 2, 2], use_odometric_path)

    # --- positions (and angle corrections) by linear LS with the angles fixed
    s1, c1 = np.sin(th[ii]), np.cos(th[ii])
    dx, dy = ZZ[:, 0], ZZ[:, 1]
    b = np.stack([c1 * dx - s1 * dy, s1 * dx + c1 * dy, _wrap(th[jj] - th[ii] - dth)], axis=1)
    J1 = np.broadcast_to(-np.eye(3), (ii.size, 3, 3)).copy()
    J1[:, 0, 2] = s1 * dx + c1 * dy
    J1[:, 1, 2] = -c1 * dx + s1 * dy
    L = II  # diagonal: Λ = diag(1/σ²)
    Hii = np.swapaxes(J1, 1, 2) @ L @ J1
    Hji = L @ J1  # J2ᵀ Λ J1 with J2 = I: block (j, i)
    D = _scatter_add(ii, Hii, N) + _scatter_add(jj, L, N)
    D[n] += np.diag(1.0 / _LAGO_ANCHOR_VARIANCES)
    Lb = np.einsum("kab,kb->ka", L, b)
    rhs = _scatter_add(ii, np.einsum("kba,kb->ka", J1, Lb), N) + _scatter_add(jj, Lb, N)
    r0, c0, v0 = _diag_lower_triplets(D, 3)
    r1, c1_, v1 = _lower_block_triplets(jj, ii, Hji, 3)
    x = solve_spd(3 * N, np.concatenate([r0, r1]), np.concatenate([c0, c1_]), np.concatenate([v0, v1]),
                  rhs.ravel()).reshape(N, 3)
    return np.stack([x[:n, 0], x[:n, 1], _wrap(th[:n] + x[:n, 2])], axis=1)


def _sum_to_root(parent: np.ndarray, step: np.ndarray, root: int) -> np.ndarray:
    """Σ of ``step`` along the tree from each node up to ``root`` (NaN where a node does not reach it).

    Pointer jumping: log₂(depth) vectorized rounds instead of a walk per node.
    """
    N = parent.size
    up = np.where(parent < 0, np.arange(N), parent)
    total = np.where(parent < 0, np.nan, step)
    total[root] = 0.0
    done = (up == root) | (parent < 0)
    while not done.all():
        nxt = up[up]
        total = np.where(done, total, total + total[up])
        up = np.where(done, up, nxt)
        done = (up == root) | np.isnan(total) | (up == np.arange(N))
    total[(up != root) & (np.arange(N) != root)] = np.nan
    return total
