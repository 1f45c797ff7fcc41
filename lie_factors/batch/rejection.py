"""False loop closures rejected in three stages: consistency, GNC, and a final check.

1. **Consistency** (:func:`lie_factors.batch.screening.screen_closures`): the
   odometry gate and pairwise consistency set aside the closures that
   contradict the odometry or the other closures on short cycles; they enter
   GNC as known outliers.
2. **GNC** (:func:`lie_factors.batch.gnc.gnc_optimize`, or GTSAM's own): the
   odometry and the priors are known inliers, and the first solve uses them
   alone (``first_solve_known_inliers``), so GNC does not start from a map the
   remaining false closures have bent.
3. **Final check**, at GNC's solution, on groups of closures whose ends lie
   within :data:`GROUP_WINDOW` poses of each other (a run of closures between
   the same two places), all at χ² probability ``group_probability``:

   * an accepted closure whose own residual exceeds ½·χ²_n(``final_probability``)
     is dropped;
   * an accepted group the rest of the graph contradicts is dropped: the
     leave-group-out test (:func:`lie_factors.batch.leave_out.leave_out_chi2`),
     which sees a group that bent the map until its own residuals looked small
     — the case GNC misses;
   * a group GNC rejected comes back if it passes the innovation test at the
     solution, or, failing that, the likelihood-ratio test: LM re-solves with
     it and the whole cost may rise by no more than the χ² quantile (at most
     :data:`MAX_TRIALS` groups).  GNC restarts every solve from the initial
     values, and on a graph with much drift it can end where a stretch of true
     closures does not fit.  Closures the first stage rejected are not
     reconsidered: a short cycle is stronger evidence than these tests have
     where the noise models are loose.

   After each change LM re-solves from the solution and the check runs again
   (at most :data:`MAX_ROUNDS` times).  A dropped group is never re-admitted.

Each rejected closure is reported with the stage that decided it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..pose_graph import PoseGraph
from ..timing import Stopwatch
from .gnc import GncParams, GncResult
from .losses import chi2_inlier_threshold
from .screening import STAGES, Screening, screen_closures

__all__ = ["Rejection", "reject_false_closures", "MAX_ROUNDS"]

#: Rounds of the final check (each one re-solve).
MAX_ROUNDS = 4

#: Groups rejected by GNC that the final check re-solves with, at most (each is one LM solve).
MAX_TRIALS = 32

#: Groups whose innovation χ² is more than this many times its threshold are not tried.
TRIAL_RATIO = 4.0

#: Closures whose corresponding ends are at most this many poses apart are tested as one group.
GROUP_WINDOW = 10


#: At most this many closures per group (clusters of aliased closures are 3–10 long).
GROUP_MAX = 10


def closure_groups(graph: PoseGraph, closures: np.ndarray, window: int = GROUP_WINDOW) -> list:
    """``closures`` (edge indices) split into groups: connected components of the pairs whose
    corresponding ends (oriented low → high id) are each within ``window`` poses, cut into
    pieces of at most :data:`GROUP_MAX` along the chain."""
    from .consistency import near_pairs

    closures = np.asarray(closures, dtype=np.int64)
    if closures.size == 0:
        return []
    ends = graph.index(graph.edge_keys[closures].reshape(-1)).reshape(-1, 2)
    first, second = near_pairs(ends.min(axis=1), ends.max(axis=1), window)
    parent = np.arange(closures.size)

    def root(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for i, j in zip(first.tolist(), second.tolist()):
        ri, rj = root(i), root(j)
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)
    roots = np.array([root(i) for i in range(closures.size)])
    order = np.lexsort((ends.min(axis=1), roots))  # by component, then along the chain
    cuts = np.flatnonzero(np.diff(roots[order])) + 1
    groups = []
    for g in np.split(order, cuts):
        # a long run (many passes over one place) in pieces of GROUP_MAX along the chain: the
        # statistic's cost grows with the square of a group's size
        groups += [closures[g[k:k + GROUP_MAX]] for k in range(0, g.size, GROUP_MAX)]
    return groups


@dataclass
class Rejection:
    """``gnc``: GNC's result (its ``values``/``weights`` replaced by the final ones);
    ``rejected_by``: edge index → stage (``"gate"``, ``"clique"``, ``"gnc"`` or
    ``"final"``) for every rejected loop closure; ``readmitted``: edges the final
    check put back; ``screening``: the first stage's verdict (None if it was
    off); ``rounds``: re-solves the final check ran; ``seconds``: the whole."""

    gnc: GncResult
    rejected_by: dict
    readmitted: list
    screening: Screening | None
    rounds: int
    seconds: float

    @property
    def outliers(self) -> np.ndarray:
        return np.array(sorted(self.rejected_by), dtype=np.int64)


def reject_false_closures(graph: PoseGraph, run_gnc: Callable[[GncParams], GncResult],
                          errors: Callable[[object], np.ndarray],
                          refine: Callable[[object, np.ndarray], object],
                          poses: Callable[[object], np.ndarray],
                          params: GncParams, screen: bool = True, probability: float = 0.9999,
                          group_probability: float = 0.9999, final_probability: float = 0.9999) -> Rejection:
    """The three stages of the module docstring on ``graph``: its edges, then its priors, are
    the factor slots.

    ``run_gnc(params)`` runs GNC (with ``params.known_outliers`` extended by the
    first stage); ``errors(values)`` gives every factor slot's Gaussian error
    ½‖R e‖² at ``values``; ``refine(values, weights)`` re-solves from
    ``values`` with each slot's information scaled by ``weights``;
    ``poses(values)`` (P, m, m) the poses in ``graph.keys`` order.
    ``probability``: the consistency stage's χ² quantile; ``group_probability``:
    the group tests'; ``final_probability``: the quantile an accepted closure's own
    residual must stay under.
    """
    clock = Stopwatch()
    lc = graph.loop_closures()
    screening = screen_closures(graph, probability) if screen else None
    known = [] if screening is None else screening.rejected.tolist()
    res = run_gnc(dataclasses.replace(params, known_outliers=sorted(set(params.known_outliers) | set(known))))
    stage = {}
    if screening is not None:
        for e, s in zip(screening.closures.tolist(), screening.stage.tolist()):
            if s in STAGES:
                stage[e] = STAGES[s]
    weights = np.asarray(res.weights, dtype=np.float64).copy()
    for e in lc[weights[lc] < 0.5].tolist():
        stage.setdefault(e, "gnc")
    values = res.values
    readmitted: list = []
    final: set = set()  # dropped by the final check: never re-admitted
    c = chi2_inlier_threshold(graph.info.dim, final_probability)
    rounds = 0

    def settle():
        nonlocal values, rounds
        for _ in range(MAX_ROUNDS):
            f = errors(values)[lc]
            accepted = weights[lc] >= 0.5
            back = np.zeros(0, dtype=np.int64)
            drop = lc[accepted & (f > c)]
            final.update(drop.tolist())
            if drop.size == 0:
                drop, back = _group_tests(graph, poses(values), weights, lc, final, stage, group_probability)
                final.update(drop.tolist())
            if back.size == 0 and drop.size == 0:
                return
            weights[back] = 1.0
            weights[drop] = 0.0
            for e in back.tolist():
                stage.pop(e, None)
                readmitted.append(e)
            for e in drop.tolist():
                stage[e] = "final"
            values = refine(values, weights)
            rounds += 1

    settle()
    # GNC restarts every solve from the initial values; on a graph with much drift it can end in
    # a basin where a stretch of true closures does not fit, and the linear innovation test,
    # taken in that basin, agrees.  The likelihood-ratio test re-solves with the group: the
    # rise of the whole cost, not the group's residual, decides.
    trials = _trial_groups(graph, poses(values), weights, stage, group_probability)
    taken = False
    for G in trials:
        base = float(np.dot(weights, errors(values)))
        trial = weights.copy()
        trial[G] = 1.0
        v = refine(values, trial)
        rounds += 1
        if 2.0 * (float(np.dot(trial, errors(v))) - base) <= \
                2.0 * chi2_inlier_threshold(graph.info.dim * len(G), group_probability):
            weights[:] = trial
            values = v
            for e in G.tolist():
                stage.pop(e, None)
                readmitted.append(e)
            taken = True
    if taken:
        settle()
    out = dataclasses.replace(res, values=values, weights=weights,
                              cost=float(np.dot(weights, errors(values))) if rounds else res.cost)
    rejected_by = {e: s for e, s in sorted(stage.items()) if weights[e] < 0.5}
    return Rejection(out, rejected_by, sorted(set(readmitted) - set(rejected_by)), screening, rounds,
                     clock.seconds())


def _trial_groups(graph: PoseGraph, X: np.ndarray, weights: np.ndarray, stage: dict,
                  probability: float) -> list:
    """Groups of closures GNC rejected, most plausible first (innovation χ² over its threshold),
    at most :data:`MAX_TRIALS`, none more than :data:`TRIAL_RATIO` over."""
    from .leave_out import leave_out_chi2

    candidates = np.array(sorted(e for e, s in stage.items() if s == "gnc" and weights[e] < 0.5),
                          dtype=np.int64)
    groups = closure_groups(graph, candidates)
    if not groups:
        return []
    T = leave_out_chi2(graph, X, weights, groups)
    n = graph.info.dim
    ratio = np.array([t / (2.0 * chi2_inlier_threshold(n * len(G), probability)) for G, t in zip(groups, T)])
    order = [i for i in np.argsort(ratio, kind="stable") if ratio[i] <= TRIAL_RATIO]
    return [groups[i] for i in order[:MAX_TRIALS]]


def _group_tests(graph: PoseGraph, X: np.ndarray, weights: np.ndarray, lc: np.ndarray, final: set,
                 stage: dict, probability: float) -> tuple[np.ndarray, np.ndarray]:
    """(drop, back): the accepted closures whose group fails the leave-group-out test, and the
    closures GNC rejected (except those in ``final``) whose group passes the innovation test."""
    from .leave_out import leave_out_chi2

    accepted = lc[weights[lc] >= 0.5]
    # Only GNC's rejections are reconsidered: the first stage rejects on short cycles, stronger
    # evidence than this test has where the noise models are loose.
    rejected = np.array([e for e in lc[weights[lc] < 0.5].tolist() if stage.get(e) == "gnc" and e not in final],
                        dtype=np.int64)
    inside = closure_groups(graph, accepted)
    outside = closure_groups(graph, rejected)
    groups = inside + outside
    empty = np.zeros(0, dtype=np.int64)
    if not groups:
        return empty, empty
    T = leave_out_chi2(graph, X, weights, groups)
    n = graph.info.dim
    passes = [t <= 2.0 * chi2_inlier_threshold(n * len(G), probability) for G, t in zip(groups, T.tolist())]
    # NaN (leverage 1) compares False: such a group is not judged by this test.
    drop = [G for G, t, ok in zip(inside, T[:len(inside)].tolist(), passes) if not ok and t == t]
    back = [G for G, ok in zip(outside, passes[len(inside):]) if ok]
    return (np.concatenate(drop) if drop else empty), (np.concatenate(back) if back else empty)
