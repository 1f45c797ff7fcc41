"""The consistency stage before GNC: loop closures that contradict the odometry, or one another, are
set aside before graduated non-convexity sees them.

GNC's truncated least squares judges a loop closure by its own residual at a
solution.  A false closure at the end of a long, soft odometry chain can bend
the chain until that residual is below the truncation threshold, and stays an
"inlier".  The tests here judge a closure by cycles instead
(:mod:`lie_factors.robust.consistency`), where the odometry's softness is in the
covariance:

1. **odometry gate** — each closure against the odometry between its ends,
   rejected if χ² > χ²_n(``probability``);
2. **pairwise consistency** (Mangelson et al., ICRA 2018) — every pair of
   closures that passed the gate and whose ends are both within ``window``
   poses of each other (a short, informative cycle; farther pairs count as
   consistent) is tested the same way, and the largest set of closures with no
   inconsistent pair is kept: an exact maximum clique of the consistency graph
   where the search fits its budget (:mod:`lie_factors.robust.clique`).

The cost is the gate (one test per closure) and the pairs, at most
``pairs_per_closure`` per closure on average (the window shrinks until that
holds): linear in the number of closures.

Closures between poses the odometry does not join (different segments of the
chain) are not tested and go to GNC as they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..posegraph.graph import PoseGraph, is_loop_closure
from ..util.timing import Stopwatch
from . import consistency as _consistency
from .clique import maximum_clique_complement
from .statistics import chi2_inlier_threshold

__all__ = ["KEPT", "GATE", "CLIQUE", "STAGES", "Screening", "screen_closures"]

#: What the stage decided for a closure.
KEPT, GATE, CLIQUE = 0, 1, 2
#: Names of the stages that can reject a closure, as the JSON records them.
STAGES = {GATE: "gate", CLIQUE: "clique"}


@dataclass
class Screening:
    """The consistency stage's verdict.

    ``closures`` (C,) int64: the graph's loop-closure edges (indices into its
    edges); ``stage`` (C,) int8: :data:`KEPT`, :data:`GATE` or :data:`CLIQUE`;
    ``gate_chi2`` (C,): each closure's χ² against the odometry (NaN: untested);
    ``pairs``: pairs tested; ``inconsistent``: pairs that failed;
    ``window``: the window used; ``exact``: the clique is a maximum one;
    ``seconds``: wall time of the stage.
    """

    closures: np.ndarray
    stage: np.ndarray
    gate_chi2: np.ndarray
    pairs: int
    inconsistent: int
    window: int
    exact: bool
    seconds: float

    @property
    def rejected(self) -> np.ndarray:
        """Edge indices of the closures the stage set aside (sorted)."""
        return self.closures[self.stage != KEPT]


def _odometry(graph: PoseGraph, ends: np.ndarray) -> np.ndarray:
    """Indices of the odometry edges, the first one per consecutive pair of poses."""
    odo = np.flatnonzero(~is_loop_closure(graph.edge_keys[:, 0], graph.edge_keys[:, 1]))
    into = np.maximum(ends[odo, 0], ends[odo, 1])
    _, first = np.unique(into, return_index=True)
    return odo[first]


def screen_closures(graph: PoseGraph, probability: float = 0.9999, window: int = 200,
                    pairs_per_closure: int = 64) -> Screening:
    """Run the odometry gate and pairwise consistency on ``graph``'s loop closures (module docstring).

    ``probability``: the χ² quantile both tests use; ``window``: the largest
    distance, in poses along the chain, between the corresponding ends of two
    closures tested as a pair.
    """
    if not 0.0 < probability < 1.0:
        raise ValueError(f"probability must be in (0, 1), got {probability}")
    if window < 1 or pairs_per_closure < 1:
        raise ValueError("window and pairs_per_closure must be positive")
    clock = Stopwatch()
    group = graph.info
    ends = graph.index(graph.edge_keys.reshape(-1)).reshape(-1, 2)
    odo = _odometry(graph, ends)
    lc = graph.loop_closures()
    C = lc.size
    stage = np.zeros(C, dtype=np.int8)
    if C == 0:
        return Screening(lc, stage, np.zeros(0), 0, 0, int(window), True, clock.seconds())
    covariance = np.linalg.inv(graph.information)
    ch = _consistency.chain(group, len(graph.keys), ends[odo, 0], ends[odo, 1], graph.measured[odo],
                            covariance[odo])
    a, b = ends[lc, 0], ends[lc, 1]
    Z = np.ascontiguousarray(graph.measured[lc])
    S = np.ascontiguousarray(covariance[lc])
    _consistency.reverse(group, Z, S, a > b)
    a, b = np.minimum(a, b), np.maximum(a, b)
    threshold = 2.0 * chi2_inlier_threshold(group.dim, probability)

    gate = _consistency.gate_chi2(ch, a, b, Z, S)
    stage[gate > threshold] = GATE

    tested = np.flatnonzero((stage == KEPT) & np.isfinite(gate))
    w = int(window)
    while True:
        first, second = _consistency.near_pairs(a[tested], b[tested], w)
        if first.size <= pairs_per_closure * max(tested.size, 1) or w <= 1:
            break
        w //= 2
    first, second = tested[first], tested[second]
    chi2 = _consistency.pair_chi2(ch, a, b, Z, S, first, second)
    bad = chi2 > threshold
    kept, cover = maximum_clique_complement(C, np.stack([first[bad], second[bad]], axis=1))
    out = np.ones(C, dtype=bool)
    out[kept] = False
    stage[out & (stage == KEPT)] = CLIQUE
    return Screening(lc, stage, gate, int(first.size), int(bad.sum()), w, bool(cover.exact),
                     clock.seconds())
