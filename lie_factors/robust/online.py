"""False loop closures rejected online: each closure tested when it arrives, every decision tested again.

The smoother holds the known inliers (odometry, priors) and the closures accepted
so far; a closure it does not hold is *pending*.  The test is the final check's
(:mod:`lie_factors.robust.leave_out`, :class:`~lie_factors.robust.tail.TailModel`),
on the smoother's estimate and its marginal covariances instead of a batch
solution: for a group G of closures with whitened residual b_G and Jacobian
A_G at the estimate, and Σ the joint marginal covariance of their ends,

    T_G = b_Gᵀ (I + A_G Σ A_Gᵀ)⁻¹ b_G     (pending: the innovation statistic)
    T_G = b_Gᵀ (I − A_G Σ A_Gᵀ)⁻¹ b_G     (accepted: the leave-group-out statistic),

each χ²-like with dim(b_G) degrees of freedom for a true group, tested against the
tail model at the same probability as the batch check (:data:`PROBABILITY`).

Each update that brings closures:

1. tests each new closure alone, then the new closures that pass as groups
   (each with the others whose ends lie within
   :data:`~lie_factors.robust.tail.GROUP_WINDOW` poses of its own, as the batch
   check groups them); the smoother takes those that pass;
2. tests again :data:`RETEST` earlier decisions, oldest first: an accepted
   closure with the accepted closures near it (its group) and alone — it
   leaves if either fails (aliased false closures hold one another); a pending
   closure with the pending closures near it, then alone — it comes back if
   either passes.

So an update's work is bounded by its new closures plus :data:`RETEST` groups,
each of at most :data:`~lie_factors.robust.tail.GROUP_MAX` closures, and A Σ Aᵀ
of a group costs one forward substitution over the union of the paths from its
ends to the roots of the smoother's tree: the number of statistics does not grow
with the graph, but each costs the nodes on those paths and their separators,
which do.  A decision made early is revisited as the map firms up:
the round robin reaches every closure within (closures ÷ :data:`RETEST`)
updates that bring closures.

The first closures wait outside the smoother until :data:`MIN_FIT` have come: enough
for their sample median to lie between the true distribution's quartiles with
probability :data:`PROBABILITY` (a binomial bound, :func:`min_fit`).  The tail
model's scale is then set from the median of their statistics against the map
they found (the known inliers alone) with the noise models' χ²_n shape — up to
half of them may be false — and each is decided in the order it came
(:meth:`OnlineRejection._first_fit`).  The statistic's scale moves with the map it
is measured against where the odometry's noise models and the closures' are off
by different factors (a closure against the odometry alone measures mostly the
odometry's), so while fewer than :data:`MIN_FIT` closures are accepted the scale
is set again the same way, from the median of the closures that came since, each
time the closures have grown by :data:`REFIT_GROWTH`.  Then the model is fitted
to the accepted closures' statistics (as the batch check's, its tail at most as
heavy as ν = :data:`~lie_factors.robust.tail.TAIL_DOF`) each time they have grown
by :data:`REFIT_GROWTH`.  No threshold exceeds the batch odometry gate's,
χ²_gn(:data:`PROBABILITY`) at the noise models' own scale.
"""

from __future__ import annotations

from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass

import math

import numpy as np

from ..errors import InputError
from ..kernels.jit import kernel
from ..posegraph.graph import is_loop_closure
from .statistics import DOF_RANGE, chi2_inlier_threshold
from .tail import GROUP_MAX, GROUP_WINDOW, MAX_ROUNDS, TailModel

__all__ = ["OnlineRejection", "RobustSmoothing", "robust_update", "check_loss", "RETEST", "MIN_FIT", "PROBABILITY",
           "min_fit", "ONLINE_LOSSES"]

#: The losses a robust smoother takes: ``tls`` (truncated least squares: a closure is in, weight 1,
#: or out, weight 0, by the test of the module docstring).  (The batch solver's m-estimators are
#: :data:`lie_factors.solve.ROBUST_LOSSES`.)
ONLINE_LOSSES = ("tls",)


def check_loss(name, what: str) -> None:
    """An :class:`~lie_factors.errors.InputError` naming :data:`ONLINE_LOSSES` unless ``name`` is
    one of them; ``what``: the argument, as the message names it."""
    if name not in ONLINE_LOSSES:
        raise InputError(f"{what}: unknown {name!r} (online rejection; choose from {', '.join(ONLINE_LOSSES)})")


#: The probability of the tests (the batch final check's).
PROBABILITY = 0.9999

#: Earlier decisions tested again in each update that brings closures.
RETEST = 4

#: The tail model is fitted again when the accepted closures have grown by this factor since its
#: last fit (a fit's spread shrinks as 1/√K: doubling K narrows it by 30 %; each fit and its
#: thresholds cost ~0.2 s, the slowest updates of a run).
REFIT_GROWTH = 2.0

#: :meth:`OnlineRejection.settle`'s Gauss–Newton iterations at most, and its step tolerance.
SETTLE_ITERATIONS = 20
SETTLE_TOLERANCE = 1e-6

PENDING, ACCEPTED = 0, 1


@kernel
def _nearest(keys, among, c, window, most):
    """Closures ``among`` (ids) whose ends (low, high key) are each within ``window`` of closure
    ``c``'s, ``c`` first, then the others nearest first (ties in ``among``'s order), ``most`` in all."""
    klo, khi = min(keys[c, 0], keys[c, 1]), max(keys[c, 0], keys[c, 1])
    ids = np.empty(among.shape[0], dtype=np.int64)
    d = np.empty(among.shape[0], dtype=np.int64)
    count = 0
    for x in among:
        if x == c:
            continue
        lo, hi = min(keys[x, 0], keys[x, 1]), max(keys[x, 0], keys[x, 1])
        dx = max(abs(lo - klo), abs(hi - khi))
        if dx <= window:
            ids[count] = x
            d[count] = dx
            count += 1
    order = np.argsort(d[:count], kind="mergesort")
    take = min(count, most - 1)
    out = np.empty(take + 1, dtype=np.int64)
    out[0] = c
    for t in range(take):
        out[t + 1] = ids[order[t]]
    return out


def min_fit(probability: float = PROBABILITY) -> int:
    """The fewest statistics whose sample median lies between the 1/4 and 3/4 quantiles of their
    distribution with probability ``probability``: the smallest k with
    P(Binomial(k, 1/4) ≥ k/2) ≤ (1 − p)/2 (each side)."""
    k = 1
    while sum(math.comb(k, j) * 0.25 ** j * 0.75 ** (k - j) for j in range((k + 1) // 2, k + 1)) \
            > (1.0 - probability) / 2.0:
        k += 1
    return k


#: Accepted closures needed before the tail model is fitted to them (:func:`min_fit`).
MIN_FIT = min_fit()


@dataclass
class Decision:
    """What one update changes: closures to ``add`` and closures to ``remove`` (closure ids)."""

    add: list
    remove: list


class OnlineRejection:
    """The decisions of a robust smoother (module docstring) on the closures of one group.

    ``n``: the group's tangent dimension.  Closures are offered with :meth:`offer` (their keys,
    and where their factor lives: a :class:`~lie_factors.incremental.factor_arrays.FactorArrays`
    and an edge index); :meth:`decide` runs the tests of one update against a smoother;
    :meth:`outliers` names the pending ones.
    """

    def __init__(self, n: int, retest: int = RETEST, probability: float = PROBABILITY):
        self.n, self.retest, self.probability = int(n), int(retest), float(probability)
        self.keys = np.zeros((0, 2), dtype=np.int64)
        self.state = np.zeros(0, dtype=np.int8)
        self.T = np.full(0, np.nan)  # each closure's statistic at its last test
        self.epoch = np.zeros(0, dtype=np.int64)  # the tail model's fit in force at its last test
        self.source: list = []  # closure id -> (FactorArrays, edge index)
        self.Minv = np.zeros((0, 0, 0))  # each closure's M⁻¹ and whitening R, from its source
        self.R = np.zeros((0, self.n, self.n))
        self.fid = np.zeros(0, dtype=np.int64)  # the smoother's factor id of an accepted closure
        self.queue: deque = deque()  # closure ids, the oldest decision first
        self.model = TailModel(self.n, np.zeros(0), self.probability)
        self._limits: dict = {}  # group size -> the model's threshold
        self._fitted_at = 0  # accepted closures at the last fit to them
        self._median_at = 0  # closures at the last scale set from a median
        self.fits = 0  # the tail model's fits so far
        self.tests = 0  # group statistics computed (the work the bound counts)
        self.unsettled = False  # settle() stopped at its rounds with a change to make
        self._memo: "dict | None" = None  # inside _one_state(): each group's statistic (frozenset -> T)

    # ------------------------------------------------------------------ bookkeeping
    def offer(self, fa, edges) -> np.ndarray:
        """Closures ``edges`` (indices into ``fa``'s between factors), new; returns their ids."""
        edges = np.asarray(edges, dtype=np.int64).reshape(-1)
        c0 = len(self.keys)
        self.keys = np.concatenate([self.keys, fa.edge_keys[edges]])
        self.state = np.concatenate([self.state, np.full(len(edges), PENDING, dtype=np.int8)])
        self.T = np.concatenate([self.T, np.full(len(edges), np.nan)])
        self.epoch = np.concatenate([self.epoch, np.full(len(edges), -1, dtype=np.int64)])
        self.fid = np.concatenate([self.fid, np.full(len(edges), -1, dtype=np.int64)])
        self.source.extend((fa, int(e)) for e in edges.tolist())
        self.Minv = np.concatenate([self.Minv.reshape(-1, *fa.Minv.shape[1:]), fa.Minv[edges]])
        self.R = np.concatenate([self.R, fa.R[edges]])
        return np.arange(c0, c0 + len(edges))

    def outliers(self) -> np.ndarray:
        """Ids of the closures the smoother does not hold now."""
        return np.flatnonzero(self.state == PENDING)

    def status(self) -> dict:
        """``{"status": "ok" | "uncertain", "reasons": [...]}``: uncertain where decisions stand
        that were last tested under an earlier fit of the tail model (the round robin has not
        reached them since), or where :meth:`settle` stopped at its rounds with a change to make."""
        stale = int(np.count_nonzero(self.epoch < self.fits))
        reasons = [f"{stale} of {len(self.epoch)} loop-closure decisions were last tested before the tail "
                   "model's last fit"] if stale else []
        if self.unsettled:
            reasons.append(f"the final rounds stopped after {MAX_ROUNDS} with a change still to make")
        return {"status": "uncertain" if reasons else "ok", "reasons": reasons}

    def accepted(self) -> np.ndarray:
        return np.flatnonzero(self.state == ACCEPTED)

    def _refit(self) -> None:
        """The tail model fitted again (module docstring): to the accepted closures once there
        are :data:`MIN_FIT` of them, each time they grow by :data:`REFIT_GROWTH`; before, its scale
        from the median of the closures that came since the last such scale, each time the
        closures grow by :data:`REFIT_GROWTH`."""
        acc = self.accepted()
        if acc.size >= MIN_FIT:
            if acc.size >= REFIT_GROWTH * self._fitted_at:
                self._fitted_at = acc.size
                self._set_model(TailModel(self.n, self.T[acc], self.probability))
        elif self._median_at and len(self.state) >= REFIT_GROWTH * self._median_at:
            self._set_median_scale(self._median_at)

    def _set_median_scale(self, first: int) -> None:
        """The model whose scale is set from the median of the statistics of closures ``first``
        onwards, with the noise models' χ²_n shape: up to half of them may be false, so only their
        median is read."""
        closures = np.arange(first, len(self.state))
        self._median_at = len(self.state)
        self._set_model(TailModel(self.n, self.T[closures], self.probability, dof=DOF_RANGE[1], fit=False))

    def _set_model(self, model: TailModel) -> None:
        self.model, self._limits = model, {}
        self.fits += 1

    def _near(self, c: int, state: int) -> np.ndarray:
        """Closures in ``state`` whose ends (low, high key) are each within GROUP_WINDOW of
        closure ``c``'s, ``c`` first, the nearest GROUP_MAX in all."""
        return self._near_among(c, np.flatnonzero(self.state == state))

    def _near_among(self, c: int, among) -> np.ndarray:
        """:meth:`_near` among the closures ``among``."""
        return _nearest(self.keys, np.asarray(among, dtype=np.int64), int(c), GROUP_WINDOW, GROUP_MAX)

    # ------------------------------------------------------------------ the statistic
    def statistic(self, smoother, group) -> float:
        """T of closures ``group`` (all accepted: leave-group-out; all pending: innovation) at
        ``smoother``'s estimate; NaN where the others do not measure what the group does."""
        group = np.asarray(group, dtype=np.int64)
        states = set(self.state[group].tolist())
        assert len(states) == 1, "a group is all accepted or all pending"
        sign = -1.0 if states.pop() == ACCEPTED else 1.0
        self.epoch[group] = self.fits
        key = None if self._memo is None else frozenset(group.tolist())
        if key is not None and key in self._memo:
            return self._memo[key]
        self.tests += 1
        keys = self.keys[group].reshape(-1).tolist()
        ends = sorted(set(keys))
        place = {k: i for i, k in enumerate(ends)}
        where = np.array([place[k] for k in keys], dtype=np.int64).reshape(-1, 2)
        T = smoother.between_statistic(self.source[int(group[0])][0].group, ends, where, self.Minv[group],
                                       self.R[group], sign)
        if key is not None:
            self._memo[key] = T
        return T

    @contextmanager
    def _one_state(self):
        """A scope in which the smoother does not change: a group's statistic computed twice in it
        (a closure's group is often its neighbour's) is computed once."""
        self._memo = {}
        try:
            yield
        finally:
            self._memo = None

    def _passes(self, T: float, g: int) -> bool:
        limit = self._limits.get(g)
        if limit is None:
            # never above the batch odometry gate's χ²_gn at the noise models' own scale: the
            # first closures may all be false (planted near one another, before any true one)
            gate = 2.0 * chi2_inlier_threshold(g * self.n, self.probability)
            limit = self._limits[g] = min(self.model.threshold(g), gate)
        return not (T > limit)  # NaN (nothing else measures it) passes

    # ------------------------------------------------------------------ one update
    def decide(self, smoother, new) -> Decision:
        """The tests of one update (module docstring): ``new`` (closure ids offered in this
        update, pending).  Returns what the smoother should add and remove (:func:`apply_decision`
        applies it); the update that ends the wait for :data:`MIN_FIT` closures applies its own
        decisions, one closure at a time (:meth:`_first_fit`), and returns the retests'."""
        new = [int(c) for c in np.asarray(new, dtype=np.int64).tolist()]
        if self.fits == 0:
            if len(self.state) < MIN_FIT:
                return Decision([], [])  # held: the tail model's scale is not known yet
            self._first_fit(smoother)
            new = []
        else:
            self._refit()
        with self._one_state():
            return self._decide_tests(smoother, new)

    def _decide_tests(self, smoother, new: list) -> Decision:
        for c in new:
            self.T[c] = self.statistic(smoother, [c])
        passing = [c for c in new if self._passes(self.T[c], 1)]
        grouped: set = set()
        for c in list(passing):
            if c in grouped:
                continue
            near = [int(x) for x in self._near_among(c, passing) if x not in grouped]
            grouped.update(near)
            if len(near) > 1 and not self._passes(self.statistic(smoother, near), len(near)):
                # new closures that support only one another (an aliased run): set aside
                passing = [x for x in passing if x not in near]
        add, remove = list(passing), []
        self.queue.extend(new)
        for _ in range(min(self.retest, len(self.queue) - len(new))):
            c = self.queue.popleft()
            self.queue.append(c)
            self._retest(smoother, c, add, remove, new)
        return Decision(sorted(set(add)), sorted(set(remove)))

    def _first_fit(self, smoother) -> None:
        """The end of the wait for :data:`MIN_FIT` closures: the tail model fitted to their
        statistics against the map they found (the known inliers alone), then each decided in
        the order they came, against the map the ones before it made (an update each)."""
        held = list(range(len(self.state)))
        for c in held:
            self.T[c] = self.statistic(smoother, [c])
        self._set_median_scale(0)  # the tail's weight is fitted later, to accepted closures
        self.queue.extend(held)
        for c in held:
            self.T[c] = self.statistic(smoother, [c])
            if self._passes(self.T[c], 1):
                apply_decision(smoother, self, Decision([c], []))

    def _retest(self, smoother, c: int, add: list, remove: list, new=()) -> None:
        """Test closure ``c``'s decision again, appending to ``add`` or ``remove`` what changes:
        an accepted closure alone, then with the accepted closures near it; a pending closure with
        the pending closures near it, then alone."""
        if c in add or c in remove:
            return
        if self.state[c] == ACCEPTED:
            self.T[c] = self.statistic(smoother, [c])
            if not self._passes(self.T[c], 1):
                remove.append(c)
                return
            near = [int(x) for x in self._near(c, ACCEPTED) if x not in remove]
            if len(near) > 1 and not self._passes(self.statistic(smoother, near), len(near)):
                remove += near
            return
        near = [int(x) for x in self._near(c, PENDING) if x not in add and x not in new]
        if len(near) > 1 and self._passes(self.statistic(smoother, near), len(near)):
            add += near
            return
        self.T[c] = self.statistic(smoother, [c])
        if self._passes(self.T[c], 1):
            add.append(c)

    def settle(self, smoother, rounds: int = MAX_ROUNDS) -> bool:
        """Test every decision again and apply the changes, until none changes (at most ``rounds``
        passes, each O(closures) statistics and Gauss–Newton to convergence on the whole graph,
        :meth:`~lie_factors.incremental.Smoother.optimize`: the tests hold at a solution);
        returns whether it settled.  Not bounded per update: the end of a run, or whenever the
        caller can afford it."""
        if self.fits == 0 and len(self.state):
            self._first_fit(smoother)  # fewer than MIN_FIT closures came: the fit to what there is
        for _ in range(rounds):
            smoother.optimize(max_iterations=SETTLE_ITERATIONS, tolerance=SETTLE_TOLERANCE)
            self._refit()
            decision = self._settle_round(smoother)
            if not decision.add and not decision.remove:
                self.unsettled = False
                return True
            apply_decision(smoother, self, decision)
        smoother.optimize(max_iterations=SETTLE_ITERATIONS, tolerance=SETTLE_TOLERANCE)
        self.unsettled = True
        return False

    def _settle_round(self, smoother) -> Decision:
        """One kind of change, as the batch final check makes them: the accepted closures that fail
        alone; else the accepted groups that fail; else the pending closures that pass, with their
        group or alone."""
        with self._one_state():
            return self._settle_tests(smoother)

    def _settle_tests(self, smoother) -> Decision:
        acc = self.accepted().tolist()
        for c in acc:
            self.T[c] = self.statistic(smoother, [c])
        drop = [c for c in acc if not self._passes(self.T[c], 1)]
        if drop:
            return Decision([], drop)
        for c in acc:
            if c in drop:
                continue
            near = [int(x) for x in self._near(c, ACCEPTED) if x not in drop]
            if len(near) > 1 and not self._passes(self.statistic(smoother, near), len(near)):
                drop += near
        if drop:
            return Decision([], sorted(set(drop)))
        back: list = []
        for c in self.outliers().tolist():
            self._retest(smoother, c, back, [])
        return Decision(sorted(set(back)), [])

    def applied(self, decision: Decision, fids) -> None:
        """Record that the smoother took ``decision``: ``fids`` the factor ids of its added closures."""
        self.state[decision.remove] = PENDING
        self.fid[decision.remove] = -1
        self.state[decision.add] = ACCEPTED
        self.fid[decision.add] = np.asarray(fids, dtype=np.int64)


def apply_decision(smoother, rejection: OnlineRejection, decision: Decision) -> None:
    """Make ``smoother`` take ``decision`` (one update per set of prepared factors the added
    closures come from; the removals in the first) and record it in ``rejection``."""
    if not decision.add and not decision.remove:
        return
    parts: dict = {}
    for c in decision.add:
        fa, e = rejection.source[c]
        parts.setdefault(id(fa), (fa, []))[1].append((c, e))
    items = list(parts.values()) or [(rejection.source[decision.remove[0]][0], [])]
    remove = rejection.fid[decision.remove].tolist()
    fids = {}
    for i, (fa, ce) in enumerate(items):
        base = smoother.bf.nf
        smoother.update_prepared(fa, [], None, [e for _, e in ce], removeFactorIndices=remove if i == 0 else None)
        fids.update((c, base + t) for t, (c, _) in enumerate(ce))
    rejection.applied(decision, [fids[c] for c in decision.add])


class RobustSmoothing:
    """What a robust smoother answers (:class:`~lie_factors.incremental.Smoother` with
    ``robust``): its ``rejection`` (an :class:`OnlineRejection`, or None before any closure)."""

    rejection: "OnlineRejection | None"

    def outliers(self) -> np.ndarray:
        """(k, 2) int64: the keys of the candidate outliers the smoother does not hold now."""
        if self.rejection is None:
            return np.zeros((0, 2), dtype=np.int64)
        return self.rejection.keys[self.rejection.outliers()]

    def settle(self) -> bool:
        """Test every decision again at the solution until none changes
        (:meth:`OnlineRejection.settle`: not bounded per update); returns whether it settled."""
        return True if self.rejection is None else self.rejection.settle(self)


def robust_update(smoother, fa, keys, values, robust_factors=None, edges=None, priors=None):
    """:meth:`~lie_factors.incremental.Smoother.update_arrays` of a robust smoother: the known
    inliers among ``fa``'s between factors ``edges`` (default all) and its priors ``priors``
    (default all) enter, then the candidate outliers (``robust_factors``: a mask or indices
    into ``edges``; default the loop closures) are offered and decided.  A new key that only
    candidates reach enters with them (nothing else measures it)."""
    if smoother.robust is None:
        raise InputError("robust_factors: the smoother is not robust (Smoother(robust='tls'))")
    edges = np.arange(fa.E) if edges is None else np.asarray(edges, dtype=np.int64).reshape(-1)
    priors = np.arange(fa.Q) if priors is None else np.asarray(priors, dtype=np.int64).reshape(-1)
    E = len(edges)
    ek = fa.edge_keys[edges]
    if robust_factors is None:
        candidate = is_loop_closure(ek[:, 0], ek[:, 1]) if E else np.zeros(0, dtype=bool)
    else:
        r = np.asarray(robust_factors)
        if r.dtype == bool:
            if r.shape != (E,):
                raise InputError(f"robust_factors: a mask of the {E} between factors, got shape {r.shape}")
            candidate = r
        else:
            idx = r.astype(np.int64).reshape(-1)
            if not np.array_equal(idx, r.reshape(-1)) or np.any((idx < 0) | (idx >= E)):
                raise InputError(f"robust_factors: indices of the {E} between factors, got {r.tolist()}")
            candidate = np.zeros(E, dtype=bool)
            candidate[idx] = True
    new = np.asarray(keys, dtype=np.int64).reshape(-1)
    measured = np.concatenate([ek[~candidate].reshape(-1), fa.prior_keys[priors]])
    alone = new[~np.isin(new, measured)]
    if alone.size:
        candidate = candidate & ~np.isin(ek, alone).any(axis=1)
    rej = smoother.rejection
    if rej is None:
        rej = smoother.rejection = OnlineRejection(fa.spec.dim)
    elif rej.source and rej.source[0][0].group != fa.group:
        raise InputError(f"a robust smoother's loop closures are of one group ({rej.source[0][0].group}); "
                         f"this update's are {fa.group}")
    result = smoother.update_prepared(fa, keys, values, edges[~candidate], priors)
    if candidate.any():
        ids = rej.offer(fa, edges[candidate])
        apply_decision(smoother, rej, rej.decide(smoother, ids))
    return result
