"""D_exp from its power series, for any algebra adjoint matrix: the test oracle.

``dexp(ad_x) = sum_{i>=0} ad_x^i / (i+1)!`` (Eade, "Derivative of the
Exponential Map", Eq. 35). Nothing here knows about a particular group, so it
shares no code with the closed forms of the group modules and can check them.

The series is summed on the augmented matrix ``M = [[A, I], [0, 0]]``, whose
power series is ``exp(M) = [[exp(A), dexp(A)], [0, I]]``. Summing it directly
for ``|A|`` of order 10 would let float64 terms of size 10^4 cancel, so the
sum is taken for ``M / 2^s`` (norm below 1/2, where 20 terms reach float64
precision) and squared ``s`` times: squaring ``exp(M/2^s)`` doubles the
argument exactly, so the top-right block of the result is still the series.
"""

from __future__ import annotations

import numpy as np

_TERMS = 20  # ||M/2^s|| <= 1/2: the remainder after 20 terms is < 2^-20/20! ~ 4e-25


def dexp(ad: np.ndarray) -> np.ndarray:
    """Sum ad^i/(i+1)! for ``ad`` of shape (..., n, n); returns (..., n, n)."""
    A = np.asarray(ad, dtype=np.float64)
    if A.ndim < 2 or A.shape[-1] != A.shape[-2]:
        raise ValueError(f"ad: expected shape (..., n, n), got {A.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError("ad: contains NaN or inf")
    n = A.shape[-1]
    batch = A.shape[:-2]
    M = np.zeros(batch + (2 * n, 2 * n))
    M[..., :n, :n] = A
    M[..., :n, n:] = np.eye(n)
    norm = np.max(np.sum(np.abs(M), axis=-1)) if M.size else 0.0
    s = max(0, int(np.ceil(np.log2(norm / 0.5)))) if norm > 0.5 else 0
    Ms = M / 2.0**s
    E = np.broadcast_to(np.eye(2 * n), M.shape).copy()
    term = E.copy()
    for k in range(1, _TERMS + 1):
        term = term @ Ms / k
        E = E + term
    for _ in range(s):
        E = E @ E
    return E[..., :n, n:]


def dlog(ad: np.ndarray) -> np.ndarray:
    """Numerical inverse of :func:`dexp` (the oracle for the closed-form dlog)."""
    return np.linalg.inv(dexp(ad))
