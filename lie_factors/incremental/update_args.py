"""ISAM2's update arguments beyond the new factors and values, read and checked.

``ISAM2.update(newFactors, newTheta, removeFactorIndices, constrainedKeys,
noRelinKeys, extraReelimKeys, force_relinearize)``, or
``update(newFactors, newTheta, ISAM2UpdateParams)``: :func:`read_args` reads
either form (GTSAM's containers, or plain Python sequences and a dict for
``constrainedKeys``) into one :class:`UpdateArgs`.  The keys are only read
here; whether they name variables is checked against the smoother
(:meth:`UpdateArgs.variables`), before anything changes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from ..batch.graph import key_name
from ..errors import InputError


@dataclass
class UpdateArgs:
    """What an update asks besides its factors and values (GTSAM's semantics).

    ``remove``: indices of factors to take out (``removeFactorIndices``); ``constrained``:
    key → group of the elimination order (``constrainedKeys``: smaller groups eliminated
    first), a dict, or a ``gtsam.KeyGroupMap`` read key by key; ``no_relin``: keys held at
    their linearization point (``noRelinKeys``); ``extra``: keys re-eliminated whatever
    their δ (``extraReelimKeys``); ``force_relinearize``: check the relinearization
    threshold this update whatever ``relinearizeSkip``; ``full_solve``: back-substitute
    exactly at the next solve (``ISAM2UpdateParams.forceFullSolve``)."""

    remove: list = field(default_factory=list)
    constrained: object = None
    no_relin: list = field(default_factory=list)
    extra: list = field(default_factory=list)
    force_relinearize: bool = False
    full_solve: bool = False

    def groups(self, keys: list) -> dict:
        """The constrained keys among ``keys`` and their groups."""
        c = self.constrained
        if c is None:
            return {}
        if isinstance(c, dict):
            return {k: c[k] for k in keys if k in c}
        out = {}
        for k in keys:  # a KeyGroupMap cannot be iterated from Python: it is asked key by key
            if len(out) == c.size():
                break
            try:
                out[k] = int(c.at(k))
            except IndexError:
                continue
        return out

    def unknown_constrained(self, known: dict) -> bool:
        """Whether the constrained keys hold keys that are not in ``known`` (the variables, old
        and new, and their groups as :meth:`groups` read them)."""
        c = self.constrained
        if c is None:
            return False
        return (len(c) if isinstance(c, dict) else int(c.size())) != len(known)


def _keys(value, what: str) -> list:
    if value is None:
        return []
    try:
        keys = [int(k) for k in value]
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected keys (a gtsam.KeyList or a sequence of integers), "
                         f"got {type(value).__name__}") from None
    if any(k < 0 for k in keys):
        raise InputError(f"{what}: keys are non-negative integers")
    return keys


def _indices(value) -> list:
    if value is None:
        return []
    try:
        out = [int(i) for i in value]
    except (TypeError, ValueError):
        raise InputError(f"removeFactorIndices: expected factor indices (integers), got "
                         f"{type(value).__name__}") from None
    if any(isinstance(i, (bool, np.bool_)) for i in value):
        raise InputError("removeFactorIndices: expected factor indices (integers), got booleans")
    return out


def _constrained(value):
    if value is None or isinstance(value, gtsam.KeyGroupMap):
        return value
    if isinstance(value, dict):
        if all(type(g) is int for g in value.values()) and all(type(k) is int for k in value):
            return dict(value)
        out = {}
        for k, g in value.items():
            if isinstance(g, (bool, np.bool_)) or not isinstance(g, (int, np.integer)):
                raise InputError(f"constrainedKeys: the group of key {key_name(int(k))} must be an integer, "
                                 f"got {g!r}")
            out[int(k)] = int(g)
        return out
    raise InputError(f"constrainedKeys: expected a gtsam.KeyGroupMap or a dict of key → group, "
                     f"got {type(value).__name__}")


def read_args(removeFactorIndices=None, constrainedKeys=None, noRelinKeys=None, extraReelimKeys=None,
              force_relinearize=False) -> UpdateArgs:
    """The update's arguments after ``newFactors, newTheta``, in either of ISAM2's forms (an
    ``ISAM2UpdateParams`` in the place of ``removeFactorIndices``), checked for their types."""
    if isinstance(removeFactorIndices, gtsam.ISAM2UpdateParams):
        if any(x not in (None, False) for x in (constrainedKeys, noRelinKeys, extraReelimKeys)) or force_relinearize:
            raise InputError("update(newFactors, newTheta, ISAM2UpdateParams) takes nothing after the params")
        up = removeFactorIndices
        if up.newAffectedKeys is not None:
            raise InputError("ISAM2UpdateParams.newAffectedKeys goes with findUnusedFactorSlots, which the "
                             "smoother does not use: leave it unset")
        return UpdateArgs(_indices(up.removeFactorIndices), _constrained(up.constrainedKeys),
                          _keys(up.noRelinKeys, "noRelinKeys"), _keys(up.extraReelimKeys, "extraReelimKeys"),
                          bool(up.force_relinearize), bool(up.forceFullSolve))
    if not isinstance(force_relinearize, (bool, np.bool_)):
        raise InputError(f"force_relinearize: expected a bool, got {type(force_relinearize).__name__}")
    return UpdateArgs(_indices(removeFactorIndices), _constrained(constrainedKeys),
                      _keys(noRelinKeys, "noRelinKeys"), _keys(extraReelimKeys, "extraReelimKeys"),
                      bool(force_relinearize))


#: An update with nothing but factors and values.
PLAIN = UpdateArgs()


def order_groups(s, args: UpdateArgs, n_new: int, new: dict):
    """(variables after the update,): each variable's group in the elimination order
    (``constrainedKeys``; 0 for a key not given), or None without constrained keys.  ``s``:
    the smoother; ``new``: the update's ``n_new`` new keys → their indices."""
    if args.constrained is None:
        return None
    known = args.groups(list(s.var) + list(new))
    if args.unknown_constrained(known):
        raise InputError("constrainedKeys: a key is not a variable of the smoother")
    groups = np.zeros(len(s.keys) + n_new, dtype=np.int64)
    for k, g in known.items():
        groups[s.var[k] if k in s.var else new[k]] = g
    return groups
