"""False loop closures rejected in three stages: consistency, GNC, and a final check.

1. **Consistency** (:func:`lie_factors.robust.screening.screen_closures`): the
   odometry gate and pairwise consistency set aside the closures that
   contradict the odometry or the other closures on short cycles; they enter
   GNC as known outliers.
2. **GNC** (:func:`lie_factors.robust.gnc.gnc_optimize`, or GTSAM's own): the
   odometry and the priors are known inliers, and the first solve uses them
   alone (``first_solve_known_inliers``), so GNC does not start from a map the
   remaining false closures have bent.  That start is the composed odometry,
   and on a 3-D graph with much rotational drift LM from it stops at a local
   minimum that the true closures do not fit (torus3D).  So GNC runs a second
   time from the relaxation (chordal) of the odometry and the closures the
   first stage kept, its first solve weighing them all, and the run whose
   truncated-least-squares cost Σ_known f_k + Σ_closures min(f_k, c̄_k) — the
   cost GNC-TLS minimizes (Yang et al., RA-L 2020) — is lower is kept: two
   local minima of one objective, compared on it (:func:`tls_cost`).  The
   second run is made only where its first solve (LM on the odometry and the
   kept closures, from the relaxation) already ends below the first run's
   cost: where the kept closures include false ones that bend the relaxation,
   it does not, and the second run's cost (up to another GNC) is not spent.
   That first solve gets at most :func:`relaxation_iterations` LM iterations:
   a relaxation whose edges agree lies where Gauss–Newton converges
   quadratically, and LM settles from it in a few iterations; one bent by
   false closures does not settle, and each of its iterations factors a
   system the false closures fill.
3. **Final check**, at GNC's solution.  Every loop closure, and every group
   of closures whose ends lie within :data:`GROUP_WINDOW` poses of each other
   (a run of closures between the same two places), is judged by how much the
   least-squares cost changes with it (:mod:`lie_factors.robust.leave_out`): the
   leave-group-out statistic for closures in the graph, the innovation
   statistic for closures out of it.  At the optimum the two are the same
   number, so a closure gets the same verdict in or out, whichever stage set
   it aside.  A group matters where closures support one another (perceptual
   aliasing): each member alone looks right while the others hold it.

   The statistic is tested against the data's own spread, not the noise
   models': the noise models of real data sets are far from their residuals
   (intel's loop closures, at the clean optimum, reach 1/60 of the χ² their
   noise models predict), and some are heavy-tailed (the largest statistic of
   the true closures of intel, CSAIL and manhattan is 34–38× the median; χ²₃
   puts its 0.9999 quantile at 9×) where others are not (smallGrid3D's: 3×).
   One closure's statistic is modelled as s·n·F(n, ν) — the squared norm of a
   Student-t residual in the n dimensions of a pose — with s and ν the maximum-
   likelihood fit to the accepted closures' statistics below the fitted model's
   own quantile, and ν no smaller than :data:`TAIL_DOF` (a tail no heavier than
   the real data sets'); a group's as the sum of independent ones
   (:class:`TailModel`).  Each fails above the model's
   quantile at ``final_probability``.

   Each round makes one kind of change, in this order: drop the accepted
   closures that fail alone; else drop the accepted groups that fail; else
   take back the rejected closures that pass.  A rejected closure near other
   rejected ones comes back with its group, or, where the group fails, with
   those of its members that pass alone, tested again as a group.  The gate's
   rejections stay out (see :func:`_final_round`).  LM re-solves from the
   solution after each change (at most :data:`MAX_ROUNDS` rounds); a closure
   is taken back at most once.  Then a group GNC rejected that fails by less
   than :data:`TRIAL_RATIO` times its threshold gets the likelihood-ratio test:
   LM re-solves with it, and twice the rise of the whole cost must pass the
   same threshold (GNC starts from the odometry, and on a graph with much
   drift it can end where a stretch of true closures does not fit, where the
   linear test agrees with it).

Each rejected closure is reported with the stage that decided it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..posegraph.graph import PoseGraph
from ..util.timing import Stopwatch
from .gnc import DECLINED, GncResult, GncSettings
from .tail import GROUP_MAX, GROUP_WINDOW, MAX_ROUNDS, TAIL_DOF, TailModel
from .screening import STAGES, Screening, screen_closures

__all__ = ["Rejection", "Solver", "TailModel", "reject_false_closures", "closure_groups", "relaxation_iterations",
           "MAX_ROUNDS", "TAIL_DOF"]

#: Groups rejected by GNC that the final check re-solves with, at most (each is one LM solve).
MAX_TRIALS = 32

#: Groups whose innovation statistic is more than this many times its threshold are not tried.
TRIAL_RATIO = 4.0

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
    off); ``rounds``: re-solves the final check ran; ``scale``: the tail model's
    scale s at the end; ``seconds``: the whole; ``reasons``: why the verdict may be wrong
    (:func:`uncertainty`); ``start``: the GNC run kept, ``"odometry"`` or ``"relaxation"``
    (module docstring); ``costs``: the truncated-least-squares cost (:func:`tls_cost`) of each run
    and of the relaxation's first solve."""

    gnc: GncResult
    rejected_by: dict
    readmitted: list
    screening: Screening | None
    rounds: int
    scale: float
    seconds: float
    reasons: tuple = ()
    start: str = "odometry"
    costs: dict = dataclasses.field(default_factory=dict)

    @property
    def outliers(self) -> np.ndarray:
        return np.array(sorted(self.rejected_by), dtype=np.int64)


class Solver(Protocol):
    """What the three stages need from a backend, on one graph whose factor slots are a pose
    graph's edges, then its priors (then any other factor).  An *estimate* is whatever the
    backend keeps (poses on arrays, ``gtsam.Values``): opaque to the stages.

    ``gnc(params, start=None, proceed=None, first_iterations=None)``: GNC
    (:class:`~lie_factors.robust.gnc.GncSettings`, its known outliers extended by the consistency
    stage) from the solver's start, or from ``start`` (P, m, m) poses in the pose graph's key
    order, its first solve at most ``first_iterations`` LM iterations, asking
    ``proceed(estimate)`` after it whether to go on (:func:`~lie_factors.robust.gnc.gnc_optimize`);
    ``errors(estimate)``: every slot's Gaussian error ½‖R e‖²; ``refine(estimate, weights)``: LM
    from ``estimate`` with each slot's information scaled by ``weights``; ``poses(estimate)``:
    (P, m, m) the poses in the pose graph's key order.
    """

    def gnc(self, params: GncSettings, start: np.ndarray | None = None, proceed=None,
            first_iterations: int | None = None) -> GncResult: ...

    def errors(self, estimate) -> np.ndarray: ...

    def refine(self, estimate, weights: np.ndarray): ...

    def poses(self, estimate) -> np.ndarray: ...


def reject_false_closures(graph: PoseGraph, solver: Solver, params: GncSettings, screen: bool = True,
                          probability: float = 0.9999, final_probability: float = 0.9999) -> Rejection:
    """The three stages of the module docstring on ``graph``, solved by ``solver`` (:class:`Solver`).

    ``probability``: the consistency stage's χ² quantile; ``final_probability``:
    the final check's quantile of the tail model.
    """
    run_gnc, errors, refine, poses = solver.gnc, solver.errors, solver.refine, solver.poses
    clock = Stopwatch()
    lc = graph.loop_closures()
    screening = screen_closures(graph, probability) if screen else None
    known = [] if screening is None else screening.rejected.tolist()
    gnc_params = dataclasses.replace(params, known_outliers=sorted(set(params.known_outliers) | set(known)))
    runs = {"odometry": run_gnc(gnc_params)}
    thresholds = runs["odometry"].thresholds  # every run's: they depend on the factors alone

    def cost(estimate) -> float:
        return tls_cost(errors(estimate), thresholds, lc, gnc_params.known_outliers)

    costs = {"odometry": cost(runs["odometry"].values)}
    relaxed = _relaxed_start(graph, screening) if params.first_solve_known_inliers else None
    if relaxed is not None:
        # GNC's first solve from the relaxation: LM on the odometry and the kept closures.  Only
        # where that point is already below the odometry's run in the objective does GNC go on.
        def below_odometry(estimate) -> bool:
            costs["relaxation's first solve"] = cost(estimate)
            return costs["relaxation's first solve"] < costs["odometry"]

        second = run_gnc(dataclasses.replace(gnc_params, first_solve_known_inliers=False), relaxed, below_odometry,
                         relaxation_iterations(gnc_params.lm_params))
        if second.stop != DECLINED:
            runs["relaxation"] = second
            costs["relaxation"] = cost(second.values)
    start = min(runs, key=lambda k: (costs[k], k != "odometry"))  # a tie keeps the odometry's
    res = runs[start]
    stage = {}
    if screening is not None:
        for e, s in zip(screening.closures.tolist(), screening.stage.tolist()):
            if s in STAGES:
                stage[e] = STAGES[s]
    weights = np.asarray(res.weights, dtype=np.float64).copy()
    for e in lc[weights[lc] < 0.5].tolist():
        stage.setdefault(e, "gnc")
    values = res.values
    # GNC stopped short of binary weights (a rejected closure still at, say, 5e-6): the tests below
    # take each closure as in the graph or out of it, so the solution is re-solved with GNC's verdict.
    verdict_weights = np.where(weights[lc] >= 0.5, 1.0, 0.0)
    resolved = bool(np.any(weights[lc] != verdict_weights))
    if resolved:
        weights[lc] = verdict_weights
        values = refine(values, weights)
    readmitted: set = set()
    rounds = 0
    model = None

    def check():
        """Rounds of the final check until nothing changes (at most MAX_ROUNDS re-solves); the last
        round's verdict."""
        nonlocal values, rounds, model
        for k in range(MAX_ROUNDS + 1):
            verdict = _final_round(graph, poses(values), weights, lc, readmitted, stage, final_probability)
            model = verdict.model
            if k == MAX_ROUNDS:
                return verdict
            if verdict.drop.size:
                weights[verdict.drop] = 0.0
                for e in verdict.drop.tolist():
                    stage[e] = "final"
            elif verdict.back.size:
                weights[verdict.back] = 1.0
                for e in verdict.back.tolist():
                    stage.pop(e, None)
                readmitted.update(verdict.back.tolist())
            else:
                return verdict
            values = refine(values, weights)
            rounds += 1
        return verdict

    verdict = check()
    # The likelihood-ratio trials: GNC's rejections that the linear test turns down by little.
    taken = False
    for G in verdict.trials:
        base = float(np.dot(weights, errors(values)))
        trial = weights.copy()
        trial[G] = 1.0
        v = refine(values, trial)
        rounds += 1
        if 2.0 * (float(np.dot(trial, errors(v))) - base) <= model.threshold(len(G)):
            weights[:] = trial
            values = v
            for e in G.tolist():
                stage.pop(e, None)
            readmitted.update(G.tolist())
            taken = True
    if taken:
        verdict = check()
    out = dataclasses.replace(res, values=values, weights=weights,
                              cost=float(np.dot(weights, errors(values))) if rounds or resolved else res.cost)
    rejected_by = {e: s for e, s in sorted(stage.items()) if weights[e] < 0.5}
    reasons = uncertainty(screening, res, settled=not (verdict.drop.size or verdict.back.size))
    return Rejection(out, rejected_by, sorted(readmitted - set(rejected_by)), screening, rounds,
                     model.scale if model is not None else float("nan"), clock.seconds(), reasons, start, costs)


def tls_cost(errors: np.ndarray, thresholds: np.ndarray, closures: np.ndarray, known_outliers) -> float:
    """The truncated-least-squares cost of an estimate: Σ f_k over the known inliers plus
    Σ min(f_k, c̄_k) over the loop closures, the known outliers left out (the same for any estimate).

    ``errors`` (size,) f_k = ½‖R_k e_k‖²; ``thresholds`` (size,) c̄_k; ``closures``: the loop
    closures' slots; ``known_outliers``: slots."""
    truncated = np.zeros(errors.size, dtype=bool)
    truncated[closures] = True
    counted = np.ones(errors.size, dtype=bool)
    counted[np.asarray(list(known_outliers), dtype=np.int64)] = False
    return float(np.sum(errors[counted & ~truncated])
                 + np.sum(np.minimum(errors, thresholds)[counted & truncated]))


def relaxation_iterations(lm_params=None) -> int:
    """The LM iterations of the relaxation's first solve, at most: twice the Gauss–Newton
    iterations that take a relative cost error of ½ below LM's ``relativeErrorTol`` at a quadratic
    rate (the error squared at each), 2·⌈log₂(ln tol / ln ½)⌉ — 10 at GTSAM's default 1e-5 — the
    factor 2 for the steps LM rejects while it sets its damping.  ``lm_params``:
    ``gtsam.LevenbergMarquardtParams`` (None: GTSAM's defaults); the tolerance is taken in
    [1e-16, ¼]."""
    import gtsam

    p = lm_params if lm_params is not None else gtsam.LevenbergMarquardtParams()
    tol = min(max(float(p.getRelativeErrorTol()), 1e-16), 0.25)
    return 2 * math.ceil(math.log2(math.log(tol) / math.log(0.5)))


def _relaxed_start(graph: PoseGraph, screening: Screening | None) -> np.ndarray | None:
    """(P, m, m) the chordal relaxation of the odometry, the priors and the closures the first stage
    kept; None without the first stage, on a graph with landmarks, or where the relaxation cannot
    run (Similarity3, no closure kept)."""
    from ..errors import InitializationError
    from ..initialization import initialize

    if screening is None or graph.landmarks is not None:
        return None
    kept = np.setdiff1d(np.arange(len(graph.edge_keys)), screening.rejected)
    if kept.size == len(graph.edge_keys) - len(screening.closures):
        return None  # every closure set aside: the relaxation is the odometry again
    try:
        return initialize(graph.with_edges(kept), "chordal").poses
    except InitializationError:
        return None


def uncertainty(screening: Screening | None, gnc: GncResult, settled: bool = True) -> tuple:
    """Why a run's verdict may be wrong (empty: nothing says so), one sentence each: a stage
    stopped at its bound — the clique search at its branch budget (its clique is not a maximum
    one; ``screening`` None: the stage did not run), GNC at its iteration limit, the final check
    at :data:`MAX_ROUNDS` with a change still to make (``settled`` False)."""
    reasons = []
    if screening is not None and not screening.exact:
        reasons.append("the pairwise-consistency clique search stopped at its branch budget")
    if gnc.stop == "maxIterations":
        reasons.append("GNC stopped at its iteration limit")
    if not settled:
        reasons.append(f"the final check stopped after {MAX_ROUNDS} rounds with a change still to make")
    return tuple(reasons)


@dataclass
class _Verdict:
    """One round of the final check: edges to ``drop`` and to take ``back``, the groups GNC
    rejected that deserve a likelihood-ratio ``trials`` (most plausible first), and the ``model``."""

    drop: np.ndarray
    back: np.ndarray
    trials: list
    model: TailModel


def _final_round(graph: PoseGraph, X: np.ndarray, weights: np.ndarray, lc: np.ndarray,
                 readmitted: set, stage: dict, probability: float) -> _Verdict:
    """The tests of one round at the poses ``X``: every closure alone, and every group of two or
    more, in the graph (leave-out) and out of it (innovation); ``stage``: edge → the stage that
    rejected it."""
    from .leave_out import leave_out_chi2

    accepted = lc[weights[lc] >= 0.5]
    # The gate's rejections stay out: it has set aside no true closure of any benchmark graph,
    # where the clique must give up one closure of every inconsistent pair, right or wrong.
    rejected = np.array([e for e in lc[weights[lc] < 0.5].tolist()
                         if e not in readmitted and stage.get(e) != "gate"], dtype=np.int64)
    groups_in = [G for G in closure_groups(graph, accepted) if len(G) > 1]
    groups_out = closure_groups(graph, rejected)
    singles_in = [accepted[k:k + 1] for k in range(accepted.size)]
    singles_out = [rejected[k:k + 1] for k in range(rejected.size)]
    multi_out = [G for G in groups_out if len(G) > 1]
    sets = [singles_in, singles_out, groups_in, multi_out]
    T = leave_out_chi2(graph, X, weights, [G for s in sets for G in s])
    parts, start = [], 0
    for s in sets:
        parts.append(T[start:start + len(s)])
        start += len(s)
    t_in, t_out, tg_in, tg_out = parts
    model = TailModel(graph.info.dim, t_in, probability)
    tau = model.threshold(1)
    empty = np.zeros(0, dtype=np.int64)
    # NaN (leverage 1: nothing else measures what it measures) compares False: not judged.
    drop = accepted[t_in > tau]
    if drop.size == 0:
        failed = [G for G, t in zip(groups_in, tg_in.tolist()) if t > model.threshold(len(G))]
        drop = np.concatenate(failed) if failed else empty
    back = empty
    trials: list = []
    if drop.size == 0:
        # A closure near other rejected ones comes back with its group: aliased false closures
        # each look plausible alone while the others are out.  Where the group fails, the members
        # that pass alone are tested again as a group (a true closure beside an aliased run).
        alone = dict(zip(rejected.tolist(), t_out.tolist()))
        passed = [G for G in groups_out if len(G) == 1 and alone[int(G[0])] <= tau]
        passed += [G for G, t in zip(multi_out, tg_out.tolist()) if t <= model.threshold(len(G))]
        retry = [G[np.array([alone[e] <= tau for e in G.tolist()])] for G, t in zip(multi_out, tg_out.tolist())
                 if not t <= model.threshold(len(G))]
        retry = [G for G in retry if 0 < len(G)]
        passed += [G for G in retry if len(G) == 1]
        retry = [G for G in retry if len(G) > 1]
        if retry:
            t_retry = leave_out_chi2(graph, X, weights, retry)
            passed += [G for G, t in zip(retry, t_retry.tolist()) if t <= model.threshold(len(G))]
        back = np.concatenate(passed) if passed else empty
        # GNC's rejections that fail by little get the likelihood-ratio test, most plausible first
        out = [G for G in groups_out if len(G) == 1] + multi_out
        t_o = [alone[int(G[0])] for G in groups_out if len(G) == 1] + tg_out.tolist()
        near = sorted(((t / model.threshold(len(G)), k) for k, (G, t) in enumerate(zip(out, t_o))
                       if model.threshold(len(G)) < t <= TRIAL_RATIO * model.threshold(len(G))
                       and all(stage.get(e) == "gnc" for e in G.tolist())))
        trials = [out[k] for _, k in near[:MAX_TRIALS]]
    return _Verdict(np.asarray(drop, dtype=np.int64), np.asarray(back, dtype=np.int64), trials, model)
