"""CHOLMOD's sparse Cholesky through cvxopt: whether it is there, and one-shot solves.

cvxopt's wheels bundle CHOLMOD (SuiteSparse) and OpenBLAS.  The batch solver
keeps a symbolic analysis across iterations (:class:`lie_factors.batch.solvers.CholmodSolver`);
the initializers solve a system once (:func:`solve_spd`); the final check of loop closures
reads the factor itself (:func:`lower_factor`).  Neither numba nor
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


def lower_factor(n: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray):
    """The Cholesky factor of a symmetric positive definite A (n × n, lower triangle as triplets
    with rows ≥ cols): P·A·Pᵀ = L·Lᵀ with CHOLMOD's fill-reducing P.

    Returns (perm, colptr, rowind, values): ``perm`` (n,) int64 with (P·x)[k] = x[perm[k]]; L
    (n × n, lower) in compressed columns, each column's diagonal first and its rows ascending.
    The supernodal factorization is asked for because CHOLMOD hands back its simplicial one as
    L·D·Lᵀ (D on L's diagonal); cvxopt's ``getfactor`` converts a supernodal factor to L·Lᵀ.
    Raises ``numpy.linalg.LinAlgError`` if A is not positive definite.
    """
    from cvxopt import cholmod, matrix, spmatrix

    A = spmatrix(matrix(np.ascontiguousarray(vals, dtype=np.float64)),
                 matrix(np.ascontiguousarray(rows, dtype=np.int64)),
                 matrix(np.ascontiguousarray(cols, dtype=np.int64)), (n, n))
    saved = dict(cholmod.options)  # a module-level dict: restored afterwards
    cholmod.options["supernodal"] = 2
    try:
        F = cholmod.symbolic(A, uplo="L")
        cholmod.numeric(A, F)
    except ArithmeticError as exc:
        raise np.linalg.LinAlgError(f"the matrix is not positive definite (CHOLMOD: {exc})") from None
    finally:
        cholmod.options.clear()
        cholmod.options.update(saved)
    p = matrix(np.arange(n, dtype=np.float64))
    cholmod.solve(F, p, sys=7)
    perm = np.rint(np.array(p).reshape(-1)).astype(np.int64)
    colptr, rowind, values = (np.array(x).reshape(-1) for x in cholmod.getfactor(F).CCS)
    return perm, colptr.astype(np.int64), rowind.astype(np.int64), values.astype(np.float64)


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
