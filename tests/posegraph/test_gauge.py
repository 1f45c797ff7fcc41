"""lie_factors.posegraph.gauge: the structural rule on index arrays, and the same rule kept update by
update (the smoother's union-find) against it."""

from __future__ import annotations

import numpy as np
import pytest

from lie_factors.posegraph import gauge
from lie_factors.posegraph.topology import components


def test_too_few_rows_first_then_the_first_free_component():
    dims = np.array([3, 3, 3, 3, 3])
    # 0-1 anchored (a prior on 1), 2-3 relative only, 4 alone in a relative factor of its own
    u, v, anchored = np.array([0, 2]), np.array([1, 3]), np.array([1])
    rows = np.array([3, 6, 3, 3, 3])
    finding = gauge.undetermined(dims, rows, u, v, anchored)
    assert finding.variable == 2
    assert finding.error("where", "x2").args[0] == "where: the component of x2 (2 variables) has no prior: its " \
                                                  "gauge is free"
    assert finding.error("where", "x2").variable == 2
    rows[3] = 2
    finding = gauge.undetermined(dims, rows, u, v, anchored)
    assert finding.variable == 3 and finding.reason.format("x3") == \
        "x3 has 2 rows of factors for its 3 dimensions: they cannot determine it"
    rows[4] = 0
    assert gauge.undetermined(dims, rows, u, v, anchored).variable == 3
    rows[3] = 3
    assert gauge.undetermined(dims, rows, u, v, anchored).reason.format("x4") == \
        "x4 is in no factor: nothing determines it"
    assert gauge.undetermined(dims, np.full(5, 3), u, v, np.array([1, 2, 4])) is None


def _random_update(rng, n0: int):
    """An update of a random graph: new variables, pairs a factor joins, the variables of
    factors that are not relative, and every variable it touches."""
    new = int(rng.integers(0, 4))
    count = n0 + new
    if count == 0:
        return 0, [], [], [], []
    factors = int(rng.integers(1, 4))
    u, v, anchored, touched = [], [], [], list(range(n0, count))
    for _ in range(factors):
        a, b = (int(x) for x in rng.integers(0, count, size=2))
        touched += [a, b]
        if a != b:
            u.append(a)
            v.append(b)
        if rng.random() < 0.15:
            anchored.append(a)
    covered = set(touched[new:])
    for q in range(n0, count):  # a new variable is in some new factor
        if q not in covered:
            u.append(q)
            v.append(int(rng.integers(0, count)))
            touched += [q, v[-1]]
    return new, u, v, anchored, touched


@pytest.mark.parametrize("seed", range(20))
def test_the_union_find_kept_update_by_update_is_the_rule_on_the_whole_graph(seed):
    """Random updates: :class:`gauge.Components` refuses exactly the updates after which a
    variable they touch is in a component with no anchor (numpy's :func:`gauge.free_gauge` on
    every factor so far), names the smallest variable of the first such component, and a
    refused update changes nothing."""
    rng = np.random.default_rng(seed)
    c = gauge.Components()
    U, V, A = [], [], []
    refused = 0
    for step in range(60):
        n0 = len(c)
        # the first update: two new variables, one relative factor
        new, u, v, anchored, touched = (2, [0], [1], [], [0, 1]) if step == 0 else _random_update(rng, n0)
        if not touched:
            continue
        state = (list(c.parent), list(c.anchored), list(c.size))
        plan, finding = c.join(new, u, v, anchored, touched)
        count = n0 + new
        free = gauge.free_gauge(count, np.array(U + u, dtype=np.int64), np.array(V + v, dtype=np.int64),
                                np.array(A + anchored, dtype=np.int64))
        bad = sorted({t for t in touched if free[t]})
        if bad:
            labels = components(count, np.array(U + u, dtype=np.int64), np.array(V + v, dtype=np.int64))
            assert finding is not None and finding.variable == int(labels[bad].min())
            assert f"({int(np.count_nonzero(labels == finding.variable))} variable" in finding.reason
            assert (list(c.parent), list(c.anchored), list(c.size)) == state
            refused += 1
            continue
        assert finding is None
        c.commit(plan)
        U, V, A = U + u, V + v, A + anchored
        labels = components(count, np.array(U, dtype=np.int64), np.array(V, dtype=np.int64))
        roots = [c._root(x) for x in range(count)]
        assert roots == labels.tolist()
        assert [c.size[r] for r in roots] == np.bincount(labels, minlength=count)[labels].tolist()
        assert [c.anchored[r] for r in roots] == (~free).tolist()
    assert refused and len(c) > 10
