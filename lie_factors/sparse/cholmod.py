"""CHOLMOD's sparse Cholesky (SuiteSparse), the one cvxopt's wheels bundle: a factor kept across
refactorizations (:class:`Cholesky`, whose factor can also be read as arrays), the fill-reducing
order of a block pattern (:func:`block_order`) and one-shot solves (:func:`solve_spd`).

A matrix is given by its lower triangle in compressed sparse columns: ``colptr`` (n + 1,)
and ``rowind`` (nnz,) int32, rows sorted within each column, the values (nnz,) float64
apart, so that one pattern takes many value arrays.

Two ways into CHOLMOD:

* **direct** (where it loads): ctypes calls into the CHOLMOD library cvxopt has loaded, on
  our own arrays.  CHOLMOD factors them where they are: the variables are numbered in a
  fill-reducing order beforehand (:func:`block_order`, CHOLMOD's AMD of the block pattern
  and its postorder), and the factor keeps that natural order, so a numeric
  factorization neither copies nor permutes the matrix (with any other order CHOLMOD
  transposes it twice per factorization, and cvxopt's own API copies it once more).  The
  handful of CHOLMOD's defaults this relies on are checked when the library is loaded
  (:func:`direct_available`); a library that does not show them is used through cvxopt.
* **through cvxopt's API** (``cvxopt.cholmod``): the same factorizations, the matrix
  copied at each one.

Neither numba nor GTSAM is imported here.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import os
import struct
import sys
import weakref

import numpy as np

from ..errors import InputError, NotPositiveDefinite
from ..util.arrays import sorted_unique
from .pivots import PIVOT_TOLERANCE, first_refused
from .supernodes import Supernodes


def available() -> bool:
    """Whether cvxopt (CHOLMOD) imports."""
    try:
        import cvxopt.cholmod  # noqa: F401
    except ImportError:
        return False
    return True


# --------------------------------------------------------------------------- #
# The direct way: CHOLMOD's C API through ctypes (its int32 interface)
# --------------------------------------------------------------------------- #

# cholmod_core.h: itype, xtype, dtype, orderings, solve systems
_INT, _PATTERN, _REAL, _DOUBLE = 0, 0, 1, 0
_ALWAYS_SUPERNODAL = 2  # Common->supernodal: CHOLMOD_SUPERNODAL (1, the default, lets CHOLMOD choose)
_NATURAL, _GIVEN, _AMD, _METIS, _NESDIS = 0, 1, 2, 3, 4
SOLVE_A, SOLVE_L, SOLVE_D, SOLVE_P = 0, 4, 6, 7

#: Bytes reserved for a ``cholmod_common`` (CHOLMOD 3–5 need fewer than 4 KiB).
_COMMON_BYTES = 1 << 14


class _Sparse(ctypes.Structure):
    _fields_ = [("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t), ("nzmax", ctypes.c_size_t),
                ("p", ctypes.c_void_p), ("i", ctypes.c_void_p), ("nz", ctypes.c_void_p),
                ("x", ctypes.c_void_p), ("z", ctypes.c_void_p),
                ("stype", ctypes.c_int), ("itype", ctypes.c_int), ("xtype", ctypes.c_int),
                ("dtype", ctypes.c_int), ("sorted", ctypes.c_int), ("packed", ctypes.c_int)]


class _Dense(ctypes.Structure):
    _fields_ = [("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t), ("nzmax", ctypes.c_size_t),
                ("d", ctypes.c_size_t), ("x", ctypes.c_void_p), ("z", ctypes.c_void_p),
                ("xtype", ctypes.c_int), ("dtype", ctypes.c_int)]


class _Factor(ctypes.Structure):
    """The leading fields of ``cholmod_factor`` (all this module reads)."""
    _fields_ = [("n", ctypes.c_size_t), ("minor", ctypes.c_size_t), ("Perm", ctypes.c_void_p),
                ("ColCount", ctypes.c_void_p), ("IPerm", ctypes.c_void_p), ("nzmax", ctypes.c_size_t),
                ("p", ctypes.c_void_p), ("i", ctypes.c_void_p), ("x", ctypes.c_void_p),
                ("z", ctypes.c_void_p), ("nz", ctypes.c_void_p), ("next", ctypes.c_void_p),
                ("prev", ctypes.c_void_p), ("nsuper", ctypes.c_size_t), ("ssize", ctypes.c_size_t),
                ("xsize", ctypes.c_size_t), ("maxcsize", ctypes.c_size_t), ("maxesize", ctypes.c_size_t),
                ("super", ctypes.c_void_p), ("pi", ctypes.c_void_p), ("px", ctypes.c_void_p),
                ("s", ctypes.c_void_p), ("ordering", ctypes.c_int), ("is_ll", ctypes.c_int),
                ("is_super", ctypes.c_int), ("is_monotonic", ctypes.c_int), ("itype", ctypes.c_int),
                ("xtype", ctypes.c_int), ("dtype", ctypes.c_int)]


class _Common:
    """Offsets of the ``cholmod_common`` fields this module sets or reads (cholmod_core.h), with
    the defaults ``cholmod_start`` gives them: :func:`_check_layout` compares them all."""

    SUPERNODAL, PRINT, NMETHODS, POSTORDER, STATUS, FL, LNZ = 48, 144, 168, 1864, 1972, 1976, 1984
    METHOD, METHOD_SIZE = 184, 168  # method[k]: lnz (+0), fl (+8), ..., ordering (+132)
    DEFAULTS = (("d", 0, 0.0), ("d", 8, 1.2), ("d", 16, 1.2), ("Q", 24, 5), ("Q", 32, 8),
                ("d", 40, 40.0), ("i", SUPERNODAL, 1), ("i", PRINT, 3), ("i", NMETHODS, 0),
                ("i", POSTORDER, 1),
                ("d", METHOD + 16, 10.0), ("d", METHOD + 24, -1.0), ("d", METHOD + 32, 1.0),
                ("Q", METHOD + 72, 200),
                ("i", METHOD + 132, _GIVEN), ("i", METHOD + METHOD_SIZE + 132, _AMD),
                ("i", METHOD + 2 * METHOD_SIZE + 132, _METIS),
                ("i", METHOD + 3 * METHOD_SIZE + 132, _NESDIS),
                ("i", METHOD + 4 * METHOD_SIZE + 132, _NATURAL),
                ("d", 1880, 0.66), ("Q", 1888, 3000), ("i", STATUS, 0), ("d", FL, -1.0), ("d", LNZ, -1.0))

    #: ``Common->status`` values (cholmod_core.h)
    MESSAGES = {-2: "out of memory", -3: "the matrix is too large for CHOLMOD's int32 interface",
                -4: "invalid input", -5: "GPU problem"}


def _loaded_cholmod() -> str | None:
    """The path of the CHOLMOD library cvxopt has loaded into this process, if it can be found."""
    import cvxopt
    import cvxopt.cholmod  # noqa: F401  (loads the library)

    if sys.platform.startswith("linux"):
        try:
            with open("/proc/self/maps") as fh:
                for line in fh:
                    path = line.split()[-1]
                    if os.path.basename(path).startswith("libcholmod") and os.path.isfile(path):
                        return path
        except OSError:
            pass
    root = os.path.dirname(os.path.dirname(os.path.abspath(cvxopt.__file__)))
    for folder in (os.path.join(root, "cvxopt.libs"), os.path.join(os.path.dirname(cvxopt.__file__), ".dylibs")):
        if os.path.isdir(folder):
            for name in sorted(os.listdir(folder)):
                if name.startswith("libcholmod"):
                    return os.path.join(folder, name)
    return None


def _check_layout(common) -> bool:
    raw = common.raw
    return all(struct.unpack_from(fmt, raw, offset)[0] == value for fmt, offset, value in _Common.DEFAULTS)


@functools.lru_cache(maxsize=None)
def _direct():
    """The ctypes handle of CHOLMOD with its prototypes, or None where the direct way does not apply."""
    if os.environ.get("LIE_FACTORS_CHOLMOD") == "cvxopt" or not available():
        return None
    path = _loaded_cholmod()
    if path is None:
        return None
    try:
        lib = ctypes.CDLL(path)
        fac = ctypes.POINTER(_Factor)
        for name, res, args in (
                ("cholmod_start", ctypes.c_int, [ctypes.c_void_p]),
                ("cholmod_finish", ctypes.c_int, [ctypes.c_void_p]),
                ("cholmod_analyze", fac, [ctypes.POINTER(_Sparse), ctypes.c_void_p]),
                ("cholmod_factorize", ctypes.c_int, [ctypes.POINTER(_Sparse), fac, ctypes.c_void_p]),
                ("cholmod_solve", ctypes.POINTER(_Dense), [ctypes.c_int, fac, ctypes.POINTER(_Dense), ctypes.c_void_p]),
                ("cholmod_free_factor", ctypes.c_int, [ctypes.POINTER(fac), ctypes.c_void_p]),
                ("cholmod_copy_factor", fac, [fac, ctypes.c_void_p]),
                ("cholmod_factor_to_sparse", ctypes.POINTER(_Sparse), [fac, ctypes.c_void_p]),
                ("cholmod_free_sparse", ctypes.c_int, [ctypes.POINTER(ctypes.POINTER(_Sparse)), ctypes.c_void_p]),
                ("cholmod_free_dense", ctypes.c_int, [ctypes.POINTER(ctypes.POINTER(_Dense)), ctypes.c_void_p])):
            f = getattr(lib, name)
            f.restype, f.argtypes = res, args
    except (OSError, AttributeError):
        return None
    common = ctypes.create_string_buffer(_COMMON_BYTES)
    if not lib.cholmod_start(common):
        return None
    try:
        if not _check_layout(common):
            return None
    finally:
        lib.cholmod_finish(common)
    return lib


def direct_available() -> bool:
    """Whether CHOLMOD is called directly (see the module docstring); else through cvxopt's API.

    ``LIE_FACTORS_CHOLMOD=cvxopt`` in the environment chooses cvxopt's API.
    """
    return _direct() is not None


def _new_common(lib, ordering: int, postorder: bool):
    """A started ``cholmod_common``: silent, one ordering method, CHOLMOD's own choice between a
    simplicial LDLᵀ and a supernodal LLᵀ."""
    common = ctypes.create_string_buffer(_COMMON_BYTES)
    if not lib.cholmod_start(common):
        raise MemoryError("CHOLMOD could not start")
    struct.pack_into("i", common, _Common.PRINT, 0)
    struct.pack_into("i", common, _Common.NMETHODS, 1)
    struct.pack_into("i", common, _Common.METHOD + 132, ordering)
    struct.pack_into("i", common, _Common.POSTORDER, int(postorder))
    return common


def _failure(common, what: str) -> str:
    status = struct.unpack_from("i", common.raw, _Common.STATUS)[0]
    return f"CHOLMOD's {what} failed: {_Common.MESSAGES.get(status, f'status {status}')}"


def _free(lib, handle, common, owned: list | None = None) -> None:
    if handle:
        if owned:  # L's values are ours: CHOLMOD must not free them
            handle.contents.x = None
            handle.contents.xtype = _PATTERN
            _release_values(owned.pop())
        lib.cholmod_free_factor(ctypes.byref(handle), common)
    lib.cholmod_finish(common)


class _Spare:
    """The value array of the last supernodal factor released inside :func:`reuse_factor_memory`."""

    depth = 0
    array: np.ndarray | None = None


@contextlib.contextmanager
def reuse_factor_memory():
    """Within this scope a released supernodal factor leaves its value array (L's entries) to
    the next factor that fits in it, so that consecutive factors of one graph — an
    initializer's, then the optimizer's — touch that memory once.  Outside it the array is
    freed with its factor."""
    _Spare.depth += 1
    try:
        yield
    finally:
        _Spare.depth -= 1
        if _Spare.depth == 0:
            _Spare.array = None


def _factor_values(size: int) -> np.ndarray:
    """An array of at least ``size`` doubles for L's entries: the spare one if it fits, else a new
    one with its pages touched in order (CHOLMOD's own allocation is first touched factor
    by factor, in no order, which costs page faults on a large factor)."""
    spare, _Spare.array = _Spare.array, None
    if spare is not None and spare.size >= size:
        return spare
    del spare
    out = np.empty(size)
    out.fill(0.0)
    return out


def _release_values(array: np.ndarray) -> None:
    if _Spare.depth:
        _Spare.array = array


def _as_int32(a: np.ndarray, what: str) -> np.ndarray:
    if a.size and int(a.max()) > np.iinfo(np.int32).max:
        raise InputError(f"{what}: more entries than CHOLMOD's int32 interface holds")
    return np.ascontiguousarray(a, dtype=np.int32)


class Cholesky:
    """A CHOLMOD factor of the symmetric matrices with one sparsity pattern.

    ``colptr`` (n + 1,), ``rowind`` (nnz,): the lower triangle in compressed columns
    (int32; kept by reference, so they must stay unchanged).  ``natural``: the matrix is
    numbered in its fill-reducing order already (:func:`block_order`) and is factored in
    that order, in place; otherwise CHOLMOD orders it (AMD) and permutes a copy.  The
    symbolic analysis runs here, once; :meth:`factorize` is a numeric factorization of
    values (nnz,) on this pattern, :meth:`solve` solves with the last one.

    ``supernodal``: CHOLMOD chose a supernodal LLᵀ (else a simplicial LDLᵀ, for
    near-chain graphs; through cvxopt, None until the first factorization tells); given as
    True, the factor is supernodal whatever the graph (the direct way: :meth:`supernodes`
    reads it); ``factor_entries``: the entries of L; ``flops``: CHOLMOD's count of
    the floating-point operations of one numeric factorization (the direct way only, else
    None).
    """

    def __init__(self, colptr: np.ndarray, rowind: np.ndarray, natural: bool = True, supernodal: bool = False):
        self.colptr = _as_int32(colptr, "colptr")
        self.rowind = _as_int32(rowind, "rowind")
        self.n = len(self.colptr) - 1
        self.nnz = int(self.colptr[-1])
        self._diagonal_at = _diagonal_positions(self.colptr, self.rowind)
        self._perm = None  # the factor's order, read when the pivot rule first needs it
        self._lib = _direct()
        if self._lib is None:
            self._impl = _CvxoptFactor(self.n, self.colptr, self.rowind, natural)
            self.supernodal, self.factor_entries, self.flops = self._impl.supernodal, None, None
            return
        lib = self._lib
        self._common = _new_common(lib, _NATURAL if natural else _AMD, postorder=not natural)
        if supernodal:
            struct.pack_into("i", self._common, _Common.SUPERNODAL, _ALWAYS_SUPERNODAL)
        self._values = None
        # The analysis reads the pattern only; factorize points the matrix at its values.
        self._A = _Sparse(self.n, self.n, self.nnz, self.colptr.ctypes.data, self.rowind.ctypes.data, None,
                          None, None, -1, _INT, _PATTERN, _DOUBLE, 1, 1)
        handle = lib.cholmod_analyze(ctypes.byref(self._A), self._common)
        if not handle:
            message = _failure(self._common, f"analysis of a {self.n} x {self.n} matrix")
            lib.cholmod_finish(self._common)
            raise MemoryError(message)
        self._A.xtype = _REAL
        self._spent = False
        self._L = handle
        head = handle.contents
        self.supernodal = bool(head.is_super)
        owned = []
        if self.supernodal:
            # L's entries in an array we own: CHOLMOD writes a supernodal factor where L.x points.
            self._x = _factor_values(int(head.xsize))
            owned.append(self._x)
            head.x = self._x.ctypes.data
            head.xtype = _REAL
        self._finalizer = weakref.finalize(self, _free, lib, handle, self._common, owned)
        stats = self._common.raw
        self.factor_entries = int(struct.unpack_from("d", stats, _Common.LNZ)[0])
        self.flops = float(struct.unpack_from("d", stats, _Common.FL)[0])

    def factorize(self, values: np.ndarray, pivot_tolerance: float = PIVOT_TOLERANCE) -> None:
        """Factor the matrix with ``values`` (nnz,) float64 (kept by reference until the next call).

        Raises :class:`NotPositiveDefinite` with the matrix's column where a pivot is refused:
        a pivot not above ``pivot_tolerance`` times its diagonal entry before elimination
        (:mod:`lie_factors.sparse.pivots`; 0: the sign rule, Levenberg–Marquardt's), or one
        CHOLMOD refuses; ``MemoryError`` where CHOLMOD runs out of memory.
        """
        if values.dtype != np.float64 or values.shape != (self.nnz,) or not values.flags.c_contiguous:
            raise InputError(f"values: expected a contiguous ({self.nnz},) float64 array")
        if self._lib is None:
            self._impl.factorize(values)
            self.supernodal = self._impl.supernodal
        else:
            self._values = values
            self._A.x = values.ctypes.data
            self._spent = False
            L = self._L
            if not self._lib.cholmod_factorize(ctypes.byref(self._A), L, self._common):
                raise MemoryError(_failure(self._common, "numeric factorization"))
            head = L.contents
            if self.supernodal and head.x != self._x.ctypes.data:
                raise RuntimeError("CHOLMOD moved a supernodal factor's values")
            if head.minor < self.n:
                raise NotPositiveDefinite(f"the matrix is not positive definite (CHOLMOD stopped at column "
                                          f"{head.minor})", int(head.minor))
        # An L·Lᵀ factor CHOLMOD completed has every pivot > 0, so the sign rule needs no check
        # there; an L·D·Lᵀ one does not stop at a negative pivot.
        if pivot_tolerance > 0.0 or not self._is_ll():
            self._refuse_pivots(values, float(pivot_tolerance))

    def _is_ll(self) -> bool:
        """Whether the last factorization is L·Lᵀ (else L·D·Lᵀ)."""
        if self._lib is None:
            return bool(self._impl.supernodal)
        return bool(self._L.contents.is_ll)

    def _refuse_pivots(self, values: np.ndarray, tolerance: float) -> None:
        """Raise :class:`NotPositiveDefinite` at the first pivot the rule of
        :mod:`lie_factors.sparse.pivots` refuses (in elimination order)."""
        pivots, diagonal, columns = self.pivots(values)
        k = first_refused(pivots, diagonal, tolerance)
        if k < 0:
            return
        column = int(columns[k])
        if tolerance > 0.0 and pivots[k] > 0.0:
            raise NotPositiveDefinite(f"the matrix is not positive definite to double precision (the pivot of "
                                      f"column {column} is {pivots[k] / diagonal[k]:.2g} of its diagonal entry, "
                                      f"not above {tolerance:g})", column)
        raise NotPositiveDefinite(f"the matrix is not positive definite (the pivot of column {column} is "
                                  f"{pivots[k]:.3g})", column)

    def pivots(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(pivots, diagonal, columns), each (n,), of the last factorization, of the matrix with
        ``values``, in elimination order: the k-th pivot (L_kk² of an L·Lᵀ factor, D_k of an
        L·D·Lᵀ one), the matrix's diagonal entry it is compared with, and the matrix's column
        it belongs to."""
        perm = self._factor_order()
        at = self._diagonal_at
        diagonal = np.where(at >= 0, values[np.maximum(at, 0)], 0.0) if len(values) else np.zeros(self.n)
        columns = np.arange(self.n) if perm is None else perm
        return self._pivots(), diagonal[columns], columns

    def _pivots(self) -> np.ndarray:
        """The pivots (n,) of the last factorization in the factor's order: L_jj² of an L·Lᵀ
        factor, D_j of an L·D·Lᵀ one."""
        if self._lib is None:
            return self._impl.pivots()
        head = self._L.contents
        ints = ctypes.POINTER(ctypes.c_int32)
        if head.is_super:
            ns = int(head.nsuper)

            def read(ptr):
                return np.ctypeslib.as_array(ctypes.cast(ptr, ints), shape=(ns + 1,)).astype(np.int64)

            first, rowptr, valptr = read(head.super), read(head.pi), read(head.px)
            width = np.diff(first)
            owner = np.repeat(np.arange(ns), width)
            k = np.arange(self.n) - first[owner]  # the column's place in its supernode
            # column k of a supernode's dense column-major block (its rows × its columns)
            L = self._x[valptr[owner] + k * (rowptr[owner + 1] - rowptr[owner] + 1)]
            return L * L
        p = np.ctypeslib.as_array(ctypes.cast(head.p, ints), shape=(self.n + 1,))
        x = np.ctypeslib.as_array(ctypes.cast(head.x, ctypes.POINTER(ctypes.c_double)), shape=(int(head.nzmax),))
        d = x[p[:self.n]]
        return d * d if head.is_ll else d.copy()

    def _factor_order(self) -> np.ndarray | None:
        """The factor's order (n,): its column k is the matrix's column ``perm[k]``; None where
        it is the matrix's own (a natural order CHOLMOD keeps)."""
        if self._perm is None:
            if self._lib is None:
                perm = self._impl.permutation()
            else:
                head = self._L.contents
                perm = np.ctypeslib.as_array(ctypes.cast(head.Perm, ctypes.POINTER(ctypes.c_int32)),
                                             shape=(self.n,)).astype(np.int64)
            self._perm = False if np.array_equal(perm, np.arange(self.n)) else perm
        return None if self._perm is False else self._perm

    def lower(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The last factorization as arrays, (perm, colptr, rowind, values, d): P·A·Pᵀ = L·diag(d)·Lᵀ
        with (P·x)[k] = x[perm[k]], L (n × n) unit lower triangular in compressed columns (int64;
        each column's diagonal, 1, first), d (n,) > 0.

        The numeric factor is handed over (cvxopt's way takes it apart to make a sparse
        matrix): :meth:`factorize` again before the next :meth:`solve`.  The direct way converts
        a copy, because CHOLMOD's conversion reallocates the values, and a supernodal factor's
        values live in an array of ours that CHOLMOD must not free.
        """
        self._check_numeric()
        if self._lib is None:
            perm, colptr, rowind, values, ll = self._impl.lower()
        else:
            lib, common = self._lib, self._common
            head = self._L.contents
            perm = np.ctypeslib.as_array(ctypes.cast(head.Perm, ctypes.POINTER(ctypes.c_int32)),
                                         shape=(self.n,)).astype(np.int64)
            ll = bool(head.is_ll)  # a supernodal factor is L·Lᵀ, and stays so as a sparse matrix
            copy = lib.cholmod_copy_factor(self._L, common)
            self._spent = True
            if not copy:
                raise MemoryError(_failure(common, "copy of the factor"))
            try:
                S = lib.cholmod_factor_to_sparse(copy, common)
            finally:
                lib.cholmod_free_factor(ctypes.byref(copy), common)
            if not S:
                raise MemoryError(_failure(common, "conversion of the factor"))
            try:
                sp = S.contents
                as_array = np.ctypeslib.as_array
                p = as_array(ctypes.cast(sp.p, ctypes.POINTER(ctypes.c_int32)), shape=(self.n + 1,)).astype(np.int64)
                start = p[:-1]
                count = (np.diff(p) if sp.packed else
                         as_array(ctypes.cast(sp.nz, ctypes.POINTER(ctypes.c_int32)), shape=(self.n,)).astype(np.int64))
                size = int(p[-1]) if sp.packed else int(start.max(initial=0) + count.max(initial=0))
                i = as_array(ctypes.cast(sp.i, ctypes.POINTER(ctypes.c_int32)), shape=(max(size, 1),))
                x = as_array(ctypes.cast(sp.x, ctypes.POINTER(ctypes.c_double)), shape=(max(size, 1),))
                colptr = np.concatenate([[0], np.cumsum(count)]).astype(np.int64)
                # each column's entries from its start in CHOLMOD's arrays, packed one after another
                take = np.arange(int(colptr[-1]), dtype=np.int64) + np.repeat(start - colptr[:-1], count)
                rowind, values = i[take].astype(np.int64), x[take].astype(np.float64)
            finally:
                lib.cholmod_free_sparse(ctypes.byref(S), common)
        return (perm, colptr, rowind) + _unit_lower(colptr, rowind, values, ll)

    def supernodes(self) -> "Supernodes":
        """The last factorization where it lies, as :class:`Supernodes`: P·A·Pᵀ = L·Lᵀ (the
        direct way, a supernodal factor).  Its ``values`` are the factor's own: what is written
        there changes the factor (:meth:`factorize` again before the next :meth:`solve`)."""
        self._check_numeric()
        if self._lib is None or not self.supernodal:
            raise RuntimeError("supernodes(): only a supernodal factor of the direct way lies as supernodes")
        head = self._L.contents
        ints = ctypes.POINTER(ctypes.c_int32)

        def read(ptr, size):
            return np.ctypeslib.as_array(ctypes.cast(ptr, ints), shape=(size,)).astype(np.int64)

        ns = int(head.nsuper)
        self._spent = True
        return Supernodes(read(head.Perm, self.n), read(head.super, ns + 1), read(head.pi, ns + 1),
                          read(head.px, ns + 1), read(head.s, max(int(head.ssize), 1)), self._x)

    def _check_numeric(self) -> None:
        if getattr(self, "_spent", False) or (self._lib is None and self._impl.spent):
            raise RuntimeError("the factor was handed over by lower(): factorize again first")

    def diagonal(self) -> np.ndarray:
        """D (n,) of a simplicial LDLᵀ factor (ones for an LLᵀ one)."""
        if self._lib is None:
            return self._impl.diagonal()
        head = self._L.contents
        if head.is_ll:
            return np.ones(self.n)
        p = np.ctypeslib.as_array(ctypes.cast(head.p, ctypes.POINTER(ctypes.c_int32)), shape=(self.n + 1,))
        x = np.ctypeslib.as_array(ctypes.cast(head.x, ctypes.POINTER(ctypes.c_double)), shape=(int(head.nzmax),))
        return x[p[:self.n]].copy()

    def solve(self, rhs: np.ndarray, system: int = SOLVE_A) -> np.ndarray:
        """x with A x = rhs (``system`` :data:`SOLVE_A`), or one of CHOLMOD's partial systems
        (:data:`SOLVE_P`: x = P·rhs, :data:`SOLVE_L`: L x = rhs, :data:`SOLVE_D`: D x = rhs).
        ``rhs`` (n,) or (n, m)."""
        self._check_numeric()
        b = np.asarray(rhs, dtype=np.float64)
        B = np.asfortranarray(b.reshape(self.n, -1))
        if self._lib is None:
            x = self._impl.solve(B, system)
        else:
            m = B.shape[1]
            dense = _Dense(self.n, m, self.n * m, self.n, B.ctypes.data, None, _REAL, _DOUBLE)
            X = self._lib.cholmod_solve(system, self._L, ctypes.byref(dense), self._common)
            if not X:
                raise MemoryError(_failure(self._common, "solve"))
            try:
                x = np.ctypeslib.as_array(ctypes.cast(X.contents.x, ctypes.POINTER(ctypes.c_double)),
                                          shape=(m, self.n)).T.copy(order="F")
            finally:
                self._lib.cholmod_free_dense(ctypes.byref(X), self._common)
        return x.reshape(b.shape)

    def half(self, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Z, d): Z = L⁻¹·P·rhs and d = D⁻¹ (ones for an LLᵀ factor), so that
        rhsᵀ·A⁻¹·rhs = Zᵀ·diag(d)·Z at the cost of one triangular sweep."""
        Z = self.solve(self.solve(rhs, SOLVE_P), SOLVE_L)
        return Z, 1.0 / self.diagonal()

    def free(self) -> None:
        """Release the factor now (it is released with the object otherwise)."""
        if self._lib is not None:
            self._finalizer()
        else:
            self._impl = None


def _diagonal_positions(colptr: np.ndarray, rowind: np.ndarray) -> np.ndarray:
    """(n,): where each column's diagonal entry is among the values of the lower triangle
    ``colptr``, ``rowind`` (first in its column: rows are sorted), −1 where it is not stored."""
    n = len(colptr) - 1
    first = colptr[:-1].astype(np.int64)
    stored = colptr[1:] > colptr[:-1]
    stored[stored] = rowind[first[stored]] == np.flatnonzero(stored)
    return np.where(stored, first, -1)


def _unit_lower(colptr, rowind, values, ll: bool) -> tuple[np.ndarray, np.ndarray]:
    """(values, d) of L·diag(d)·Lᵀ with L unit lower triangular, from CHOLMOD's L·Lᵀ (``ll``) or its
    L·D·Lᵀ, whose simplicial factor keeps D on L's diagonal; each column's diagonal is first."""
    diag = values[colptr[:-1]].copy()
    if not np.all(rowind[colptr[:-1]] == np.arange(len(colptr) - 1)):
        raise AssertionError("CHOLMOD's factor does not keep each column's diagonal first")
    if ll:
        values = values / np.repeat(diag, np.diff(colptr))
        d = diag * diag
    else:
        values = values.copy()
        d = diag
    values[colptr[:-1]] = 1.0
    return values, d


class _CvxoptFactor:
    """The same factor through cvxopt's API (its spmatrix holds a copy of the pattern and values)."""

    def __init__(self, n, colptr, rowind, natural):
        from cvxopt import cholmod, matrix, spmatrix

        self._cholmod, self._matrix = cholmod, matrix
        cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(colptr))
        self._S = spmatrix(matrix(np.ones(len(rowind))), matrix(rowind.astype(np.int64)), matrix(cols), (n, n))
        saved = dict(cholmod.options)
        cholmod.options["supernodal"] = 1  # CHOLMOD's own choice, as the direct way
        try:
            if natural:
                cholmod.options["nmethods"] = 1
                self._F = cholmod.symbolic(self._S, p=matrix(np.arange(n, dtype=np.int64)), uplo="L")
            else:
                self._F = cholmod.symbolic(self._S, uplo="L")
        finally:
            cholmod.options.clear()
            cholmod.options.update(saved)
        self.n = n
        self.supernodal = None
        self._dinv = None
        self.spent = False

    def lower(self):
        """(perm, colptr, rowind, values, ll): cvxopt's getfactor gives a supernodal factor as L·Lᵀ
        and a simplicial one as L·D·Lᵀ with D on the diagonal; D's solve told which (an L·Lᵀ
        factor has D = I, and a unit diagonal reads the same either way)."""
        perm = self.permutation()
        colptr, rowind, values = (np.array(a).reshape(-1) for a in self._cholmod.getfactor(self._F).CCS)
        self.spent = True
        colptr, rowind = colptr.astype(np.int64), rowind.astype(np.int64)
        ll = not np.allclose(values[colptr[:-1]], self.diagonal(), rtol=1e-12, atol=0.0)
        return perm, colptr, rowind, values.astype(np.float64), ll

    def factorize(self, values):
        self.spent = False
        self._S.V = self._matrix(values)
        try:
            self._cholmod.numeric(self._S, self._F)
        except ArithmeticError as exc:
            column = int(exc.args[0]) if exc.args and str(exc.args[0]).isdigit() else None
            where = exc.args[0] if exc.args else "?"
            raise NotPositiveDefinite(f"the matrix is not positive definite (CHOLMOD stopped at column {where})",
                                      column) from None
        # cvxopt's diag() takes a supernodal factor only (lower() leaves a simplicial one behind)
        try:
            self._ldiag = np.array(self._cholmod.diag(self._F)).reshape(-1)
            self.supernodal = True
        except ValueError:
            self._ldiag = None
            self.supernodal = False
        D = self._matrix(np.ones(self.n))
        self._cholmod.solve(self._F, D, sys=SOLVE_D)
        self._dinv = np.array(D).reshape(-1)

    def pivots(self):
        """L_jj² of a supernodal L·Lᵀ factor, D_j of a simplicial L·D·Lᵀ one, in the factor's order."""
        if self._ldiag is not None:
            return self._ldiag * self._ldiag
        return 1.0 / self._dinv

    def permutation(self):
        """The factor's order (n,): P·x with x = 0, 1, …, n − 1 (CHOLMOD postorders even a given order)."""
        p = self._matrix(np.arange(self.n, dtype=np.float64))
        self._cholmod.solve(self._F, p, sys=SOLVE_P)
        return np.rint(np.array(p).reshape(-1)).astype(np.int64)

    def diagonal(self):
        return 1.0 / self._dinv

    def solve(self, B, system):
        X = self._matrix(B)
        self._cholmod.solve(self._F, X, sys=system)
        return np.array(X)


# --------------------------------------------------------------------------- #
# Orderings and one-shot solves
# --------------------------------------------------------------------------- #

def block_order(count: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """A fill-reducing order (count,) of the variables of a block pattern: position → variable.

    ``rows``, ``cols`` (K,): the variable pairs that share a block (either order, duplicates
    and the diagonal allowed).  :func:`order_blocks` of their lower triangle.
    """
    rows = np.asarray(rows, dtype=np.int64)
    cols = np.asarray(cols, dtype=np.int64)
    lo, hi = np.minimum(rows, cols), np.maximum(rows, cols)
    codes = sorted_unique(np.concatenate([lo * count + hi, np.arange(count, dtype=np.int64) * (count + 1)]))
    bcol, brow = np.divmod(codes, count)
    colptr = np.zeros(count + 1, dtype=np.int64)
    np.cumsum(np.bincount(bcol, minlength=count), out=colptr[1:])
    return order_blocks(colptr, brow)


def order_blocks(colptr: np.ndarray, rowind: np.ndarray) -> np.ndarray:
    """A fill-reducing order of the block graph whose lower triangle (diagonal included) is
    ``colptr`` (V + 1,), ``rowind``: position → block.

    CHOLMOD's analysis of the block graph: AMD and the etree postorder it follows
    (cvxopt's AMD where CHOLMOD is not called directly).  Numbering a block's scalars
    together in this order makes every block part of a supernode, and costs a fraction of
    ordering the scalar matrix.
    """
    count = len(colptr) - 1
    lib = _direct()
    if lib is None:
        from cvxopt import amd, spmatrix

        cols = np.repeat(np.arange(count, dtype=np.int64), np.diff(colptr))
        S = spmatrix(1.0, np.asarray(rowind, dtype=np.int64).tolist(), cols.tolist(), (count, count))
        return np.array(amd.order(S)).reshape(-1).astype(np.int64)
    colptr32, rowind32 = _as_int32(colptr, "block colptr"), _as_int32(rowind, "block rowind")
    common = _new_common(lib, _AMD, postorder=True)
    A = _Sparse(count, count, len(rowind32), colptr32.ctypes.data, rowind32.ctypes.data, None, None, None,
                -1, _INT, _PATTERN, _DOUBLE, 1, 1)
    handle = lib.cholmod_analyze(ctypes.byref(A), common)
    try:
        if not handle:
            raise MemoryError(_failure(common, f"ordering of {count} blocks"))
        perm = np.ctypeslib.as_array(ctypes.cast(handle.contents.Perm, ctypes.POINTER(ctypes.c_int32)),
                                     shape=(count,)).astype(np.int64)
    finally:
        _free(lib, handle, common)
    return perm


def lower_csc(n: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray):
    """(colptr, rowind, values) of the lower-triangle triplets (rows ≥ cols, duplicates summed)."""
    keys = np.asarray(cols, dtype=np.int64) * n + np.asarray(rows, dtype=np.int64)
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    new = np.concatenate(([True], keys[1:] != keys[:-1])) if len(keys) else np.zeros(0, dtype=bool)
    values = np.add.reduceat(np.asarray(vals, dtype=np.float64)[order], np.flatnonzero(new)) if len(keys) else keys * 0.0
    c, r = np.divmod(keys[new], n)
    colptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(c, minlength=n), out=colptr[1:])
    return colptr, r, values


def solve_spd(n: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """x with A x = rhs, A (n × n) symmetric positive definite given by its lower triangle.

    ``rows``, ``cols``, ``vals`` (K,): triplets with rows ≥ cols, duplicates summed;
    ``rhs`` (n,) or (n, m).  CHOLMOD's sparse Cholesky in its own (AMD) order.  Raises
    ``numpy.linalg.LinAlgError`` if A is not positive definite or x is not finite.
    """
    colptr, rowind, values = lower_csc(n, rows, cols, vals)
    factor = Cholesky(colptr, rowind, natural=False)
    factor.factorize(values)
    x = factor.solve(rhs)
    if not np.all(np.isfinite(x)):
        raise np.linalg.LinAlgError("the linear system is singular (non-finite solution)")
    return x
