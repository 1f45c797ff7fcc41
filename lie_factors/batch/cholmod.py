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


class Factor:
    """One CHOLMOD factorization P·A·Pᵀ = L·D·Lᵀ of an SPD matrix A (n × n), for repeated solves.

    ``solve(rhs)``: x with A x = rhs; ``half(rhs)``: (Z, d) with Z = L⁻¹·P·rhs and d = D⁻¹
    (ones for a supernodal LLᵀ), so that rhsᵀ·A⁻¹·rhs = Zᵀ·diag(d)·Z at the cost of one
    triangular sweep.  ``rhs`` (n,) or (n, m).
    """

    def __init__(self, n: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray):
        from cvxopt import cholmod, matrix, spmatrix

        self.n, self._cholmod, self._matrix = n, cholmod, matrix
        A = spmatrix(matrix(np.ascontiguousarray(vals, dtype=np.float64)),
                     matrix(np.ascontiguousarray(rows, dtype=np.int64)),
                     matrix(np.ascontiguousarray(cols, dtype=np.int64)), (n, n))
        try:
            self._F = cholmod.symbolic(A, uplo="L")
            cholmod.numeric(A, self._F)
        except ArithmeticError as exc:
            raise np.linalg.LinAlgError(f"the matrix is not positive definite (CHOLMOD: {exc})") from None
        D = matrix(np.ones(n))
        cholmod.solve(self._F, D, sys=6)
        self.dinv = np.array(D).reshape(-1)
        if not (np.all(self.dinv > 0) and np.all(np.isfinite(self.dinv))):
            raise np.linalg.LinAlgError("the matrix is not positive definite (a pivot of D is not > 0)")

    def _run(self, rhs, systems) -> np.ndarray:
        b = np.asarray(rhs, dtype=np.float64)
        B = self._matrix(b.reshape(self.n, -1).copy(order="F"))
        for sys in systems:
            self._cholmod.solve(self._F, B, sys=sys)
        x = np.array(B).reshape(b.shape)
        if not np.all(np.isfinite(x)):
            raise np.linalg.LinAlgError("the linear system is singular (non-finite solution)")
        return x

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return self._run(rhs, (0,))

    def half(self, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._run(rhs, (7, 4)), self.dinv


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
