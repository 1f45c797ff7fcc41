"""Compilation helpers shared by every kernel module.

Each closed form is written once, as a numba-compiled *core* that works on one
element (``core(x, out)`` with ``x`` of shape ``(n,)`` and ``out`` preallocated).
The factors call the cores directly (a sub-microsecond call); the public,
broadcasting functions (:mod:`lie_factors.kernels.public`) run the same cores
over a flattened batch, or, given exactly one element, through the
:func:`entry_point` of a small kernel that checks it and calls the core. There
is therefore exactly one implementation of each formula.
"""

from __future__ import annotations

import time

from numba import njit, typeof, types
from numba.core.registry import CPUDispatcher
from numba.core import event as _event

from . import blas_check, cache

# Before anything is compiled: symbols unique across processes, cache keys over the whole package,
# and numba's BLAS check made without importing scipy.linalg.
cache.install()
blas_check.check_blas()

#: Decorator for element cores. ``error_model="numpy"`` gives IEEE semantics
#: (no Python ZeroDivisionError checks inside hot loops); ``cache=True`` keeps
#: the compiled code in ``__pycache__`` so only the first import compiles
#: (:mod:`lie_factors.kernels.cache` says what makes that safe).
kernel = njit(cache=True, nogil=True, error_model="numpy")

#: The dense loops: :data:`kernel`'s options, with sums that may be reassociated and
#: multiply-adds contracted (vectorized); NaN and infinity keep their IEEE semantics.
dense_kernel = njit(cache=True, nogil=True, error_model="numpy", fastmath={"reassoc", "contract"})

#: Like :data:`kernel`, with ``prange`` loops run on numba's threads.
parallel_kernel = njit(cache=True, nogil=True, error_model="numpy", parallel=True)

class HelperDispatcher(CPUDispatcher):
    """The dispatcher of a :func:`helper_kernel`: compiled code calls it; a call from Python is
    a ``TypeError`` (numba would jump into the Python entry point the helper does not have)."""

    def __call__(self, *args, **kwargs):
        raise TypeError(f"{self.py_func.__module__}.{self.py_func.__qualname__} is called by compiled code "
                        "only (a helper of the kernels); call the kernel or public function built on it")


def helper_kernel(fn):
    """Decorator for a scalar or small-block helper that only compiled code calls (a coefficient,
    a 3×3 block): :data:`kernel`'s options without numba's Python entry point, whose generation
    is a good part of a small function's first-run compilation."""
    dispatcher = njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True)(fn)
    dispatcher.__class__ = HelperDispatcher
    return dispatcher

#: A part of a larger kernel, written apart to be read apart: numba inlines its code into each
#: caller's (``inline="always"``), where it is compiled with the caller's options (a
#: :data:`dense_kernel` caller's fast-math flags included).  It is not compiled on its own, so
#: it adds nothing to numba's fixed cost per compiled function, which is most of a first run's
#: compilation.
inline_kernel = njit(cache=True, nogil=True, error_model="numpy", inline="always")


class _CompileClock(_event.Listener):
    """Wall time numba spends compiling in this process (outermost compilations only;
    loading from the on-disk cache is not a compilation and is not counted)."""

    def __init__(self):
        self.depth = 0
        self.started = 0.0
        self.total = 0.0

    def on_start(self, event):
        if self.depth == 0:
            self.started = time.perf_counter()
        self.depth += 1

    def on_end(self, event):
        self.depth -= 1
        if self.depth == 0:
            self.total += time.perf_counter() - self.started


_clock = _CompileClock()
_event.register("numba:compile", _clock)


def compile_seconds() -> float:
    """Seconds numba has spent compiling so far in this process (0 when all came from cache).

    Timers subtract the difference of two readings so that reported
    optimization times never include compilation.
    """
    if _clock.depth:  # asked from inside a compilation (a progress callback can't be, but be exact)
        return _clock.total + time.perf_counter() - _clock.started
    return _clock.total


#: float64 arrays of any memory order (C, Fortran, strided) by number of axes; and C-ordered.
ANY = {n: types.Array(types.float64, n, "A") for n in (1, 2)}
C = {n: types.Array(types.float64, n, "C") for n in (1, 2)}


def entry_point(wrapper, argtypes: tuple):
    """numba's compiled entry point of ``wrapper`` for exactly the signature ``argtypes``.

    Compiles that single signature (or loads it from the on-disk cache) and returns
    what ``Dispatcher.compile`` returns, the function the dispatcher itself ends up
    calling.

    Why: calling the entry point skips the dispatcher's argument typing, a good part
    of a call on two small arrays, and one signature with arrays of any memory
    order (:data:`ANY`) serves every layout. The price is that nothing checks the
    arguments: callers pass exactly these types (the public functions check
    ``type``, ``shape`` and ``dtype`` first, and pass ``out`` they allocated with
    ``np.empty``). A tag argument (:mod:`lie_factors.kernels.dispatch`) is not even
    looked at: its type is all it carries.
    """
    return wrapper.compile(tuple(argtypes))


def direct(kernel):
    """``kernel`` called through its :func:`entry_point` for the argument types of its first call.

    For a caller whose arguments never change type, such as the incremental factor's
    structures (namedtuples of int64 and float64 C arrays it allocates itself): numba's
    dispatcher types every argument of every call, and the type of a namedtuple holds its
    fields' names, which it reads afresh each time, most of the call of a kernel that does
    little.  As with :func:`entry_point`, nothing checks the arguments after the first call.
    """
    entry = None

    def call(*args):
        nonlocal entry
        if entry is None:
            entry = entry_point(kernel, [typeof(a) for a in args])
        return entry(*args)

    call.__name__ = call.__qualname__ = kernel.__name__
    call.__doc__ = kernel.__doc__
    call.kernel = kernel
    return call
