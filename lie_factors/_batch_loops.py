"""Whole-graph numba loops of the batch solver, over the factors' own kernels.

Every loop is a cached top-level kernel taking the group tag ``g``
(:mod:`lie_factors._dispatch`: each group compiles its own specialization,
holding only its own cores); the per-factor work is
:func:`lie_factors.factors.between` / :func:`~lie_factors.factors.prior` (error
and Jacobians) and their ``*_error`` halves, so no formula is repeated here.
Arrays: ``X`` (N, m, m) poses of one group; ``i1``, ``i2`` (F,) indices into
``X``; ``Minv``/``Pinv`` (F, m, m); ``AdMinv`` (F, n, n); ``R`` (F, n, n)
whitening; outputs ``A1``, ``A2`` (F, n, n) and ``b`` (F, n).
"""

from __future__ import annotations

import numpy as np

from . import _dispatch
from . import factors as _factors
from ._jit import kernel


@kernel
def _whiten_residual(Rf, e, out):
    """out = −Rf·e (the right-hand side b); returns ½‖Rf·e‖²."""
    total = 0.0
    for r in range(Rf.shape[0]):
        acc = 0.0
        for k in range(e.shape[0]):
            acc += Rf[r, k] * e[k]
        out[r] = -acc
        total += 0.5 * acc * acc
    return total


@kernel
def _whiten_jacobian(Rf, H, out):
    """out = Rf·H."""
    n = H.shape[1]
    for r in range(Rf.shape[0]):
        for c in range(n):
            acc = 0.0
            for k in range(H.shape[0]):
                acc += Rf[r, k] * H[k, c]
            out[r, c] = acc


@kernel
def _between_lin(g, X, i1, i2, Minv, AdMinv, R, A1, A2, b):
    """Whitened A1 = R·H1, A2 = R·H2, b = −R·e for every between factor; returns Σ ½‖R e‖²."""
    n = AdMinv.shape[1]
    e = np.empty(n)
    H1 = np.empty((n, n))
    H2 = np.empty((n, n))
    total = 0.0
    for f in range(i1.shape[0]):
        _factors.between(g, Minv[f], AdMinv[f], X[i1[f]], X[i2[f]], e, H1, H2)
        total += _whiten_residual(R[f], e, b[f])
        _whiten_jacobian(R[f], H1, A1[f])
        _whiten_jacobian(R[f], H2, A2[f])
    return total


@kernel
def _prior_lin(g, X, i1, Pinv, R, A1, b):
    n = R.shape[1]
    e = np.empty(n)
    H = np.empty((n, n))
    total = 0.0
    for f in range(i1.shape[0]):
        _factors.prior(g, Pinv[f], X[i1[f]], e, H)
        total += _whiten_residual(R[f], e, b[f])
        _whiten_jacobian(R[f], H, A1[f])
    return total


@kernel
def _between_err(g, X, i1, i2, Minv, R):
    """Σ ½‖R·Log(M⁻¹·X1⁻¹·X2)‖² (no Jacobians)."""
    e = np.empty(R.shape[2])
    scratch = np.empty(R.shape[1])
    total = 0.0
    for f in range(i1.shape[0]):
        _factors.between_error(g, Minv[f], X[i1[f]], X[i2[f]], e)
        total += _whiten_residual(R[f], e, scratch)
    return total


@kernel
def _prior_err(g, X, i1, Pinv, R):
    e = np.empty(R.shape[2])
    scratch = np.empty(R.shape[1])
    total = 0.0
    for f in range(i1.shape[0]):
        _factors.prior_error(g, Pinv[f], X[i1[f]], e)
        total += _whiten_residual(R[f], e, scratch)
    return total


@kernel
def _retract(g, X, delta, offsets, out):
    """out[i] = X[i]·Exp(delta[offsets[i] : offsets[i] + n]) (GTSAM's retract)."""
    n = _dispatch.dim(g)
    m = X.shape[1]
    D = np.empty((m, m))
    x = np.empty(n)
    for i in range(X.shape[0]):
        o = offsets[i]
        for k in range(n):
            x[k] = delta[o + k]
        _dispatch.exp(g, x, D)
        _dispatch.compose(g, X[i], D, out[i])


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


def bound_to(spec):
    """(between_lin, prior_lin, between_err, prior_err, retract, relative_log) bound to one group."""
    g = spec.group
    return (
        lambda *a: _between_lin(g, *a),
        lambda *a: _prior_lin(g, *a),
        lambda *a: _between_err(g, *a),
        lambda *a: _prior_err(g, *a),
        lambda *a: _retract(g, *a),
        lambda *a: _relative_log(g, *a),
    )


@kernel
def linear_error2(A1, A2, b, o1, o2, delta):
    """Σ ½‖A1·δ1 + A2·δ2 − b‖² for between factors (rows of any count)."""
    total = 0.0
    n = A1.shape[2]
    for f in range(A1.shape[0]):
        for r in range(A1.shape[1]):
            acc = -b[f, r]
            for c in range(n):
                acc += A1[f, r, c] * delta[o1[f] + c] + A2[f, r, c] * delta[o2[f] + c]
            total += 0.5 * acc * acc
    return total


@kernel
def linear_error1(A1, b, o1, delta):
    total = 0.0
    n = A1.shape[2]
    for f in range(A1.shape[0]):
        for r in range(A1.shape[1]):
            acc = -b[f, r]
            for c in range(n):
                acc += A1[f, r, c] * delta[o1[f] + c]
            total += 0.5 * acc * acc
    return total


@kernel
def col_sumsq(A, o, diag):
    """diag[o[f] + c] += Σ_r A[f, r, c]² (Hessian diagonal of whitened Jacobian blocks)."""
    for f in range(A.shape[0]):
        for c in range(A.shape[2]):
            s = 0.0
            for r in range(A.shape[1]):
                s += A[f, r, c] * A[f, r, c]
            diag[o[f] + c] += s

