"""The numerical work of Between and Prior factors on any registered group, as compiled code: the
error Log(M⁻¹·X1⁻¹·X2) (a prior: Log(P⁻¹·X)), its Jacobians H1 = −dlog(e)·Ad(M⁻¹), H2 = dlog(−e)
(GTSAM's right Jacobians, ``docs/factors.md``), and a factor's construction (the check of its
measurement, M⁻¹, Ad(M⁻¹)).  Each takes the group tag ``g`` first
(:mod:`lie_factors.kernels.dispatch`); :mod:`lie_factors.factors` (the factor objects), the batch
loops and the smoother run them.  The per-factor formulas are inlined into their callers
(``inline_kernel``): a loop over factors compiles as one function.
"""

from __future__ import annotations

import numpy as np

from . import dispatch as _dispatch
from .checks import ORTHONORMAL_TOL, OK, element_code
from .jit import inline_kernel, kernel


@inline_kernel
def between_relative(g, Minv, X1, X2, E):
    """E = M⁻¹·X1⁻¹·X2 on group ``g`` (a :mod:`lie_factors.kernels.dispatch` tag): a Between
    factor's error is Log(E)."""
    m = X1.shape[0]
    # C-ordered copies: GTSAM hands out Fortran-ordered matrices, the batch
    # loops C-ordered ones; with copies every core is compiled for C only.
    A = np.empty((m, m))
    B = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            A[i, j] = X1[i, j]
            B[i, j] = X2[i, j]
    X1inv = np.empty((m, m))
    rel = np.empty((m, m))
    _dispatch.inverse(g, A, X1inv)
    _dispatch.compose(g, X1inv, B, rel)
    _dispatch.compose(g, Minv, rel, E)


@inline_kernel
def between_error(g, Minv, X1, X2, e):
    """e = Log(M⁻¹·X1⁻¹·X2) on group ``g``."""
    m = X1.shape[0]
    E = np.empty((m, m))
    between_relative(g, Minv, X1, X2, E)
    _dispatch.log(g, E, e)


@inline_kernel
def between(g, Minv, AdMinv, X1, X2, e, H1, H2):
    """Error and Jacobians of a Between factor: H1 = −dlog(e)·Ad(M⁻¹), H2 = dlog(−e)."""
    between_error(g, Minv, X1, X2, e)
    between_jacobians(g, AdMinv, e, H1, H2)


@inline_kernel
def between_jacobians(g, AdMinv, e, H1, H2):
    """The Jacobians of a Between factor at its error ``e``: H1 = −dlog(e)·Ad(M⁻¹), H2 = dlog(−e)
    (:func:`prior_jacobian`'s)."""
    between_first_jacobian(g, AdMinv, e, H1)
    prior_jacobian(g, e, H2)


@inline_kernel
def between_first_jacobian(g, AdMinv, e, H1):
    """H1 = −dlog(e)·Ad(M⁻¹), a Between factor's Jacobian for its first variable."""
    n = e.shape[0]
    D = np.empty((n, n))
    _dispatch.dlog(g, e, D)
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += D[i, k] * AdMinv[k, j]
            H1[i, j] = -acc


@inline_kernel
def prior_relative(g, Pinv, X, E):
    """E = P⁻¹·X on group ``g``: a Prior factor's error is Log(E)."""
    _dispatch.compose(g, Pinv, X, E)


@inline_kernel
def prior_error(g, Pinv, X, e):
    """e = Log(P⁻¹·X) on group ``g``."""
    m = X.shape[0]
    E = np.empty((m, m))
    prior_relative(g, Pinv, X, E)
    _dispatch.log(g, E, e)


@inline_kernel
def prior(g, Pinv, X, e, H):
    """Error and Jacobian of a Prior factor: H = dlog(−e)."""
    prior_error(g, Pinv, X, e)
    prior_jacobian(g, e, H)


@inline_kernel
def prior_jacobian(g, e, H):
    """H = dlog(−e): the Jacobian of a Prior factor at its error ``e``, and a Between factor's
    for its second variable."""
    n = e.shape[0]
    neg = np.empty(n)
    for i in range(n):
        neg[i] = -e[i]
    _dispatch.dlog(g, neg, H)


@kernel
def between_many(g, Minv, AdMinv, X, i1, i2, e, H1, H2):
    """:func:`between` for every factor k of a group: X1 = X[i1[k]], X2 = X[i2[k]] (a prior
    is the Between factor from the identity, stored as one more element of X)."""
    for k in range(i1.shape[0]):
        between(g, Minv[k], AdMinv[k], X[i1[k]], X[i2[k]], e[k], H1[k], H2[k])


@inline_kernel
def check_element(g, X):
    """Validate one (m, m) element of group ``g``; returns OK or the first failure's code.

    Finite entries; rotation block R (d×d) with max|RᵀR − I| ≤ ORTHONORMAL_TOL
    and det R > 0; then the last row [0 … 0 1] (or [0 … 0 s], s > 0, for
    similarity groups): :func:`lie_factors.kernels.checks.element_code`, the check
    the public functions' single-element path runs too.
    """
    return element_code(X, _dispatch.rot_dim(g), _dispatch.corner(g), ORTHONORMAL_TOL)


@kernel
def between_setup(g, M, Minv, AdMinv):
    """Construction of a factor: check M, then Minv = M⁻¹, AdMinv = Ad(M⁻¹).

    Prior factors use it too (they are Between factors from the identity).
    """
    code = check_element(g, M)
    if code == OK:
        m = M.shape[0]
        A = np.empty((m, m))  # C-ordered, like every other input of the cores
        for i in range(m):
            for j in range(m):
                A[i, j] = M[i, j]
        _dispatch.inverse(g, A, Minv)
        _dispatch.Ad(g, Minv, AdMinv)
    return code
