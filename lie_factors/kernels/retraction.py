"""GTSAM's retraction of group elements, X·Exp(δ), over a range of them: written once for the batch
loops (:mod:`lie_factors.batch.loops`) and the compiled small-problem solver's retraction entries
(:mod:`lie_factors.expressions.centry`).  The group tag ``g`` comes first
(:mod:`lie_factors.kernels.dispatch`)."""

from __future__ import annotations

import numpy as np

from . import dispatch as _dispatch
from .jit import kernel

__all__ = ["retract_range"]


@kernel
def retract_range(g, X, delta, offsets, out, i0, i1):
    """out[i] = X[i]·Exp(delta[offsets[i] : offsets[i] + n]) for i0 ≤ i < i1 (GTSAM's retract);
    an offset −1 copies X[i] unchanged."""
    n = _dispatch.dim(g)
    m = X.shape[1]
    D = np.empty((m, m))
    x = np.empty(n)
    for i in range(i0, i1):
        o = offsets[i]
        if o < 0:
            # element by element: an array assignment would compile numba's shape-mismatch
            # message, seconds of string formatting on a first run
            for r in range(m):
                for c in range(m):
                    out[i, r, c] = X[i, r, c]
            continue
        for k in range(n):
            x[k] = delta[o + k]
        _dispatch.exp(g, x, D)
        _dispatch.compose(g, X[i], D, out[i])
