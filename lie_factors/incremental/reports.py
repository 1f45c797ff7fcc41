"""What an update reports (``gtsam.ISAM2Result``'s fields), and the choices made from reports.

:func:`update_result` fills :class:`~lie_factors.incremental.params.UpdateResult`
after an update that succeeded; :func:`error_before` is ISAM2's
``errorBefore`` (with ``evaluateNonlinearError``); :func:`adaptive_reorder`
decides, from the factor's entries, when an update orders every variable afresh
(``enableAdaptiveReorder``).
"""

from __future__ import annotations

import gtsam
import numpy as np

from .params import UpdateResult
from .removal import users


def update_result(s, relinearized: int, nf, removal, extra, relin, before, adaptive: bool) -> UpdateResult:
    """The report of the update the smoother ``s`` has just made: ``nf`` its new factors (None
    for the array path, which adds variables and factors only), ``removal`` what it took out,
    ``extra`` its extra re-eliminated variables, ``relin`` the relinearized ones, ``before``
    the error before it (or None), ``adaptive`` whether it reordered every variable for
    ``enableAdaptiveReorder``."""
    bf, keys = s.bf, s.keys
    p = s.smoother_params
    result = UpdateResult(bf.last.columns, relinearized, bf.live, bf.last.batch,
                          factorsRecalculated=bf.last.factors, batchReorderTriggered=adaptive)
    if p.enableDetailedResults or p.enableAdaptiveReorder:
        result.treeNnz = bf.nnz()
        if adaptive or s._nnz_at_reorder == 0 or bf.last.batch:
            s._nnz_at_reorder = result.treeNnz
    if nf is None:
        return result
    nf0 = bf.nf - nf.count
    result.newFactorsIndices = list(range(nf0, bf.nf))
    unused = set(removal.dead.tolist())
    observed = ({s.var[k] for k in nf.keys} | users(s, nf, s.var) | set(removal.touched.tolist())
                | set(extra)) - unused
    result.unusedKeys = [keys[w] for w in sorted(unused)]
    result.keysWithRemovedFactors = [keys[w] for w in removal.touched.tolist()]
    result.observedKeys = [keys[w] for w in sorted(observed)]
    result.markedKeys = [keys[w] for w in sorted(observed | set(np.asarray(relin).tolist()))]
    if before is not None:
        result.errorBefore = before
        result.errorAfter = s.error_at(s.calculateEstimate())
    return result


def adaptive_reorder(s):
    """With ``enableAdaptiveReorder``: every live variable, when the factor's entries have grown
    past ``adaptiveReorderThreshold`` × their count after the last reordering of every variable
    (an update observing them all orders and eliminates everything afresh), else None."""
    p = s.smoother_params
    if not p.enableAdaptiveReorder or s._nnz_at_reorder == 0:
        return None
    if s.bf.nnz() <= p.adaptiveReorderThreshold * s._nnz_at_reorder:
        return None
    return np.flatnonzero(s.bf.vdead[:s.bf.nv] == 0).astype(np.int64)


def error_before(s, nf, removal) -> float:
    """ISAM2's ``errorBefore``: the error of every factor after the update's additions and
    removals, at the estimate before it (the new variables at their given values)."""
    values = s.calculateEstimate()
    values.insert(nf.theta)
    graph = s.getFactorsUnsafe()
    removed = set(removal.fids.tolist())
    total = 0.0
    for i in range(graph.size()):
        f = graph.at(i)
        if f is not None and i not in removed:
            total += f.error(values)
    new = gtsam.NonlinearFactorGraph()
    for f, _ in nf.native:
        new.push_back(f)
    for entry in nf.arrays.values():
        for f in entry["src"]:
            if f is not None:
                new.push_back(f)
    return total + float(new.error(values))
