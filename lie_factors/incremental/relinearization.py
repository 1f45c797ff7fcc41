"""Which variables an update relinearizes: ISAM2's check of δ against the threshold.

A variable is relinearized (θ ← θ ⊕ δ, every factor on it linearized again) when
its step δ has a component of at least the threshold (ISAM2's
``CheckRelinearizationFull``: the max norm ≥ the threshold), or, with a per-type
map (``ISAM2ThresholdMap``, by a key's symbol character), when a component
exceeds its own threshold; with the ``"global"`` policy (SLAM++'s), every
variable once the largest component reaches it.  Held: ``noRelinKeys``, the
variables of marginal factors (ISAM2's fixed variables) and those taken out.
"""

from __future__ import annotations

import numpy as np


def relinearized_now(s, force: bool = False, frozen=()) -> np.ndarray:
    """The variables the next update of the smoother ``s`` relinearizes: on every
    ``relinearizeSkip``-th update (ISAM2's count), or now with ``force`` (``force_relinearize``),
    δ brought up to date and :func:`relinearize_set` (``frozen`` held); none on the others."""
    p = s.smoother_params
    if not (p.enableRelinearization and (force or checks_next(s)) and s.bf.nv):
        return np.zeros(0, dtype=np.int64)
    s._solve()
    return relinearize_set(s, frozen)


def checks_next(s) -> bool:
    """Whether the next update of the smoother ``s`` is one that checks δ against the threshold
    (every ``relinearizeSkip``-th, ISAM2's count; whether relinearization is enabled or not)."""
    return (s.update_count + 1) % s.smoother_params.relinearizeSkip == 0


def relinearize_set(s, frozen=()) -> np.ndarray:
    """The variables of the smoother ``s`` to relinearize now (module docstring); ``frozen``:
    variable indices held this update."""
    bf = s.bf
    p = s.smoother_params
    th = p.relinearizeThreshold
    if isinstance(th, dict):
        relin = []
        tree = bf.tree
        for w in np.flatnonzero(bf.vdead[:bf.nv] == 0).tolist():
            t = p.threshold_of(s.keys[w], int(tree.dim[w]))
            if np.any(np.abs(s._variable_step(w)) > t):
                relin.append(w)
        out = np.array(relin, dtype=np.int64)
    else:
        moved = bf.largest_steps(s.step)
        if p.relinearizePolicy == "global":
            out = np.arange(bf.nv, dtype=np.int64) if moved.size and moved.max() >= th else moved[:0].astype(np.int64)
        else:
            out = np.flatnonzero(moved >= th).astype(np.int64)
    held = s.vfixed[out] | (bf.vdead[out] != 0)
    if len(frozen):
        held[np.isin(out, np.asarray(frozen, dtype=np.int64))] = True
    return out[~held] if held.any() else out
