"""CHOLMOD's sparse Cholesky through cvxopt: whether it is there, and one-shot solves.

cvxopt's wheels bundle CHOLMOD (SuiteSparse) and OpenBLAS.  The batch solver
keeps a symbolic analysis across iterations (:class:`lie_factors.batch.solvers.CholmodSolver`);
the initializers solve a system once (:func:`solve_spd`).  Neither numba nor
GTSAM is imported here.
"""

from __future__ import annotations

import numpy as np


def available() -> bool:
    """Whether cvxopt (CHOLMOD) imports."""
    try:
        import cvxopt.cholmod  # noqa: F401
    except ImportError:
        return False
    return True


def solve_spd(n: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """x with A x = rhs, A (n × n) symmetric positive definite given by its lower triangle.

    ``rows``, ``cols``, ``vals`` (K,): triplets with rows ≥ cols, duplicates summed;
    ``rhs`` (n,) or (n, m).  CHOLMOD's sparse Cholesky (AMD ordering).  Raises
    ``numpy.linalg.LinAlgError`` if A is not positive definite or x is not finite.
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
        raise np.linalg.LinAlgError(f"the linear system is not positive definite (CHOLMOD: {exc})") from None
    x = np.array(B).reshape(b.shape)
    if not np.all(np.isfinite(x)):
        raise np.linalg.LinAlgError("the linear system is singular (non-finite solution)")
    return x
