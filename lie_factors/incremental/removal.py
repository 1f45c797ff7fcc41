"""Factors and variables leaving the smoother: what a removal takes out, and the structure left.

ISAM2's ``removeFactorIndices`` takes factors out by their index (the order they
were added in, counted over every update); a variable no factor holds any more,
old or new, is taken out with them (ISAM2's *unused keys*), and a key taken out
can be added again later as a new variable.  :func:`plan` reads and checks a
removal before anything changes (an index out of range, given twice or already
removed is an :class:`~lie_factors.errors.InputError`); :func:`structure` applies
the structural rule of :mod:`lie_factors.posegraph.gauge` to the graph the update
leaves, which, unlike an update that only adds, can split a component from its
anchor or leave a variable with too few rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..batch.graph import key_name
from ..errors import InputError
from ..posegraph import gauge


@dataclass
class Removal:
    """The factors an update takes out (``fids``), the variables they were on (``touched``,
    each once), and those left with no factor (``dead``): ISAM2's ``keysWithRemovedFactors``
    and ``unusedKeys``."""

    fids: np.ndarray
    touched: np.ndarray
    dead: np.ndarray

    @property
    def empty(self) -> bool:
        return not self.fids.size


NONE = Removal(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))


def factor_variables(store, fids: np.ndarray) -> np.ndarray:
    """The variables of the factors ``fids`` (each factor's, in order; repeats kept)."""
    starts, counts = store.fvstart[fids], store.fnv[fids]
    if not counts.sum():
        return np.zeros(0, dtype=np.int64)
    idx = np.repeat(starts - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))
    return store.fvars[idx]


def plan(s, indices: list, new_users: set) -> Removal:
    """The removal of the factors ``indices`` from the smoother ``s``, checked: each an index
    of a factor added and not removed, once.  ``new_users``: the variables the update's new
    factors use (they stay, whatever is removed)."""
    if not indices:
        return NONE
    bf = s.bf
    seen = set()
    for i in indices:
        if not 0 <= i < bf.nf:
            raise InputError(f"removeFactorIndices: no factor {i} (the smoother holds factors 0 … {bf.nf - 1})")
        if i in seen:
            raise InputError(f"removeFactorIndices: factor {i} is given twice")
        if bf.fremoved[i]:
            raise InputError(f"removeFactorIndices: factor {i} was removed already")
        seen.add(i)
    fids = np.array(indices, dtype=np.int64)
    touched = np.unique(factor_variables(bf.store, fids))
    remaining = np.setdiff1d(bf.factors_of(touched), fids, assume_unique=True)
    kept = np.union1d(factor_variables(bf.store, remaining), np.fromiter(new_users, dtype=np.int64))
    return Removal(fids, touched, np.setdiff1d(touched, kept, assume_unique=False))


def structure(s, n_new: int, dims: list, u: list, v: list, anchored: list, rows_new: dict,
              removal: Removal):
    """The structural rule on the graph an update with a removal leaves (module docstring):
    the components rebuilt from every factor that stays and the new ones (``u``, ``v``,
    ``anchored`` as :meth:`lie_factors.posegraph.gauge.Components.join` takes them, over the
    variables old and ``n_new`` new), and the rows of every variable that lost a factor and
    stays (``rows_new``: the rows the new factors give each variable).  Returns (the new
    :class:`~lie_factors.posegraph.gauge.Components` to keep, the finding or None)."""
    bf = s.bf
    store = bf.store
    n0 = len(s.keys)
    live = np.flatnonzero(~bf.fremoved[:bf.nf])
    live = np.setdiff1d(live, removal.fids, assume_unique=True)
    counts = store.fnv[live]
    variables = factor_variables(store, live)
    firsts = np.repeat(variables[np.cumsum(counts) - counts] if live.size else variables, counts)
    pair = variables != firsts
    relative = s.frelative[live]
    anchors = variables[(np.cumsum(counts) - counts)[(~relative) & (counts > 0)]] if live.size else variables
    comps = gauge.Components()
    stays = np.setdiff1d(removal.touched, removal.dead, assume_unique=True)
    touched = stays.tolist() + list(range(n0, n0 + n_new)) + list(u) + list(v) + list(anchored)
    plan_, finding = comps.join(n0 + n_new, firsts[pair].tolist() + list(u), variables[pair].tolist() + list(v),
                                anchors.tolist() + list(anchored), touched)
    if finding is None and stays.size:
        rows = np.bincount(variables, weights=np.repeat(store.frows[live], counts), minlength=n0)
        for w in stays.tolist():
            r = int(rows[w]) + rows_new.get(w, 0)
            d = int(bf.tree.dim[w])
            if r < d:
                finding = gauge.too_few_rows(w, r, d)
                break
    if finding is None:
        comps.commit(plan_)
    return comps, finding


def check_keys(s, keys: list, new: dict, what: str) -> list:
    """The variable indices of ``keys`` (old variables, or the update's new ones in ``new``:
    key → index); an InputError naming ``what`` for a key that is neither."""
    out = []
    for k in keys:
        w = s.var.get(k, new.get(k))
        if w is None:
            raise InputError(f"{what}: key {key_name(k)} is not a variable of the smoother")
        out.append(w)
    return out


def no_value(user: str, key: int) -> InputError:
    """The error of a new factor (``user``: what it is, "a ``user`` uses …") on ``key``, which
    is neither a new key nor a variable of the smoother."""
    return InputError(f"a {user} uses key {key_name(key)}, which has no value (neither new nor in the smoother)")


def keys_used(nf) -> set:
    """The keys the update ``nf``'s new factors use."""
    out = set()
    for entry in nf.arrays.values():
        out.update(entry["keys"].ravel().tolist())
    for _, keys in nf.native:
        out.update(keys)
    return out


def users(s, nf, new: dict) -> set:
    """The variables the update ``nf``'s new factors use (old ones, and new ones by ``new``:
    key → index)."""
    var = s.var
    return {var.get(k, new.get(k)) for k in keys_used(nf)}


def forget(s, dead: np.ndarray) -> None:
    """The variables ``dead`` (taken out by an update that succeeded) out of the smoother's keys
    and the values GTSAM holds; their key can be a new variable again."""
    for w in dead.tolist():
        k = s.keys[w]
        s.var.pop(k, None)
        for values in (s.other, s.native_theta):
            if values.exists(k):
                values.erase(k)
        s.other_types.pop(k, None)
        s.vnative[w] = False
        s.vfixed[w] = False
