"""lie_factors.kernels.sort (heapsort for kernels) against numpy's sort, on drawn arrays."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from lie_factors.kernels.sort import argsort, sort


@njit(cache=False)
def _sorted(a):
    b = a.copy()
    sort(b)
    return argsort(a), b


@settings(max_examples=300, deadline=None)
@given(st.lists(st.integers(-2 ** 62, 2 ** 62), max_size=300, unique=True))
def test_sort_and_argsort_agree_with_numpy_on_distinct_values(values):
    a = np.array(values, dtype=np.int64)
    idx, b = _sorted(a)
    assert np.array_equal(b, np.sort(a))
    assert np.array_equal(a[idx], np.sort(a)) and np.array_equal(np.sort(idx), np.arange(len(a)))


@settings(max_examples=100, deadline=None)
@given(st.lists(st.integers(0, 5), max_size=60))
def test_repeated_values_are_sorted_too(values):
    a = np.array(values, dtype=np.int64)
    idx, b = _sorted(a)
    assert np.array_equal(b, np.sort(a)) and np.array_equal(a[idx], np.sort(a))
