"""Small array routines the layers above share (numpy only)."""

from __future__ import annotations

import numpy as np


def sorted_unique(a: np.ndarray) -> np.ndarray:
    """``np.unique`` of an integer array, by a sort: numpy 2's np.unique hashes integers, which is
    slower on keys and block codes (mostly distinct, and many)."""
    a = np.sort(np.asarray(a).ravel())
    return a[np.concatenate(([True], a[1:] != a[:-1]))] if len(a) else a
