"""Graph searches on key arrays: connected components (and, with them, connectivity checks)."""

from __future__ import annotations

import numpy as np


def components(n: int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Connected-component label (smallest member) of nodes 0..n-1 joined by edges u–v.

    Hook-and-compress in numpy: each round hooks the larger root under the
    smaller, then jumps pointers until flat; rounds are few (O(log n)).
    """
    parent = np.arange(n)
    while True:
        pu, pv = parent[u], parent[v]
        if (pu == pv).all():
            return parent
        lo, hi = np.minimum(pu, pv), np.maximum(pu, pv)
        np.minimum.at(parent, hi, lo)
        while True:
            pp = parent[parent]
            if (pp == parent).all():
                break
            parent = pp
