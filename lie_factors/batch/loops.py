"""Whole-graph numba loops over the factors' own kernels: linearize, evaluate, retract.

Every loop is a cached top-level kernel taking the group tag ``g``
(:mod:`lie_factors.kernels.dispatch`: one specialization per group, holding only
that group's cores); the per-factor work is
:func:`lie_factors.factors.between` / :func:`~lie_factors.factors.prior` (error
and Jacobians) and their ``*_error`` halves, so no formula is repeated here.

Arrays: ``X`` (N, m, m) elements of one group; ``i1``, ``i2`` (F,) indices into
``X``; ``Minv``/``Pinv`` (F, m, m); ``R`` (U, n, n) whitening matrices and ``ridx``
(F,) the one of each factor (a group's factors are handed to the linearizations as one
:class:`Between` or :class:`Prior` of these arrays); outputs ``A1``, ``A2`` (F, n, n),
``b`` (F, n) and ``sq`` (F,), the
squared whitened residual norm ‖R·e‖² of every factor (the per-factor array a
robust reweighting needs; the Gaussian error is ½·Σ sq).

The loops over factors are ``prange`` loops over contiguous chunks (scratch
allocated once per chunk), so they use every numba thread; each factor writes
only its own outputs, so there are no races.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numba
import numpy as np
from numba import prange

from ..kernels import dispatch as _dispatch
from .. import factors as _factors
from ..kernels.jit import kernel, parallel_kernel

#: Factors per parallel chunk: large enough that thread start-up and scratch allocation vanish.
CHUNK = 256

#: ``i1`` of a group of priors: no first variable.
_NO_INDEX = np.zeros(0, dtype=np.int64)


class Between(NamedTuple):
    """A group's between factors, as the linearization kernels take them: factor f joins
    ``X[i1[f]]`` to ``X[i2[f]]``, measured M with ``Minv[f]`` = M⁻¹, whitened by ``R[ridx[f]]``."""

    i1: np.ndarray
    i2: np.ndarray
    Minv: np.ndarray
    R: np.ndarray
    ridx: np.ndarray


class Prior(NamedTuple):
    """A group's priors: factor f on ``X[i1[f]]``, ``Pinv[f]`` = P⁻¹, whitened by ``R[ridx[f]]``."""

    i1: np.ndarray
    Pinv: np.ndarray
    R: np.ndarray
    ridx: np.ndarray


@kernel
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


@kernel
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
def _between_lin_range(g, X, fs, A1, A2, b, sq, f0, f1):
    """:func:`_between_lin` on the factors f0 … f1 − 1 of ``fs`` (a :class:`Between`)."""
    n = fs.R.shape[1]
    e = np.empty(n)
    H1 = np.empty((n, n))
    H2 = np.empty((n, n))
    Ad = np.empty((n, n))
    for f in range(f0, f1):
        _dispatch.Ad(g, fs.Minv[f], Ad)
        _factors.between(g, fs.Minv[f], Ad, X[fs.i1[f]], X[fs.i2[f]], e, H1, H2)
        Rf = fs.R[fs.ridx[f]]
        sq[f] = whiten_residual(Rf, e, b[f])
        whiten_jacobian(Rf, H1, A1[f])
        whiten_jacobian(Rf, H2, A2[f])


@parallel_kernel
def _between_lin(g, X, fs, A1, A2, b, sq):
    """Whitened A1 = R·H1, A2 = R·H2, b = −R·e and sq = ‖R e‖² for every between factor of
    ``fs`` (a :class:`Between`; R = R[ridx[f]]; Ad(M⁻¹) from M⁻¹ by the factors' own
    construction core)."""
    F = fs.i1.shape[0]
    for c in prange((F + CHUNK - 1) // CHUNK):
        _between_lin_range(g, X, fs, A1, A2, b, sq, c * CHUNK, min(F, (c + 1) * CHUNK))


@kernel
def _prior_lin_range(g, X, fs, A1, b, sq, f0, f1):
    """:func:`_prior_lin` on the factors f0 … f1 − 1 of ``fs`` (a :class:`Prior`)."""
    n = fs.R.shape[1]
    e = np.empty(n)
    H = np.empty((n, n))
    for f in range(f0, f1):
        _factors.prior(g, fs.Pinv[f], X[fs.i1[f]], e, H)
        Rf = fs.R[fs.ridx[f]]
        sq[f] = whiten_residual(Rf, e, b[f])
        whiten_jacobian(Rf, H, A1[f])


@parallel_kernel
def _prior_lin(g, X, fs, A1, b, sq):
    F = fs.i1.shape[0]
    for c in prange((F + CHUNK - 1) // CHUNK):
        _prior_lin_range(g, X, fs, A1, b, sq, c * CHUNK, min(F, (c + 1) * CHUNK))


@parallel_kernel
def _errors(g, X, i1, i2, Minv, R, ridx, sq):
    """sq[f] = ‖R·e‖² (no Jacobians), e = Log(M⁻¹·X1⁻¹·X2) with X1 = X[i1[f]], X2 = X[i2[f]]; for
    priors (``i1`` empty) e = Log(P⁻¹·X2), P⁻¹ = Minv[f]."""
    n = R.shape[2]
    F = i2.shape[0]
    prior = i1.shape[0] == 0
    for c in prange((F + CHUNK - 1) // CHUNK):
        e = np.empty(n)
        scratch = np.empty(R.shape[1])
        for f in range(c * CHUNK, min(F, (c + 1) * CHUNK)):
            if prior:
                _factors.prior_error(g, Minv[f], X[i2[f]], e)
            else:
                _factors.between_error(g, Minv[f], X[i1[f]], X[i2[f]], e)
            sq[f] = whiten_residual(R[ridx[f]], e, scratch)


@kernel
def _retract_range(g, X, delta, offsets, out, i0, i1):
    """:func:`_retract` on the elements i0 … i1 − 1."""
    n = _dispatch.dim(g)
    m = X.shape[1]
    D = np.empty((m, m))
    x = np.empty(n)
    for i in range(i0, i1):
        o = offsets[i]
        if o < 0:
            out[i] = X[i]
            continue
        for k in range(n):
            x[k] = delta[o + k]
        _dispatch.exp(g, x, D)
        _dispatch.compose(g, X[i], D, out[i])


@parallel_kernel
def _retract(g, X, delta, offsets, out):
    """out[i] = X[i]·Exp(delta[offsets[i] : offsets[i] + n]) (GTSAM's retract); offset −1: unchanged."""
    N = X.shape[0]
    for c in prange((N + CHUNK - 1) // CHUNK):
        _retract_range(g, X, delta, offsets, out, c * CHUNK, min(N, (c + 1) * CHUNK))


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
        codes[i] = _factors.between_setup(g, M[i], Minv[i], Ad)


class GroupLoops:
    """The loops above bound to one group (``spec.group``, a :mod:`lie_factors.kernels.dispatch` tag):
    ``between_lin(X, i1, i2, Minv, R, ridx, A1, A2, b, sq)`` is :func:`_between_lin` on
    ``Between(i1, i2, Minv, R, ridx)``, ``prior_lin(X, i1, Pinv, R, ridx, A1, b, sq)``
    :func:`_prior_lin` on ``Prior(i1, Pinv, R, ridx)``, ``retract(*a)`` ``_retract(g, *a)``,
    and so on; ``between_err`` and ``prior_err`` are :func:`_errors`.  ``serial=True``: the
    linearizations and the retraction run on the calling thread, one compiled call with no
    fork and join (for the few factors of an incremental update, where starting numba's
    threads costs more than the work)."""

    def __init__(self, spec, serial: bool = False):
        self.g = spec.group
        self._serial = serial
        for name in ("retract", "relative_log"):
            setattr(self, name, functools.partial(globals()[f"_{name}"], self.g))
        if serial:
            g = self.g
            self.retract = lambda X, *a: _retract_range(g, X, *a, 0, X.shape[0])

    def between_lin(self, X, i1, i2, Minv, R, ridx, A1, A2, b, sq):
        fs = Between(i1, i2, Minv, R, ridx)
        if self._serial:
            _between_lin_range(self.g, X, fs, A1, A2, b, sq, 0, i1.shape[0])
        else:
            _between_lin(self.g, X, fs, A1, A2, b, sq)

    def prior_lin(self, X, i1, Pinv, R, ridx, A1, b, sq):
        fs = Prior(i1, Pinv, R, ridx)
        if self._serial:
            _prior_lin_range(self.g, X, fs, A1, b, sq, 0, i1.shape[0])
        else:
            _prior_lin(self.g, X, fs, A1, b, sq)

    def between_err(self, X, i1, i2, Minv, R, ridx, sq):
        _errors(self.g, X, i1, i2, Minv, R, ridx, sq)

    def prior_err(self, X, i1, Pinv, R, ridx, sq):
        _errors(self.g, X, _NO_INDEX, i1, Pinv, R, ridx, sq)

    def setup(self, M):
        """(M⁻¹ (N, m, m), check codes (N,)) of elements ``M`` (N, m, m)."""
        M = np.ascontiguousarray(M, dtype=np.float64)
        N, m = M.shape[0], M.shape[1]
        Minv = np.empty((N, m, m))
        codes = np.empty(N, dtype=np.int64)
        if N:
            _setup(self.g, M, Minv, codes)
        return Minv, codes


def threads() -> int:
    """numba threads the parallel loops use (``numba.set_num_threads`` changes it)."""
    return numba.get_num_threads()
