"""Compilation helpers shared by every kernel module.

Each closed form is written once, as a numba-compiled *core* that works on one
element (``core(x, out)`` with ``x`` of shape ``(n,)`` and ``out`` preallocated).
The factors call the cores directly (a sub-microsecond call); the public,
broadcasting functions run the same cores over a flattened batch with
:func:`apply`, or, given exactly one element, through a small kernel that
checks it and calls the core (:func:`one_element`). There is therefore
exactly one implementation of each formula.
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit, types
from numba.core import event as _event

#: Decorator for element cores. ``error_model="numpy"`` gives IEEE semantics
#: (no Python ZeroDivisionError checks inside hot loops); ``cache=True`` keeps
#: the compiled code in ``__pycache__`` so only the first import compiles.
kernel = njit(cache=True, nogil=True, error_model="numpy")


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


# Not cached: numba keys specialisations on the identity of the kernel passed
# in, which changes from process to process, so a cache would only grow.
# Compiling one specialisation takes ~0.1 s, once per process and kernel.
@njit(nogil=True, error_model="numpy")
def _rows(core, x, out):
    for i in range(x.shape[0]):
        core(x[i], out[i])


@njit(nogil=True, error_model="numpy")
def _rows2(core, x, y, out):
    for i in range(x.shape[0]):
        core(x[i], y[i], out[i])


def apply(core, x: np.ndarray, core_ndim: int, out_core_shape: tuple) -> np.ndarray:
    """Run ``core`` over every element of ``x``, broadcasting leading axes.

    ``x`` has shape ``batch + core_shape`` (``core_ndim`` trailing axes); the
    result has shape ``batch + out_core_shape``. ``x`` must already be a
    validated float64 array (see :mod:`lie_factors.kernels.validate`).
    """
    batch = x.shape[: x.ndim - core_ndim]
    flat = np.ascontiguousarray(x.reshape((-1,) + x.shape[x.ndim - core_ndim :]))
    out = np.empty((flat.shape[0],) + tuple(out_core_shape))
    if flat.shape[0]:
        _rows(core, flat, out)
    return out.reshape(batch + tuple(out_core_shape))


def apply2(core, x: np.ndarray, y: np.ndarray, core_ndims: tuple, out_core_shape: tuple) -> np.ndarray:
    """Two-argument version of :func:`apply`; ``x`` and ``y`` batch shapes broadcast."""
    bx = x.shape[: x.ndim - core_ndims[0]]
    by = y.shape[: y.ndim - core_ndims[1]]
    batch = np.broadcast_shapes(bx, by)
    xs = np.broadcast_to(x, batch + x.shape[x.ndim - core_ndims[0] :])
    ys = np.broadcast_to(y, batch + y.shape[y.ndim - core_ndims[1] :])
    fx = np.ascontiguousarray(xs.reshape((-1,) + xs.shape[len(batch) :]))
    fy = np.ascontiguousarray(ys.reshape((-1,) + ys.shape[len(batch) :]))
    out = np.empty((fx.shape[0],) + tuple(out_core_shape))
    if fx.shape[0]:
        _rows2(core, fx, fy, out)
    return out.reshape(batch + tuple(out_core_shape))


#: float64 arrays of any memory order (C, Fortran, strided) by number of axes; and C-ordered.
_ANY = {n: types.Array(types.float64, n, "A") for n in (1, 2)}
_C = {n: types.Array(types.float64, n, "C") for n in (1, 2)}


def one_element(wrapper, in_ndims: tuple, out_ndim: int, namespace: dict, name: str):
    """The compiled entry point of ``wrapper(*inputs, out)`` for one signature, bound lazily.

    ``wrapper`` is a kernel taking float64 inputs with ``in_ndims`` axes (any
    memory order) and a C-ordered float64 ``out`` with ``out_ndim`` axes. Returns
    a stub that, on its first call, compiles that single signature (or loads it
    from the on-disk cache), rebinds ``namespace[name]`` to numba's compiled
    entry point (what ``Dispatcher.compile`` returns, the function the
    dispatcher itself ends up calling) and forwards the call.

    Why: calling the entry point skips the dispatcher's argument typing, ≈0.1 µs
    of a ≈0.3 µs call on two arrays, and one signature serves every memory
    order. The price is that nothing checks the arguments: callers pass
    ndarrays of dtype float64 with exactly these numbers of axes (the public
    functions check ``type``, ``shape`` and ``dtype`` first) and an ``out``
    they allocated with ``np.empty``.
    """
    if not hasattr(wrapper, "compile"):  # NUMBA_DISABLE_JIT=1: the wrapper is the Python function
        return wrapper
    sig = tuple(_ANY[n] for n in in_ndims) + (_C[out_ndim],)

    def first_call(*args):
        entry = wrapper.compile(sig)
        namespace[name] = entry
        return entry(*args)

    first_call.__name__ = name
    return first_call
