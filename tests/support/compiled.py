"""Helpers of the kernels (``lie_factors.kernels.jit.helper_kernel``: compiled code calls them, they
have no Python entry point) called from the tests, through a compiled shim."""

from __future__ import annotations

from numba import njit

_shims: dict = {}


def call(helper, *args):
    """``helper(*args)``, run by a compiled function that calls it (one shim per helper)."""
    shim = _shims.get(helper)
    if shim is None:
        def run(*a):
            return helper(*a)

        shim = _shims[helper] = njit(cache=False)(run)
    return shim(*args)
