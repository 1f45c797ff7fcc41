"""Heapsort for kernels: ``sort(a)`` in place and ``argsort(keys)``, O(n log n), no allocation but the
result of :func:`argsort`.

Why not ``np.sort``/``np.argsort`` inside a kernel: numba compiles its own quicksort for them, a
family of nested functions that costs a first run over a second, once per process and array type;
these compile in a small fraction of that.  Neither sort is stable: the kernels that call them sort
distinct values (node ids, pool offsets), whose order is unique.
"""

from __future__ import annotations

import numpy as np

from .jit import helper_kernel


@helper_kernel
def _sift_down(keys, idx, start, end):
    """Restore the max-heap of ``keys[idx[start:end]]`` below ``idx[start]``."""
    root = start
    while True:
        child = 2 * root + 1
        if child >= end:
            return
        if child + 1 < end and keys[idx[child + 1]] > keys[idx[child]]:
            child += 1
        if keys[idx[root]] >= keys[idx[child]]:
            return
        t = idx[root]
        idx[root] = idx[child]
        idx[child] = t
        root = child


@helper_kernel
def _heapsort(keys, idx):
    """``idx`` reordered so that ``keys[idx]`` ascends."""
    n = idx.shape[0]
    for start in range(n // 2 - 1, -1, -1):
        _sift_down(keys, idx, start, n)
    for end in range(n - 1, 0, -1):
        t = idx[0]
        idx[0] = idx[end]
        idx[end] = t
        _sift_down(keys, idx, 0, end)


@helper_kernel
def argsort(keys):
    """(n,) int64: the indices that sort ``keys`` (n,) ascending."""
    idx = np.arange(keys.shape[0])
    _heapsort(keys, idx)
    return idx


@helper_kernel
def sort(a):
    """Sort the 1-D array ``a`` ascending, in place."""
    idx = argsort(a)
    tmp = np.empty_like(a)
    for i in range(a.shape[0]):
        tmp[i] = a[idx[i]]
    for i in range(a.shape[0]):
        a[i] = tmp[i]
