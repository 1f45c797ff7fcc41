"""Writing whitened blocks straight into GTSAM JacobianFactors' own storage.

gtsam's ``JacobianFactor.getA()``/``getb()`` return numpy views of the factor's
(column-major) storage. The batch optimizer creates its JacobianFactors once and,
at every linearization, writes the new whitened blocks into that storage from
numba, instead of constructing ~3 µs Python→C++ objects per factor and
iteration. :func:`pointers` checks the layout on a sample of the factors and
returns None where a gtsam build hands out copies, in which case the optimizer
rebuilds the graph each iteration instead. The caller must keep the factors
alive as long as it uses the pointers.
"""

from __future__ import annotations

import numba
import numpy as np
from numba.core import cgutils
from numba.core import types as _nbtypes
from numba.extending import intrinsic

from ._jit import kernel


@intrinsic
def _voidptr(typingctx, addr):
    if not isinstance(addr, _nbtypes.Integer):
        return None

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], cgutils.voidptr_t)

    return _nbtypes.voidptr(addr), codegen


@kernel
def scatter2(A1, A2, b, ptrA, ldA, ptrb):
    """Factor f's [A1 | A2] (column-major, leading dimension ldA[f]) and b ← arrays."""
    n = A1.shape[1]
    for f in range(A1.shape[0]):
        A = numba.carray(_voidptr(ptrA[f]), (2 * n, ldA[f]), np.float64)
        for c in range(n):
            for r in range(n):
                A[c, r] = A1[f, r, c]
                A[n + c, r] = A2[f, r, c]
        bb = numba.carray(_voidptr(ptrb[f]), (n,), np.float64)
        for r in range(n):
            bb[r] = b[f, r]


@kernel
def scatter1(A1, b, ptrA, ldA, ptrb):
    n = A1.shape[1]
    for f in range(A1.shape[0]):
        A = numba.carray(_voidptr(ptrA[f]), (n, ldA[f]), np.float64)
        for c in range(n):
            for r in range(n):
                A[c, r] = A1[f, r, c]
        bb = numba.carray(_voidptr(ptrb[f]), (n,), np.float64)
        for r in range(n):
            bb[r] = b[f, r]


@kernel
def write_diagonal(ptrA, ldA, dims, offsets, damp):
    """Damping factor i (A = diag, dims[i] × dims[i]) ← diag(damp[offsets[i]:+dims[i]]); NaN → 0."""
    for i in range(ptrA.shape[0]):
        d = dims[i]
        A = numba.carray(_voidptr(ptrA[i]), (d, ldA[i]), np.float64)
        for j in range(d):
            v = damp[offsets[i] + j]
            A[j, j] = 0.0 if v != v else v


@kernel
def _addr(a):
    """Address of an array's first element (5× cheaper than ``a.ctypes.data``)."""
    return a.ctypes.data


def pointers(fs, ncols: int):
    """(ptrA, ldA, ptrb) of JacobianFactors, or None if gtsam does not hand out views.

    All factors of a list have the same shape (``ncols`` A columns), so the
    layout is checked on a sample: A column-major with leading dimension ld, b
    the next column of the same VerticalBlockMatrix (ptrb = ptrA + 8·ld·ncols).
    """
    n = len(fs)
    As = [f.getA() for f in fs]
    if not n:
        return np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0, np.int64)
    a0 = As[0]
    if a0.flags.owndata or not a0.flags.writeable or a0.strides[0] != 8 or a0.strides[1] % 8:
        return None
    ld = a0.strides[1] // 8
    ptrA = np.fromiter((_addr(a) for a in As), dtype=np.int64, count=n)
    if ptrA[0] != a0.ctypes.data:
        return None
    ptrb = ptrA + 8 * ld * ncols
    for i in sorted({0, n // 3, n // 2, n - 1}):
        a, bv = As[i], fs[i].getb()
        if (a.strides != a0.strides or a.shape != a0.shape or bv.flags.owndata or bv.strides[0] != 8
                or bv.ctypes.data != ptrb[i]):
            return None
    return ptrA, np.full(n, ld, dtype=np.int64), ptrb
