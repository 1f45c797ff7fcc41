"""The array path of ``Smoother.update_prepared``: one compiled call adds and marks, the same
factor as the general path, refusals that leave the smoother as it was."""

from __future__ import annotations

import numpy as np
import pytest

from lie_factors.errors import IndeterminantLinearSystem, InputError
from lie_factors.incremental import FactorArrays, Smoother, cholesky
from lie_factors.incremental.smoother import Smoother as SmootherClass
from lie_factors.kernels import registry
from lie_factors.se3 import exp as se3_exp


def _graph(poses=40, seed=0):
    """A noisy SE(3) chain with a closure every 5th pose and a prior: FactorArrays and the
    factors of each update (edges, priors) and the poses' start values."""
    rng = np.random.default_rng(seed)
    step = se3_exp(np.array([0.0, 0.0, 0.2, 1.0, 0.0, 0.0]))
    truth = [np.eye(4)]
    for _ in range(poses - 1):
        truth.append(truth[-1] @ step)
    edges, updates = [], []
    for i in range(poses):
        mine = []
        if i:
            mine.append(len(edges))
            edges.append((i - 1, i))
        if i >= 6 and i % 5 == 0:
            mine.append(len(edges))
            edges.append((i - 6, i))
        updates.append(mine)
    measured = np.array([np.linalg.inv(truth[a]) @ truth[b] @ se3_exp(0.01 * rng.normal(size=6))
                         for a, b in edges])
    info = np.array([np.diag(rng.uniform(50, 100, size=6)) for _ in edges])
    fa = FactorArrays("Pose3", np.array(edges), measured, info, [0], truth[0][None], 100 * np.eye(6)[None])
    start = [truth[i] @ se3_exp(0.05 * rng.normal(size=6)) for i in range(poses)]
    return fa, updates, start


def _replay(s: Smoother, fa, updates, start, upto=None):
    for i, mine in enumerate(updates[:upto]):
        s.update_prepared(fa, [i], start[i][None], mine, [0] if i == 0 else [])


#: The block factor's compiled kernels that Python calls (``cholesky``'s entry points).
KERNELS = ("init_variables", "append_factors", "link_adjacency", "unlink_factors", "relink", "clear_nodes",
           "mark_affected", "ordering_graph", "order_small", "reeliminate")


def test_an_update_on_the_array_path_is_one_compiled_call(monkeypatch):
    """An update adds its factors, marks, orders and re-eliminates in one compiled call; Python
    calls nothing else of the block factor's kernels, but where the call leaves the set to it:
    a set larger than the minimum-degree bound (COLAMD's), a batch step, pools to grow."""
    from lie_factors.incremental.ordering import SMALL_SET

    fa, updates, start = _graph(poses=60)
    s = Smoother(enableRelinearization=False)
    _replay(s, fa, updates, start, 3)  # compiles the entry points
    tag = registry.group("Pose3")
    calls = {name: 0 for name in ("entry", "general", "python_reelimination", *KERNELS)}

    def count(name, f):
        def counted(*a, **k):
            calls[name] += 1
            return f(*a, **k)
        return counted

    monkeypatch.setitem(cholesky._add_and_reeliminate, tag, count("entry", cholesky._add_and_reeliminate[tag]))
    for name in KERNELS:
        monkeypatch.setattr(cholesky, name, count(name, getattr(cholesky, name)))
    apply, reelim = SmootherClass._apply, cholesky.BlockFactor._reeliminate_set
    monkeypatch.setattr(SmootherClass, "_apply", lambda self, *a: count("general", apply)(self, *a))
    monkeypatch.setattr(cholesky.BlockFactor, "_reeliminate_set",
                        lambda self, *a: count("python_reelimination", reelim)(self, *a))
    one_call = 0
    for i in range(3, len(updates)):
        before = dict(calls)
        def room():
            return (s.bf.pools.ipool.shape[0], s.bf.pools.fpool.shape[0], s.bf.compactions,
                    s.bf._graph_ptr.shape[0], s.bf._graph_vars.shape[0])

        had = room()
        s.update_prepared(fa, [i], start[i][None], updates[i], [])
        made = {k: calls[k] - before[k] for k in calls}
        assert made["general"] == 0 and made["entry"] == 1
        # (the pools or the ordering graph's arrays grew: the call had no room)
        left = s.bf.last.batch or room() != had or s.bf.last.columns > max(SMALL_SET, s.bf.max_small)
        if not left:
            assert sum(made[k] for k in KERNELS) == 0 and made["python_reelimination"] == 0
            one_call += 1
    assert one_call >= 0.9 * (len(updates) - 3)


def test_a_set_larger_than_the_bound_is_ordered_and_eliminated_after_the_call(monkeypatch):
    """With the minimum-degree bound at 0, every set is left to the block factor's Python
    (COLAMD orders those above SMALL_SET): the same factor as with the bound, to rounding."""
    fa, updates, start = _graph(seed=3)
    one = Smoother(enableRelinearization=False, wildfireThreshold=0.0)
    left = Smoother(enableRelinearization=False, wildfireThreshold=0.0)
    left.bf.max_small = 0
    calls = []
    reelim = cholesky.BlockFactor._reeliminate_set
    monkeypatch.setattr(cholesky.BlockFactor, "_reeliminate_set", lambda self, *a: calls.append(1) or reelim(self, *a))
    _replay(one, fa, updates, start)
    n_one = len(calls)
    _replay(left, fa, updates, start)
    assert len(calls) - n_one > n_one  # (sets of more than SMALL_SET variables left to Python)
    keys = list(range(len(updates)))
    assert np.max(np.abs(one.estimate_matrices(keys) - left.estimate_matrices(keys))) <= 1e-9


def test_the_array_path_builds_the_factor_the_general_path_builds():
    fa, updates, start = _graph(seed=1)
    # the general path on every update (a check every update, a threshold nothing reaches);
    # exact solves (wildfire's estimate depends on when δ is solved, and the check solves)
    general = Smoother(relinearizeSkip=1, relinearizeThreshold=1e9, wildfireThreshold=0.0)
    arrays = Smoother(enableRelinearization=False, wildfireThreshold=0.0)
    _replay(general, fa, updates, start)
    _replay(arrays, fa, updates, start)
    assert arrays.bf.nf == general.bf.nf == fa.E + fa.Q
    a, g = arrays.bf, general.bf
    nj = g.njac
    assert a.njac == nj
    assert np.max(np.abs(a.store.jac[:nj] - g.store.jac[:nj])) <= 1e-12 * np.max(np.abs(g.store.jac[:nj]))
    for x, y in zip(a.dense_factor(), g.dense_factor()):
        assert np.max(np.abs(x - y)) <= 1e-10 * max(1.0, np.max(np.abs(y)))
    keys = list(range(len(updates)))
    assert np.max(np.abs(arrays.estimate_matrices(keys) - general.estimate_matrices(keys))) <= 1e-9
    assert arrays.getFactorsUnsafe().size() == fa.E + fa.Q


def test_refusals_on_the_array_path_leave_the_smoother_as_it_was():
    fa, updates, start = _graph(seed=2)
    # exact solves: reading the estimate between updates does not change later ones
    s = Smoother(enableRelinearization=False, wildfireThreshold=0.0)
    _replay(s, fa, updates, start, 20)
    before = (s.estimate_matrices(list(range(20))), s.bf.nv, s.bf.nf, len(s.keys), s.update_count)

    def refused(match, exc=InputError, **kw):
        args = dict(fa=fa, keys=[20], values=start[20][None], edges=updates[20], priors=[])
        args.update(kw)
        with pytest.raises(exc, match=match):
            s.update_prepared(**args)
        assert (s.bf.nv, s.bf.nf, len(s.keys), s.update_count) == before[1:]
        assert np.array_equal(s.estimate_matrices(list(range(20))), before[0])

    refused("already a variable", keys=[3])
    refused("given twice", keys=[20, 20], values=np.stack([start[20]] * 2))
    refused("no new factor", keys=[20, 77], values=np.stack([start[20]] * 2))
    refused("has no value", edges=[len(fa.edge_keys) - 1])  # pose 39's closure: 33 is unknown
    refused("indices must be in", edges=[len(fa.edge_keys)])
    refused("expected shape", values=start[20][None, :3])
    refused("not finite", values=np.full((1, 4, 4), np.nan))
    # two new poses tied only to each other: the gauge is free, the update undetermined
    lone = FactorArrays("Pose3", [[200, 201]], np.eye(4)[None], np.eye(6)[None])
    with pytest.raises(IndeterminantLinearSystem, match="undetermined"):
        s.update_prepared(lone, [200, 201], np.stack([np.eye(4)] * 2), [0], [])
    assert (s.bf.nv, s.bf.nf, len(s.keys), s.update_count) == before[1:]
    # the next updates work and agree with a smoother never refused
    for i in range(20, len(updates)):
        s.update_prepared(fa, [i], start[i][None], updates[i], [])
    t = Smoother(enableRelinearization=False, wildfireThreshold=0.0)
    _replay(t, fa, updates, start)
    assert np.array_equal(s.bf.dense_factor()[1], t.bf.dense_factor()[1])
    keys = list(range(len(updates)))
    assert np.max(np.abs(s.estimate_matrices(keys) - t.estimate_matrices(keys))) <= 1e-12


def _gtsam_updates(fa, updates, start):
    """The same updates as GTSAM's factor objects: (graph, values) per pose."""
    import gtsam

    out = []
    for i, mine in enumerate(updates):
        g = gtsam.NonlinearFactorGraph()
        for k in mine:
            a, b = (int(x) for x in fa.edge_keys[k])
            g.add(gtsam.BetweenFactorPose3(a, b, gtsam.Pose3(np.linalg.inv(fa.Minv[k])),
                                           gtsam.noiseModel.Gaussian.Information(fa.R[k].T @ fa.R[k])))
        if i == 0:
            g.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
        v = gtsam.Values()
        v.insert(i, gtsam.Pose3(start[i]))
        out.append((g, v))
    return out


def test_updates_of_gtsam_factor_objects_take_the_array_path_and_equal_the_general_one(monkeypatch):
    """update() with GTSAM's Between/Prior objects runs on the array path, relinearizing updates
    too, and every factor, estimate and report equals the general path's."""
    import lie_factors.incremental.array_path as array_path_module

    fa, updates, start = _graph(seed=4)
    steps = _gtsam_updates(fa, updates, start)
    fast = Smoother()
    general_calls = []
    apply = SmootherClass._apply
    monkeypatch.setattr(SmootherClass, "_apply", lambda self, *a: general_calls.append(1) or apply(self, *a))
    fast_results = [fast.update(g, v) for g, v in steps]
    assert not general_calls
    assert fast.relinearizations > 0  # (the updates every relinearizeSkip-th relinearized some)
    monkeypatch.setattr(array_path_module, "try_objects", lambda s, nf: None)
    slow = Smoother()
    slow_results = [slow.update(g, v) for g, v in steps]
    assert len(general_calls) == len(steps)
    assert fast.relinearizations == slow.relinearizations
    assert np.array_equal(fast.bf.dense_factor()[1], slow.bf.dense_factor()[1])
    keys = list(range(len(updates)))
    assert np.array_equal(fast.estimate_matrices(keys), slow.estimate_matrices(keys))
    for a, b in zip(fast_results, slow_results):
        assert a.getNewFactorsIndices() == b.getNewFactorsIndices()
        assert a.getObservedKeys() == b.getObservedKeys()
        assert list(a.getMarkedKeys()) == list(b.getMarkedKeys())
        assert a.getVariablesReeliminated() == b.getVariablesReeliminated()
        assert a.getVariablesRelinearized() == b.getVariablesRelinearized()
    fg, sg = fast.getFactorsUnsafe(), slow.getFactorsUnsafe()
    assert fg.size() == sg.size()
    for k in range(fg.size()):
        assert type(fg.at(k)) is type(sg.at(k)) and fg.at(k).equals(sg.at(k), 0.0)


def test_gtsam_object_updates_the_array_path_refuses_read_as_the_general_paths(monkeypatch):
    import gtsam
    import lie_factors.incremental.array_path as array_path_module

    fa, updates, start = _graph(seed=5)
    steps = _gtsam_updates(fa, updates, start)
    noise = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    unknown = gtsam.NonlinearFactorGraph()
    unknown.add(gtsam.BetweenFactorPose3(11, 99, gtsam.Pose3(), noise))
    known = gtsam.Values()
    known.insert(3, gtsam.Pose3())
    lone = gtsam.NonlinearFactorGraph()
    lone.add(gtsam.BetweenFactorPose3(200, 201, gtsam.Pose3(), noise))
    two = gtsam.Values()
    two.insert(200, gtsam.Pose3())
    two.insert(201, gtsam.Pose3())
    cases = [(unknown, gtsam.Values()), (gtsam.NonlinearFactorGraph(), known), (lone, two)]

    def refusals():
        s = Smoother()
        for g, v in steps[:12]:
            s.update(g, v)
        before = (s.bf.nv, s.bf.nf, len(s.keys), s.update_count, s.estimate_matrices(list(range(12))))
        out = []
        for g, v in cases:
            with pytest.raises((InputError, IndeterminantLinearSystem)) as info:
                s.update(g, v)
            out.append((type(info.value), str(info.value)))
            assert (s.bf.nv, s.bf.nf, len(s.keys), s.update_count) == before[:4]
            assert np.array_equal(s.estimate_matrices(list(range(12))), before[4])
        return out

    fast = refusals()
    monkeypatch.setattr(array_path_module, "try_objects", lambda s, nf: None)
    assert fast == refusals()
    assert "uses key 99, which has no value" in fast[0][1] and "already a variable" in fast[1][1]


def test_adaptive_reordering_keeps_every_update_on_the_general_path(monkeypatch):
    """With enableAdaptiveReorder an update may order every variable afresh: the general path's
    decision, so no update takes the array path (from arrays or from factor objects)."""
    fa, updates, start = _graph(seed=6)
    calls = []
    apply = SmootherClass._apply
    monkeypatch.setattr(SmootherClass, "_apply", lambda self, *a: calls.append(1) or apply(self, *a))
    s = Smoother(enableAdaptiveReorder=True)
    _replay(s, fa, updates, start)
    assert len(calls) == len(updates)
    t = Smoother(enableAdaptiveReorder=True)
    for g, v in _gtsam_updates(fa, updates, start):
        t.update(g, v)
    assert len(calls) == 2 * len(updates)


def _general_only(monkeypatch):
    """Every update of ``update_prepared`` through the general path."""
    import lie_factors.incremental.smoother as smoother_module

    monkeypatch.setattr(smoother_module, "try_update", lambda *a, **k: None)


@pytest.mark.parametrize("threshold", [0.0, 0.01])
def test_relinearizing_updates_on_the_array_path_equal_the_general_path(monkeypatch, threshold):
    """Every other update relinearizes (every variable at threshold 0, some at 0.01): the array
    path moves the same θ, linearizes the same factors again and reports the same counts as the
    general path, bit for bit."""
    fa, updates, start = _graph(seed=7)

    def run():
        s = Smoother(relinearizeSkip=2, relinearizeThreshold=threshold)
        counts = []
        for i, mine in enumerate(updates):
            r = s.update_prepared(fa, [i], start[i][None], mine, [0] if i == 0 else [])
            counts.append((r.getVariablesRelinearized(), r.getVariablesReeliminated()))
            s.estimate_matrix(i)  # (δ solved between updates, as a user's loop reads it)
        return s, counts

    fast, fast_counts = run()
    _general_only(monkeypatch)
    slow, slow_counts = run()
    assert fast_counts == slow_counts
    relinearized = [r for r, _ in fast_counts]
    assert sum(relinearized) > 0 and relinearized.count(0) > len(updates) // 2 - 1
    if threshold == 0.0:  # every variable there was before the update, each other update
        assert relinearized == [i if i % 2 else 0 for i in range(len(updates))]
    el_fast, el_slow = fast.elements["Pose3"], slow.elements["Pose3"]
    assert np.array_equal(el_fast.X[:el_fast.n], el_slow.X[:el_slow.n])
    nj = slow.bf.njac
    assert np.array_equal(fast.bf.store.jac[:nj], slow.bf.store.jac[:nj])
    keys = list(range(len(updates)))
    assert np.array_equal(fast.estimate_matrices(keys), slow.estimate_matrices(keys))


def test_a_failed_relinearizing_update_leaves_theta_and_the_jacobians_as_they_were(monkeypatch):
    """A relinearizing update that fails in the re-elimination, after θ moved and the Jacobians
    were replaced: both are put back, and the smoother goes on as one that never failed."""
    fa, updates, start = _graph(seed=8)

    def smoother():
        return Smoother(relinearizeSkip=2, relinearizeThreshold=0.0, wildfireThreshold=0.0)

    s = smoother()
    _replay(s, fa, updates, start, 21)
    assert (s.update_count + 1) % 2 == 0  # the next update relinearizes every variable
    el = s.elements["Pose3"]
    before = (el.X[:el.n].copy(), s.bf.store.jac[:s.bf.njac].copy(), s.bf.nv, s.bf.nf, s.relinearizations,
              len(s.keys), s.update_count)
    reeliminate = cholesky.reeliminate

    def interrupted(*a):
        raise KeyboardInterrupt

    monkeypatch.setattr(cholesky, "reeliminate", interrupted)
    with pytest.raises(KeyboardInterrupt):
        s.update_prepared(fa, [21], start[21][None], updates[21], [])
    monkeypatch.setattr(cholesky, "reeliminate", reeliminate)
    assert np.array_equal(el.X[:el.n], before[0])
    assert np.array_equal(s.bf.store.jac[:s.bf.njac], before[1])
    assert (s.bf.nv, s.bf.nf, s.relinearizations, len(s.keys), s.update_count) == before[2:]
    for i in range(21, len(updates)):
        s.update_prepared(fa, [i], start[i][None], updates[i], [])
    t = smoother()
    _replay(t, fa, updates, start)
    keys = list(range(len(updates)))
    assert np.array_equal(s.estimate_matrices(keys), t.estimate_matrices(keys))
