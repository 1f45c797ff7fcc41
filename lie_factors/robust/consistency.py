"""χ² consistency of loop closures with the odometry chain and with one another.

Poses are numbered by their position in the graph's sorted keys; the odometry
edge ``k → k+1`` has measurement Ẑ_k and covariance Σ_k (the inverse of its
information), its noise on the right: Z_k = Ẑ_k·Exp(ξ_k).  Composing the chain
gives every pose's dead-reckoned pose T_k relative to the first pose of its
*segment* (a maximal run of poses joined by odometry), and, to first order,
the relative pose of two poses of one segment is

    T_ij = T̂_ij · Exp(Ad(T̂_j⁻¹) · (W_j − W_i)),   W_k = Σ_{m<k} Ad(T̂_{m+1}) · ξ_m,

(move each Exp(ξ_m) to the right end: ``X·Exp(ξ)·Y = X·Y·Exp(Ad(Y⁻¹)ξ)``).
The W_k are sums of independent terms, so Cov(W_x, W_y) = P_{min(x,y)} with the
prefix sums P_k = Σ_{m<k} Ad(T̂_{m+1}) Σ_m Ad(T̂_{m+1})ᵀ: one (n, n) matrix per
pose answers the covariance of any stretch of odometry, and of two stretches
that overlap, in O(1).

:func:`cycle_chi2` is the test of both stages, on the cycle
L = Z₁⁻¹ · T_ac · Z₂ · T_db of loop closures Z₁ (a → b) and Z₂ (c → d) with the
odometry between their ends:

* **odometry gate**: one closure against the chain (c = d = b, Z₂ = I, Σ₂ = 0):
  L = Z₁⁻¹·T_ab;
* **pairwise consistency** (Mangelson, Dominic, Eustice, Vasudevan, "Pairwise
  Consistency Maximization for Robust Multi-Robot Map Merging", ICRA 2018,
  Eq. 8): two closures and the odometry between their ends.

With every noise moved to L's right end, L = L̂·Exp(δ), δ = J_A ζ₁ + J_C ζ₂ +
J_B u_B + J_D u_D where ζ₁, ζ₂ are the closures' noises, u_B = W_c − W_a,
u_D = W_b − W_d, and

    J_A = −Ad(L̂⁻¹),  J_B = Ad((T̂_c·Ẑ₂·T̂_db)⁻¹),  J_C = Ad(T̂_db⁻¹),  J_D = Ad(T̂_b⁻¹);
    Cov u_B = P_a + P_c − 2P_min(a,c),  Cov u_D = P_b + P_d − 2P_min(b,d),
    Cov(u_B, u_D) = P_min(c,b) − P_min(c,d) − P_min(a,b) + P_min(a,d).

The statistic is χ² = rᵀ Σ_δ⁻¹ r with r = Log(L̂): to first order Log(L) = r +
J_r(r)⁻¹ δ, and J_r(r)·r = r (ad_r r = 0), so rᵀ(J_r⁻¹ Σ_δ J_r⁻ᵀ)⁻¹ r = rᵀ Σ_δ⁻¹ r.
It is χ²-distributed with n degrees of freedom when the closures are true and
the noise models right.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from ..kernels import dispatch as _dispatch
from ..kernels.jit import kernel
from ..batch.loops import CHUNK, parallel, parallel_kernel

__all__ = ["Chain", "chain", "reverse", "cycle_chi2", "gate_chi2", "pair_chi2", "near_pairs"]


@kernel
def _matmul(A, B, out):
    n, k, p = A.shape[0], A.shape[1], B.shape[1]
    for i in range(n):
        for j in range(p):
            acc = 0.0
            for t in range(k):
                acc += A[i, t] * B[t, j]
            out[i, j] = acc


@kernel
def _add_sandwich(J, S, K, out):
    """out += J·S·Kᵀ (all (n, n))."""
    n = J.shape[0]
    JS = np.empty((n, n))
    _matmul(J, S, JS)
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for t in range(n):
                acc += JS[i, t] * K[j, t]
            out[i, j] += acc


@kernel
def _chain_kernel(g, Z, S, start, T, P):
    """Dead reckoning and prefix covariances: see the module docstring.

    Z (N, m, m), S (N, n, n): the odometry into pose k (Z[k] takes pose k−1 to
    pose k; ignored where ``start[k]``); T (N, m, m), P (N, n, n) written.
    """
    N = T.shape[0]
    m = T.shape[1]
    n = P.shape[1]
    Ad = np.empty((n, n))
    for k in range(N):
        if start[k]:
            for i in range(m):
                for j in range(m):
                    T[k, i, j] = 1.0 if i == j else 0.0
            for i in range(n):
                for j in range(n):
                    P[k, i, j] = 0.0
            continue
        _dispatch.compose(g, T[k - 1], Z[k], T[k])
        _dispatch.Ad(g, T[k], Ad)
        for i in range(n):
            for j in range(n):
                P[k, i, j] = P[k - 1, i, j]
        _add_sandwich(Ad, S[k], Ad, P[k])


@kernel
def _cholesky_quad(Sig, r):
    """rᵀ Sig⁻¹ r by Cholesky of the symmetric part of Sig; inf if Sig is not positive definite."""
    n = r.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        d = 0.5 * (Sig[j, j] + Sig[j, j])
        for t in range(j):
            d -= L[j, t] * L[j, t]
        if not d > 0.0:
            return np.inf
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, n):
            s = 0.5 * (Sig[i, j] + Sig[j, i])
            for t in range(j):
                s -= L[i, t] * L[j, t]
            L[i, j] = s / L[j, j]
    y = np.empty(n)
    total = 0.0
    for i in range(n):
        s = r[i]
        for t in range(i):
            s -= L[i, t] * y[t]
        y[i] = s / L[i, i]
        total += y[i] * y[i]
    return total


@kernel
def cycle_chi2(g, T, P, a, b, Z1, S1, c, d, Z2, S2):
    """χ² of the cycle L = Z1⁻¹·T_ac·Z2·T_db (module docstring); a, b, c, d pose positions
    of one segment, Z1, Z2 (m, m), S1, S2 (n, n) the closures' covariances."""
    m = T.shape[1]
    n = P.shape[1]
    Ta_inv = np.empty((m, m))
    Td_inv = np.empty((m, m))
    Tb_inv = np.empty((m, m))
    Z1_inv = np.empty((m, m))
    Tac = np.empty((m, m))
    Tdb = np.empty((m, m))
    CD = np.empty((m, m))
    BCD = np.empty((m, m))
    L = np.empty((m, m))
    X = np.empty((m, m))
    Xi = np.empty((m, m))
    _dispatch.inverse(g, T[a], Ta_inv)
    _dispatch.inverse(g, T[d], Td_inv)
    _dispatch.inverse(g, T[b], Tb_inv)
    _dispatch.inverse(g, Z1, Z1_inv)
    _dispatch.compose(g, Ta_inv, T[c], Tac)
    _dispatch.compose(g, Td_inv, T[b], Tdb)
    _dispatch.compose(g, Z2, Tdb, CD)
    _dispatch.compose(g, Tac, CD, BCD)
    _dispatch.compose(g, Z1_inv, BCD, L)
    r = np.empty(n)
    _dispatch.log(g, L, r)

    Sig = np.zeros((n, n))
    J = np.empty((n, n))
    K = np.empty((n, n))
    V = np.empty((n, n))
    # J_A = −Ad(L̂⁻¹): the sign drops out of J_A S1 J_Aᵀ.
    _dispatch.inverse(g, L, Xi)
    _dispatch.Ad(g, Xi, J)
    _add_sandwich(J, S1, J, Sig)
    # J_C = Ad(T̂_db⁻¹)
    _dispatch.inverse(g, Tdb, Xi)
    _dispatch.Ad(g, Xi, J)
    _add_sandwich(J, S2, J, Sig)
    # J_B = Ad((T̂_c·Ẑ2·T̂_db)⁻¹), J_D = Ad(T̂_b⁻¹)
    _dispatch.compose(g, T[c], CD, X)
    _dispatch.inverse(g, X, Xi)
    _dispatch.Ad(g, Xi, J)
    _dispatch.Ad(g, Tb_inv, K)
    ac, bd = min(a, c), min(b, d)
    for i in range(n):
        for j in range(n):
            V[i, j] = P[a, i, j] + P[c, i, j] - 2.0 * P[ac, i, j]
    _add_sandwich(J, V, J, Sig)
    for i in range(n):
        for j in range(n):
            V[i, j] = P[b, i, j] + P[d, i, j] - 2.0 * P[bd, i, j]
    _add_sandwich(K, V, K, Sig)
    cb, cd, ab, ad = min(c, b), min(c, d), min(a, b), min(a, d)
    for i in range(n):
        for j in range(n):
            V[i, j] = P[cb, i, j] - P[cd, i, j] - P[ab, i, j] + P[ad, i, j]
    # cross terms J_B X J_Dᵀ + (J_B X J_Dᵀ)ᵀ
    C = np.zeros((n, n))
    _add_sandwich(J, V, K, C)
    for i in range(n):
        for j in range(n):
            Sig[i, j] += C[i, j] + C[j, i]
    return _cholesky_quad(Sig, r)


@kernel
def _gate_range(g, T, P, a, b, Z, S, out, k0, k1):
    """out[k] = the χ² of closure k against the odometry between its ends, k0 ≤ k < k1."""
    m = T.shape[1]
    n = P.shape[1]
    I = np.zeros((m, m))
    for i in range(m):
        I[i, i] = 1.0
    O = np.zeros((n, n))
    for k in range(k0, k1):
        out[k] = cycle_chi2(g, T, P, a[k], b[k], Z[k], S[k], b[k], b[k], I, O)


@parallel_kernel
def _gate_kernel(g, T, P, a, b, Z, S, out):
    C = a.shape[0]
    for ch in prange((C + CHUNK - 1) // CHUNK):
        _gate_range(g, T, P, a, b, Z, S, out, ch * CHUNK, min(C, (ch + 1) * CHUNK))


@kernel
def _pair_range(g, T, P, a, b, Z, S, first, second, out, k0, k1):
    """out[k] = the χ² of the cycle of closures first[k] and second[k], k0 ≤ k < k1."""
    for k in range(k0, k1):
        i, j = first[k], second[k]
        out[k] = cycle_chi2(g, T, P, a[i], b[i], Z[i], S[i], a[j], b[j], Z[j], S[j])


@parallel_kernel
def _pair_kernel(g, T, P, a, b, Z, S, first, second, out):
    K = first.shape[0]
    for ch in prange((K + CHUNK - 1) // CHUNK):
        _pair_range(g, T, P, a, b, Z, S, first, second, out, ch * CHUNK, min(K, (ch + 1) * CHUNK))


@kernel
def _reverse_kernel(g, Z, S, flip):
    m = Z.shape[1]
    n = S.shape[1]
    Zi = np.empty((m, m))
    Ad = np.empty((n, n))
    for k in range(Z.shape[0]):
        if flip[k]:
            _dispatch.Ad(g, Z[k], Ad)
            _dispatch.inverse(g, Z[k], Zi)
            V = np.zeros((n, n))
            _add_sandwich(Ad, S[k], Ad, V)
            # entry by entry: an array assignment compiles numba's shape-mismatch message,
            # seconds of a first run
            for i in range(m):
                for j in range(m):
                    Z[k, i, j] = Zi[i, j]
            for i in range(n):
                for j in range(n):
                    S[k, i, j] = V[i, j]


def reverse(group, Z: np.ndarray, S: np.ndarray, flip: np.ndarray) -> None:
    """Turn the edges ``flip`` (bool (K,)) around in place: Z ← Z⁻¹ (K, m, m) and
    S ← Ad(Z)·S·Ad(Z)ᵀ (K, n, n), since ``Ẑ·Exp(ξ)`` inverted is ``Ẑ⁻¹·Exp(−Ad(Ẑ)ξ)``."""
    _reverse_kernel(group, Z, S, np.ascontiguousarray(flip, dtype=np.bool_))


class Chain:
    """The odometry chain of a pose graph, composed: see the module docstring.

    ``segment`` (N,) int64: each pose's segment; ``T`` (N, m, m) dead-reckoned
    poses relative to their segment's first pose; ``P`` (N, n, n) prefix
    covariances.
    """

    def __init__(self, group, segment: np.ndarray, T: np.ndarray, P: np.ndarray):
        self.group, self.segment, self.T, self.P = group, segment, T, P


def chain(group, N: int, odo_from: np.ndarray, odo_to: np.ndarray, measured: np.ndarray,
          covariance: np.ndarray) -> Chain:
    """Compose the odometry ``odo_from[k] → odo_to[k]`` (pose positions, |to − from| = 1,
    one edge per consecutive pair; measured (K, m, m), covariance (K, n, n)) over N poses.

    An edge given backwards (k+1 → k) is turned around (:func:`reverse`).
    """
    m, n = group.mat, group.dim
    Z = np.zeros((N, m, m))
    S = np.zeros((N, n, n))
    start = np.ones(N, dtype=np.bool_)
    odo_from = np.asarray(odo_from, dtype=np.int64)
    odo_to = np.asarray(odo_to, dtype=np.int64)
    forward = odo_to == odo_from + 1
    into = np.where(forward, odo_to, odo_from)
    Z[into] = measured
    S[into] = covariance
    reverse(group, Z, S, np.isin(np.arange(N), into[~forward]))
    start[into] = False
    start[0] = True
    segment = np.cumsum(start) - 1
    T = np.empty((N, m, m))
    P = np.empty((N, n, n))
    _chain_kernel(group, Z, S, start, T, P)
    return Chain(group, segment.astype(np.int64), T, P)


def gate_chi2(ch: Chain, a: np.ndarray, b: np.ndarray, Z: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(C,) χ² of each closure a[k] → b[k] (measured Z (C, m, m), covariance S (C, n, n))
    against the odometry between its ends; NaN where a and b are in different segments."""
    a = np.ascontiguousarray(a, dtype=np.int64)
    b = np.ascontiguousarray(b, dtype=np.int64)
    out = np.full(a.shape[0], np.nan)
    same = ch.segment[a] == ch.segment[b]
    idx = np.flatnonzero(same)
    if idx.size:
        res = np.empty(idx.size)
        args = (ch.group, ch.T, ch.P, a[idx], b[idx], np.ascontiguousarray(Z[idx]), np.ascontiguousarray(S[idx]), res)
        if parallel(idx.size, S.shape[1]):
            _gate_kernel(*args)
        else:
            _gate_range(*args, 0, idx.size)
        out[idx] = res
    return out


def pair_chi2(ch: Chain, a, b, Z, S, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """(K,) χ² of the cycle of closures ``first[k]`` and ``second[k]`` (indices into a, b, Z, S)
    with the odometry between their ends; the four ends must be in one segment."""
    out = np.empty(first.shape[0])
    if first.size:
        args = (ch.group, ch.T, ch.P, np.ascontiguousarray(a, dtype=np.int64), np.ascontiguousarray(b, dtype=np.int64),
                np.ascontiguousarray(Z), np.ascontiguousarray(S), np.ascontiguousarray(first, dtype=np.int64),
                np.ascontiguousarray(second, dtype=np.int64), out)
        if parallel(first.size, S.shape[1]):
            _pair_kernel(*args)
        else:
            _pair_range(*args, 0, first.size)
    return out


@kernel
def _near_pairs_kernel(order, a, b, window, first, second):
    """Pairs (i, j) of closures, i before j in ``order`` (sorted by a), with |a_i − a_j| ≤ window
    and |b_i − b_j| ≤ window; returns how many were written (up to first.shape[0])."""
    count = 0
    C = order.shape[0]
    for x in range(C):
        i = order[x]
        y = x + 1
        while y < C and a[order[y]] - a[i] <= window:
            j = order[y]
            if abs(b[j] - b[i]) <= window:
                if count < first.shape[0]:
                    first[count] = i
                    second[count] = j
                count += 1
            y += 1
    return count


def near_pairs(a: np.ndarray, b: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Every pair of closures (a_i → b_i, oriented a < b) whose ends are both within ``window``
    poses of the other's: the pairs whose cycle is short enough to be informative.
    Returns (first, second), each (K,) int64."""
    a = np.ascontiguousarray(a, dtype=np.int64)
    b = np.ascontiguousarray(b, dtype=np.int64)
    order = np.argsort(a, kind="stable")
    size = max(16, 8 * a.shape[0])
    while True:
        first = np.empty(size, dtype=np.int64)
        second = np.empty(size, dtype=np.int64)
        count = _near_pairs_kernel(order, a, b, int(window), first, second)
        if count <= size:
            return first[:count], second[:count]
        size = count
