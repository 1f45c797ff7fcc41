"""Group-id dispatch over the element cores, so group-generic loops can be cached.

The factors and the batch solver need the same few cores (inverse, compose,
log, exp, dlog) for whichever group a factor lives on. A numba closure over a
group's cores cannot be cached on disk, so it would be recompiled in every
process (seconds per group); a top-level function that branches on a small
integer group id can. The branch costs one integer comparison per call.

The ids are the ``GID`` attribute of each group module.
"""

from __future__ import annotations

from . import se2, se3, sim2, sim3, so3
from ._jit import kernel

SO3, SE3, SE2, SIM2, SIM3 = so3.GID, se3.GID, se2.GID, sim2.GID, sim3.GID


@kernel
def dim(g):
    """Tangent dimension of group ``g``."""
    if g == SO3:
        return so3.DIM
    if g == SE3:
        return se3.DIM
    if g == SE2:
        return se2.DIM
    if g == SIM3:
        return sim3.DIM
    return sim2.DIM


@kernel
def inverse(g, X, out):
    if g == SO3:
        so3._inverse(X, out)
    elif g == SE3:
        se3._inverse(X, out)
    elif g == SE2:
        se2._inverse(X, out)
    elif g == SIM3:
        sim3._inverse(X, out)
    else:
        sim2._inverse(X, out)


@kernel
def compose(g, X, Y, out):
    if g == SO3:
        so3._compose(X, Y, out)
    elif g == SE3:
        se3._compose(X, Y, out)
    elif g == SE2:
        se2._compose(X, Y, out)
    elif g == SIM3:
        sim3._compose(X, Y, out)
    else:
        sim2._compose(X, Y, out)


@kernel
def log(g, X, out):
    if g == SO3:
        so3._log(X, out)
    elif g == SE3:
        se3._log(X, out)
    elif g == SE2:
        se2._log(X, out)
    elif g == SIM3:
        sim3._log(X, out)
    else:
        sim2._log(X, out)


@kernel
def exp(g, x, out):
    if g == SO3:
        so3._exp(x, out)
    elif g == SE3:
        se3._exp(x, out)
    elif g == SE2:
        se2._exp(x, out)
    elif g == SIM3:
        sim3._exp(x, out)
    else:
        sim2._exp(x, out)


@kernel
def dlog(g, x, out):
    if g == SO3:
        so3._dlog(x, out)
    elif g == SE3:
        se3._dlog(x, out)
    elif g == SE2:
        se2._dlog(x, out)
    elif g == SIM3:
        sim3._dlog(x, out)
    else:
        sim2._dlog(x, out)
