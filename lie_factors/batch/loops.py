"""Whole-graph numba loops over the factors' own kernels: linearize, evaluate, retract.

Every loop is a cached top-level kernel taking the group tag ``g``
(:mod:`lie_factors.kernels.dispatch`: one specialization per group, holding only
that group's cores); the per-factor work is the factors' own
(:mod:`lie_factors.kernels.relative`: the relative element whose Log is the error, the
Jacobians), so no formula is repeated here.

Arrays: ``X`` (N, m, m) elements of one group; ``i1``, ``i2`` (F,) indices into
``X``; ``Minv``/``Pinv`` (F, m, m); ``R`` (U, n, n) whitening matrices and ``ridx``
(F,) the one of each factor (a group's factors are handed to the kernel as one
:class:`Factors` of these arrays); outputs ``A1``, ``A2`` (F, n, n),
``b`` (F, n) and ``sq`` (F,), the
squared whitened residual norm ‖R·e‖² of every factor (the per-factor array a
robust reweighting needs; the Gaussian error is ½·Σ sq).

Each loop is written once, as a kernel over a range of factors (or elements) that runs
on the calling thread, and wrapped by a ``prange`` loop over contiguous chunks of that
range (scratch allocated once per chunk) that uses every numba thread; each factor writes
only its own outputs, so there are no races.  :class:`GroupLoops` runs a call on the
threads only when its work reaches :data:`PARALLEL_MIN_WORK`: below it the fork and join
cost more than a second thread saves, and a run that never reaches it never compiles the
parallel wrappers (numba spends seconds on each, the most of any kernel here).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
from numba import prange

from ..kernels import dispatch as _dispatch
from ..kernels import relative as _relative
from ..kernels.checks import OK as ELEMENT_OK
from ..kernels.retraction import retract_range
from ..kernels.jit import inline_kernel, kernel, parallel_kernel

#: Factors per parallel chunk: large enough that thread start-up and scratch allocation vanish.
CHUNK = 256

#: Factors (or elements) × (tangent dimension)² below which a loop runs on the calling thread:
#: there numba's fork and join cost more than the second thread saves (docs/batch.md).
PARALLEL_MIN_WORK = 500_000



#: ``i2`` of a group of priors: no second variable.
_NO_INDEX = np.zeros(0, dtype=np.int64)


def _none3(n: int) -> np.ndarray:
    """The Jacobian outputs of an evaluation without Jacobians (never written)."""
    return np.empty((0, n, n))


def _none2(n: int) -> np.ndarray:
    return np.empty((0, n))


class Factors(NamedTuple):
    """A group's factors of one kind, as the kernels take them: between factor f joins
    ``X[i1[f]]`` to ``X[i2[f]]``, measured M with ``C[f]`` = M⁻¹; a prior (``i2`` empty) is on
    ``X[i1[f]]``, with ``C[f]`` = P⁻¹; factor f is whitened by ``R[ridx[f]]``."""

    i1: np.ndarray
    i2: np.ndarray
    C: np.ndarray
    R: np.ndarray
    ridx: np.ndarray


@inline_kernel
def whiten_residual(Rf, e, out):
    """out = −Rf·e (the right-hand side b); returns ‖Rf·e‖²."""
    total = 0.0
    for r in range(Rf.shape[0]):
        acc = 0.0
        for k in range(e.shape[0]):
            acc += Rf[r, k] * e[k]
        out[r] = -acc
        total += acc * acc
    return total


@inline_kernel
def whiten_jacobian(Rf, H, out):
    """out = Rf·H."""
    n = H.shape[1]
    for r in range(Rf.shape[0]):
        for c in range(n):
            acc = 0.0
            for k in range(H.shape[0]):
                acc += Rf[r, k] * H[k, c]
            out[r, c] = acc


@kernel
def factor_range(g, X, fs, A1, A2, b, sq, f0, f1, jacobians):
    """:func:`_factor_chunks` on the factors f0 … f1 − 1 of ``fs``."""
    n = fs.R.shape[1]
    m = X.shape[1]
    prior = fs.i2.shape[0] == 0
    E = np.empty((m, m))
    e = np.empty(n)
    H1 = np.empty((n, n))
    H2 = np.empty((n, n))
    Ad = np.empty((n, n))
    scratch = np.empty(n)
    for f in range(f0, f1):
        Rf = fs.R[fs.ridx[f]]
        # one call of each core for both kinds: the kernel holds one copy of each
        if prior:
            _relative.prior_relative(g, fs.C[f], X[fs.i1[f]], E)
        else:
            _relative.between_relative(g, fs.C[f], X[fs.i1[f]], X[fs.i2[f]], E)
        _dispatch.log(g, E, e)
        if not jacobians:
            sq[f] = whiten_residual(Rf, e, scratch)
            continue
        sq[f] = whiten_residual(Rf, e, b[f])
        _relative.prior_jacobian(g, e, H2)  # dlog(−e): a prior's Jacobian, a between factor's second
        if prior:
            whiten_jacobian(Rf, H2, A1[f])
            continue
        _dispatch.Ad(g, fs.C[f], Ad)
        _relative.between_first_jacobian(g, Ad, e, H1)
        whiten_jacobian(Rf, H1, A1[f])
        whiten_jacobian(Rf, H2, A2[f])


@parallel_kernel
def _factor_chunks(g, X, fs, A1, A2, b, sq, jacobians):
    """sq = ‖R e‖² for every factor of ``fs`` (a :class:`Factors`; R = R[ridx[f]]): e =
    Log(M⁻¹·X1⁻¹·X2) of a between factor, Log(P⁻¹·X) of a prior; with ``jacobians`` also the
    whitened Jacobians A1 = R·H1 (and A2 = R·H2 of a between factor) and b = −R·e (Ad(M⁻¹) from
    M⁻¹ by the factors' own construction core).  One kernel for both kinds, with and without
    Jacobians: a group's factors compile once."""
    F = fs.i1.shape[0]
    for c in prange((F + CHUNK - 1) // CHUNK):
        factor_range(g, X, fs, A1, A2, b, sq, c * CHUNK, min(F, (c + 1) * CHUNK), jacobians)


@parallel_kernel
def _retract(g, X, delta, offsets, out):
    """out[i] = X[i]·Exp(delta[offsets[i] : offsets[i] + n]) (GTSAM's retract; :func:`retract_range`
    on numba's threads); offset −1: unchanged."""
    N = X.shape[0]
    for c in prange((N + CHUNK - 1) // CHUNK):
        retract_range(g, X, delta, offsets, out, c * CHUNK, min(N, (c + 1) * CHUNK))


@kernel
def _relative_log(g, X0, X, out):
    """out[i] = Log(X0[i]⁻¹·X[i]) (no validation: GTSAM values drift off SO(n) by ~1e-9)."""
    m = X.shape[1]
    inv = np.empty((m, m))
    rel = np.empty((m, m))
    for i in range(X.shape[0]):
        _dispatch.inverse(g, X0[i], inv)
        _dispatch.compose(g, inv, X[i], rel)
        _dispatch.log(g, rel, out[i])


@kernel
def _setup(g, M, Minv, codes):
    """Every factor's construction: Minv[i] = M[i]⁻¹, codes[i] the check of M[i]
    (``factors.between_setup``, the kernel each factor object runs; its Ad(M⁻¹) is
    recomputed where a linearization needs it)."""
    n = _dispatch.dim(g)
    Ad = np.empty((n, n))
    for i in range(M.shape[0]):
        codes[i] = _relative.between_setup(g, M[i], Minv[i], Ad)


@inline_kernel
def upper_cholesky(A, R):
    """R (n, n) upper triangular with RᵀR = A, from A's lower triangle (as LAPACK's ``potrf``
    reads it; A symmetric positive definite).  False, R unfinished, when a pivot is not
    positive (or NaN): A is not positive definite."""
    n = A.shape[0]
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= R[k, j] * R[k, j]
        if not s > 0.0:
            return False
        d = np.sqrt(s)
        R[j, j] = d
        for i in range(j + 1, n):
            t = A[i, j]
            for k in range(j):
                t -= R[k, j] * R[k, i]
            R[j, i] = t / d
        for i in range(j):
            R[j, i] = 0.0
    return True


@kernel
def whiten_all(A, R):
    """R[i] = :func:`upper_cholesky` of A[i] for A (N, n, n); the first i whose A[i] is not
    positive definite, or −1."""
    for i in range(A.shape[0]):
        if not upper_cholesky(A[i], R[i]):
            return i
    return -1


#: :func:`prepare` status: the factors are ready; a number is not finite; a key is its own
#: neighbour; a measurement is not in the group (``codes``); an information matrix is not
#: positive definite.
READY, NOT_FINITE, SELF_LOOP, NOT_ELEMENT, NOT_DEFINITE = 0, 1, 2, 3, 4


@kernel
def prepare(g, keys, M, info, Minv, R, codes):
    """Check and set up F factors at once: ``keys`` (F, k), measurements ``M`` (F, m, m),
    information ``info`` (F, n, n) → M⁻¹ and the whitening R (RᵀR = Λ) in ``Minv``, ``R``,
    the element checks in ``codes``.  Returns (status, factor): the first problem in the
    order the checks are stated (every number finite, then no self-loop, then each
    element, then each Λ), as :data:`READY` … :data:`NOT_DEFINITE`."""
    F = M.shape[0]
    for i in range(F):
        for v in M[i].ravel():
            if not np.isfinite(v):
                return NOT_FINITE, i
        for v in info[i].ravel():
            if not np.isfinite(v):
                return NOT_FINITE, i
    if keys.shape[1] == 2:
        for i in range(F):
            if keys[i, 0] == keys[i, 1]:
                return SELF_LOOP, i
    _setup(g, M, Minv, codes)
    for i in range(F):
        if codes[i] != ELEMENT_OK:
            return NOT_ELEMENT, i
    at = whiten_all(info, R)
    if at >= 0:
        return NOT_DEFINITE, at
    return READY, -1


class GroupLoops:
    """The loops above bound to one group (``spec.group``, a :mod:`lie_factors.kernels.dispatch` tag):
    ``between_lin(X, i1, i2, Minv, R, ridx, A1, A2, b, sq)`` and ``prior_lin(X, i1, Pinv, R,
    ridx, A1, b, sq)`` are :func:`_factor_chunks` on ``Factors(i1, i2, Minv, R, ridx)`` (priors: ``i2``
    empty), ``retract(X, delta, offsets, out)``
    :func:`_retract`, ``relative_log`` :func:`_relative_log`.

    ``*_lin`` linearize (Jacobians, right-hand side and squared norms), ``*_err`` evaluate the
    squared norms only; all four run the one kernel :func:`factor_range` (or its chunks).

    A call runs on numba's threads when its factors (or elements) × n² reach
    :data:`PARALLEL_MIN_WORK` and numba has more than one thread, else its range kernel on
    the calling thread, one compiled call with no fork and join; both give the same bits.
    ``serial=True``: always on the calling thread (the few factors of an incremental update).
    """

    def __init__(self, spec, serial: bool = False):
        self.g = spec.group
        self._serial = serial
        self._n = spec.dim

    def _parallel(self, count: int) -> bool:
        return not self._serial and parallel(count, self._n)

    def retract(self, X, delta, offsets, out):
        """out[i] = X[i]·Exp(δ_i) for every element (:func:`_retract`)."""
        if self._parallel(X.shape[0]):
            _retract(self.g, X, delta, offsets, out)
        else:
            retract_range(self.g, X, delta, offsets, out, 0, X.shape[0])

    def relative_log(self, X0, X, out):
        _relative_log(self.g, X0, X, out)

    def between_lin(self, X, i1, i2, Minv, R, ridx, A1, A2, b, sq):
        self._run(X, Factors(i1, i2, Minv, R, ridx), A1, A2, b, sq, True)

    def prior_lin(self, X, i1, Pinv, R, ridx, A1, b, sq):
        self._run(X, Factors(i1, _NO_INDEX, Pinv, R, ridx), A1, _none3(R.shape[1]), b, sq, True)

    def between_err(self, X, i1, i2, Minv, R, ridx, sq):
        n = R.shape[1]
        self._run(X, Factors(i1, i2, Minv, R, ridx), _none3(n), _none3(n), _none2(n), sq, False)

    def prior_err(self, X, i1, Pinv, R, ridx, sq):
        n = R.shape[1]
        self._run(X, Factors(i1, _NO_INDEX, Pinv, R, ridx), _none3(n), _none3(n), _none2(n), sq, False)

    def _run(self, X, fs, A1, A2, b, sq, jacobians):
        if self._parallel(fs.i1.shape[0]):
            _factor_chunks(self.g, X, fs, A1, A2, b, sq, jacobians)
        else:
            factor_range(self.g, X, fs, A1, A2, b, sq, 0, fs.i1.shape[0], jacobians)

    def prepare(self, keys, M, info):
        """(status, factor, M⁻¹ (F, m, m), R (F, n, n), codes (F,)) of F factors: :func:`prepare`."""
        F, m, n = M.shape[0], M.shape[1], info.shape[1]
        Minv, R, codes = np.empty((F, m, m)), np.empty((F, n, n)), np.zeros(F, dtype=np.int64)
        status, at = prepare(self.g, keys, M, info, Minv, R, codes)
        return int(status), int(at), Minv, R, codes

    def setup(self, M):
        """(M⁻¹ (N, m, m), check codes (N,)) of elements ``M`` (N, m, m)."""
        M = np.ascontiguousarray(M, dtype=np.float64)
        N, m = M.shape[0], M.shape[1]
        Minv = np.empty((N, m, m))
        codes = np.empty(N, dtype=np.int64)
        if N:
            _setup(self.g, M, Minv, codes)
        return Minv, codes


def parallel(count: int, n: int) -> bool:
    """Whether a loop over ``count`` items of tangent dimension ``n`` runs on numba's threads:
    when count·n² reaches :data:`PARALLEL_MIN_WORK` and numba has more than one thread."""
    return count * n * n >= PARALLEL_MIN_WORK and threads() > 1


def threads() -> int:
    """numba threads the parallel loops use (``numba.set_num_threads`` changes it)."""
    return numba.get_num_threads()
