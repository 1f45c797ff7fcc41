"""The consistency stage before GNC and the final check after it.

References that share no code with what they test: the cycle χ² against a
numerical linearization built from GTSAM's own Pose2/Pose3 (Expmap, compose);
the clique solver against brute force; the leave-group-out statistic against a
dense inverse of GTSAM's own linearization.
"""

from __future__ import annotations

from types import SimpleNamespace

import dataclasses
import itertools
import json
from pathlib import Path

import gtsam
import numpy as np
import pytest

import lie_factors as lf
from lie_factors.app import cli, demo
from lie_factors.backends import build_graph
from lie_factors.g2o import read_pose_graph
from lie_factors.posegraph.graph import PoseGraph
from lie_factors.app.plotting import positions
from support.runs import run
from lie_factors.robust import clique, consistency
from lie_factors.robust import gnc as gncm
from lie_factors.robust import inner
from lie_factors.robust import leave_out
from lie_factors.robust.leave_out import leave_out_chi2
from lie_factors.robust.statistics import chi2_inlier_threshold, f_quantile
from lie_factors.robust.rejection import closure_groups, reject_false_closures, relaxation_iterations, tls_cost
from lie_factors.interop import values_from_matrices
from lie_factors.robust.solvers import ArraySolver, GraphSolver
from lie_factors.batch.graph import Problem
from lie_factors.batch.system import LinearSystem
from lie_factors.initialization import initialize
from lie_factors.robust.screening import CLIQUE, GATE, KEPT, screen_closures
from lie_factors.kernels import registry
from lie_factors.testing import outliers

# --------------------------------------------------------------------------- #
# The cycle χ² against a numerical linearization with GTSAM's poses
# --------------------------------------------------------------------------- #

GROUPS = {"Pose2": (gtsam.Pose2, 3), "Pose3": (gtsam.Pose3, 6)}


def _random_pose(rng, name, scale=1.0):
    Pose, n = GROUPS[name]
    return Pose.Expmap(rng.normal(scale=scale, size=n))


def _random_cov(rng, n, scale):
    B = rng.normal(size=(n, n))
    return scale * (B @ B.T / n + 0.2 * np.eye(n))


def _reference_chi2(name, odo, odo_cov, a, b, Z1, S1, c, d, Z2, S2):
    """χ² of L = Z1⁻¹·T_ac·Z2·T_db, every measurement perturbed on the right by its own noise,
    Log(L) linearized by central differences in all the noises at once."""
    Pose, n = GROUPS[name]
    N = len(odo) + 1

    def relative(x, y, xi):
        # T_xy from the odometry, edge m perturbed by xi[m]
        T = Pose()
        if x <= y:
            for m in range(x, y):
                T = T.compose(odo[m].compose(Pose.Expmap(xi[m])))
            return T
        return relative(y, x, xi).inverse()

    def log_L(noise):
        xi = noise[: (N - 1) * n].reshape(N - 1, n)
        z1 = noise[(N - 1) * n:(N - 1) * n + n]
        z2 = noise[(N - 1) * n + n:]
        L = (Z1.compose(Pose.Expmap(z1))).inverse().compose(relative(a, c, xi)) \
            .compose(Z2.compose(Pose.Expmap(z2))).compose(relative(d, b, xi))
        return Pose.Logmap(L)

    dim = (N - 1) * n + 2 * n
    r = log_L(np.zeros(dim))
    J = np.zeros((n, dim))
    h = 1e-6
    for k in range(dim):
        e = np.zeros(dim)
        e[k] = h
        J[:, k] = (log_L(e) - log_L(-e)) / (2 * h)
    S = np.zeros((dim, dim))
    for m in range(N - 1):
        S[m * n:(m + 1) * n, m * n:(m + 1) * n] = odo_cov[m]
    S[(N - 1) * n:(N - 1) * n + n, (N - 1) * n:(N - 1) * n + n] = S1
    S[(N - 1) * n + n:, (N - 1) * n + n:] = S2
    Sig = J @ S @ J.T
    return float(r @ np.linalg.solve(Sig, r))


def _chain(rng, name, N, backwards=()):
    Pose, n = GROUPS[name]
    odo = [_random_pose(rng, name, 0.3) for _ in range(N - 1)]
    cov = [_random_cov(rng, n, 1e-2) for _ in range(N - 1)]
    g = registry.group(name)
    frm = np.arange(N - 1)
    to = frm + 1
    Z = np.array([p.matrix() for p in odo])
    S = np.array(cov)
    # some edges given backwards (k+1 → k): the chain must turn them around
    for k in backwards:
        frm[k], to[k] = to[k], frm[k]
        Z[k] = odo[k].inverse().matrix()
        Ad = odo[k].AdjointMap()
        S[k] = Ad @ cov[k] @ Ad.T
    return odo, cov, consistency.chain(g, N, frm, to, Z, S)


@pytest.mark.parametrize("name", ["Pose2", "Pose3"])
@pytest.mark.parametrize("ends", [(0, 7, 1, 6), (1, 6, 0, 7), (2, 5, 4, 7), (5, 1, 6, 3), (0, 3, 4, 7),
                                  (6, 2, 1, 5), (3, 3, 3, 3)])
def test_pair_chi2_equals_a_numerical_linearization(name, ends):
    rng = np.random.default_rng(hash(ends) % 2**32)
    Pose, n = GROUPS[name]
    odo, cov, ch = _chain(rng, name, 8, backwards=(2, 5))
    a, b, c, d = ends
    Z1, Z2 = _random_pose(rng, name, 0.5), _random_pose(rng, name, 0.5)
    S1, S2 = _random_cov(rng, n, 1e-2), _random_cov(rng, n, 3e-3)
    ours = consistency.pair_chi2(ch, np.array([a, c]), np.array([b, d]), np.array([Z1.matrix(), Z2.matrix()]),
                                 np.array([S1, S2]), np.array([0]), np.array([1]))[0]
    ref = _reference_chi2(name, odo, cov, a, b, Z1, S1, c, d, Z2, S2)
    assert ours == pytest.approx(ref, rel=1e-6)


@pytest.mark.parametrize("name", ["Pose2", "Pose3"])
def test_gate_chi2_is_the_cycle_with_the_odometry_alone(name):
    rng = np.random.default_rng(3)
    Pose, n = GROUPS[name]
    odo, cov, ch = _chain(rng, name, 9, backwards=(0, 4))
    a = np.array([0, 7, 3, 8])
    b = np.array([8, 2, 4, 0])
    Z = [_random_pose(rng, name, 0.5) for _ in a]
    S = [_random_cov(rng, n, 1e-2) for _ in a]
    ours = consistency.gate_chi2(ch, a, b, np.array([z.matrix() for z in Z]), np.array(S))
    for k in range(len(a)):
        ref = _reference_chi2(name, odo, cov, a[k], b[k], Z[k], S[k], b[k], b[k], Pose(), np.zeros((n, n)))
        assert ours[k] == pytest.approx(ref, rel=1e-6)


def test_gate_is_nan_across_segments_and_the_chain_restarts_there():
    rng = np.random.default_rng(4)
    g = registry.group("Pose2")
    Z = np.array([_random_pose(rng, "Pose2").matrix() for _ in range(3)])
    S = np.array([np.eye(3) * 1e-2] * 3)
    ch = consistency.chain(g, 5, np.array([0, 1, 3]), np.array([1, 2, 4]), Z, S)  # no edge 2 → 3
    np.testing.assert_array_equal(ch.segment, [0, 0, 0, 1, 1])
    np.testing.assert_array_equal(ch.T[3], np.eye(3))
    x = consistency.gate_chi2(ch, np.array([0, 3]), np.array([4, 4]), np.array([np.eye(3)] * 2),
                              np.array([np.eye(3)] * 2))
    assert np.isnan(x[0]) and np.isfinite(x[1])


def test_reverse_turns_an_edge_around():
    rng = np.random.default_rng(5)
    g = registry.group("Pose3")
    P = _random_pose(rng, "Pose3")
    S = _random_cov(rng, 6, 1.0)
    Z = np.array([P.matrix(), P.matrix()])
    C = np.array([S, S])
    consistency.reverse(g, Z, C, np.array([True, False]))
    np.testing.assert_allclose(Z[0], P.inverse().matrix(), atol=1e-14)
    np.testing.assert_allclose(C[0], P.AdjointMap() @ S @ P.AdjointMap().T, rtol=1e-13)
    np.testing.assert_array_equal(Z[1], P.matrix())
    np.testing.assert_array_equal(C[1], S)


def test_near_pairs_are_exactly_the_pairs_within_the_window():
    rng = np.random.default_rng(6)
    a = rng.integers(0, 300, 200)
    b = a + rng.integers(2, 300, 200)
    for w in (1, 5, 40):
        f, s = consistency.near_pairs(a, b, w)
        got = {(min(i, j), max(i, j)) for i, j in zip(f.tolist(), s.tolist())}
        assert len(got) == len(f)
        want = {(i, j) for i in range(200) for j in range(i + 1, 200)
                if abs(a[i] - a[j]) <= w and abs(b[i] - b[j]) <= w}
        assert got == want


# --------------------------------------------------------------------------- #
# Maximum clique / minimum vertex cover against brute force
# --------------------------------------------------------------------------- #

def _brute_cover(n, edges):
    for k in range(n + 1):
        for S in itertools.combinations(range(n), k):
            s = set(S)
            if all(i in s or j in s for i, j in edges):
                return k
    return n


def test_vertex_cover_is_minimum_on_random_graphs():
    rng = np.random.default_rng(7)
    for _ in range(250):
        n = int(rng.integers(1, 14))
        p = rng.uniform(0.05, 0.8)
        edges = np.array([(i, j) for i in range(n) for j in range(i + 1, n) if rng.random() < p],
                         dtype=np.int64).reshape(-1, 2)
        res = clique.minimum_vertex_cover(n, edges)
        cover = set(res.cover.tolist())
        assert all(i in cover or j in cover for i, j in edges)
        assert res.exact
        assert len(cover) == _brute_cover(n, edges.tolist())


def test_the_kept_set_is_a_maximum_clique_of_the_consistency_graph():
    rng = np.random.default_rng(8)
    for _ in range(100):
        n = int(rng.integers(2, 12))
        bad = np.array([(i, j) for i in range(n) for j in range(i + 1, n) if rng.random() < 0.3],
                       dtype=np.int64).reshape(-1, 2)
        kept, res = clique.maximum_clique_complement(n, bad)
        k = set(kept.tolist())
        assert not any(i in k and j in k for i, j in bad)  # a clique: no inconsistent pair inside
        best = max(len(S) for r in range(n + 1) for S in itertools.combinations(range(n), r)
                   if not any(i in S and j in S for i, j in bad.tolist()))
        assert len(kept) == best


def test_an_exhausted_search_still_returns_a_cover_and_says_it_is_not_exact():
    rng = np.random.default_rng(9)
    n = 400
    edges = rng.integers(0, n, size=(1200, 2))
    edges = edges[edges[:, 0] != edges[:, 1]]
    res = clique.minimum_vertex_cover(n, edges, budget=50)
    cover = set(res.cover.tolist())
    assert all(i in cover or j in cover for i, j in edges.tolist())
    assert not res.exact


def test_vertex_cover_refuses_bad_edges():
    with pytest.raises(ValueError, match="self-loop"):
        clique.minimum_vertex_cover(3, np.array([[1, 1]]))
    with pytest.raises(ValueError, match="vertices 0..2"):
        clique.minimum_vertex_cover(3, np.array([[0, 3]]))


# --------------------------------------------------------------------------- #
# The stage on graphs
# --------------------------------------------------------------------------- #

def _chain_graph(n=150, seed=1):
    prob = demo.simulate(n, seed=seed)
    between = demo.between_graph(prob)
    return prob, between


def _dataset(between, keys, vertices, name="test") -> PoseGraph:
    pg = PoseGraph.from_gtsam(between, "Pose3", np.asarray(keys))
    import dataclasses

    return dataclasses.replace(pg, vertices=vertices, name=name)


def test_clustered_false_closures_agree_with_one_another_exactly():
    prob, between = _chain_graph(120)
    graph, slots = outliers.plant_clustered_false_loop_closures(between, list(range(120)), 8, 3, True,
                                                                size=(4, 4))
    f = [graph.at(int(k)) for k in slots]
    odo = {i: prob.odometry[i] for i in range(119)}
    for x, y in zip(f[:3], f[1:4]):  # one cluster: i+k → j+k
        (i, j), (i2, j2) = x.keys(), y.keys()
        assert (i2, j2) == (i + 1, j + 1)
        cycle = x.measured().inverse().compose(odo[i]).compose(y.measured()).compose(odo[j].inverse())
        assert np.max(np.abs(gtsam.Pose3.Logmap(cycle))) < 1e-9


def test_screening_rejects_planted_closures_and_keeps_the_true_ones():
    prob, between = _chain_graph(200, seed=2)
    lc = int(outliers.loop_closure_mask(between).sum())
    graph, planted = outliers.plant_false_loop_closures(between, list(range(200)), lc // 3, 2, True)
    pg = PoseGraph.from_gtsam(graph, "Pose3", np.arange(200))
    s = screen_closures(pg)
    rejected = set(s.rejected.tolist())
    assert rejected <= set(planted.tolist())       # no true closure set aside
    assert len(rejected) >= 0.9 * len(planted)     # and most false ones are
    assert set(np.unique(s.stage).tolist()) <= {KEPT, GATE, CLIQUE}
    assert s.exact
    # every kept pair that was tested is consistent (the kept set is a clique)
    np.testing.assert_array_equal(s.closures, pg.loop_closures())


@pytest.fixture(params=["paths", "selected inversion"])
def leave_out_way(request, monkeypatch):
    """Each way the groups in the graph are computed, forced (the rule picks one per call)."""
    monkeypatch.setattr(leave_out, "_selected_inverse_is_cheaper", lambda *a: request.param != "paths")
    return request.param


def test_leave_out_chi2_equals_a_dense_reference(leave_out_way):
    prob, between = _chain_graph(40, seed=4)
    graph, planted = outliers.plant_false_loop_closures(between, list(range(40)), 3, 4, True)
    pg = PoseGraph.from_gtsam(graph, "Pose3", np.arange(40))
    pg = pg.with_prior(0, prob.truth[0].matrix(), np.diag(1.0 / demo.PRIOR_SIGMAS ** 2))
    X = np.array([prob.initial.atPose3(k).matrix() for k in range(40)])
    E = len(pg.edge_keys)
    w = np.ones(E + 1)
    lc = pg.loop_closures()
    w[planted] = 0.0
    inside = [lc[~np.isin(lc, planted)][:1], lc[~np.isin(lc, planted)][1:4]]
    outside = [planted[:1], planted[1:]]
    T = leave_out_chi2(pg, X, w, inside + outside)
    np.testing.assert_allclose(T, _dense_chi2(pg, X, w, inside + outside, (-1, -1, 1, 1)), rtol=1e-8)


def test_leave_out_chi2_where_a_poses_block_of_h_holds_exact_zeros(leave_out_way):
    """A planar grid graph (city10000's kind): headings in quarter turns and isotropic translation
    information, so Rᵀ·Ω·R has no x–y term and the blocks of H within a pose hold exact zeros; the
    entries of the factor that selected inversion reads there must stay in its pattern all the same."""
    P = 40
    rng = np.random.default_rng(7)
    theta = np.cumsum(rng.integers(-1, 2, P)) * (np.pi / 2)
    steps = np.round(np.stack([np.cos(theta), np.sin(theta)], axis=1))
    xy = np.cumsum(steps, axis=0)
    truth = [gtsam.Pose2(x, y, t) for (x, y), t in zip(xy, theta)]
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.05]))
    between = gtsam.NonlinearFactorGraph()
    exact = [(k, k + 1) for k in range(P - 1)] + [(2, 20), (5, 33)]
    noisy = [(9, 24), (12, 37)]
    for i, j in exact + noisy:
        z = truth[i].between(truth[j])
        if (i, j) in noisy:
            z = z.compose(gtsam.Pose2(*rng.normal(0, [0.1, 0.1, 0.05])))
        between.add(gtsam.BetweenFactorPose2(i, j, z, noise))
    pg = PoseGraph.from_gtsam(between, "Pose2", np.arange(P)).with_first_prior()
    X = np.array([truth[k].matrix() for k in range(P)])
    w = np.ones(len(pg.edge_keys) + 1)
    lc = pg.loop_closures()
    groups = [lc[[0, 2]], lc[[1, 3]], lc[2:3], lc[3:4]]
    T = leave_out_chi2(pg, X, w, groups)
    np.testing.assert_allclose(T, _dense_chi2(pg, X, w, groups, (-1, -1, -1, -1)), rtol=1e-8)
    assert np.all(T > 0)
    # the cause: every entry among a group's poses, within each pose's block too, is in the pattern
    # the factor is analysed from, though H holds exact zeros there
    problem = Problem.from_pose_graph(pg, X)
    problem.linearize()
    between = next(g for g in problem.groups if g.kind == "between")
    ends = [np.unique(np.concatenate([between.v1[G], between.v2[G]])) for G in groups]
    colptr, rowind, _, pos = leave_out._system_with_blocks(problem, between, w, ends)
    entries = set(zip(rowind.tolist(), np.repeat(np.arange(len(colptr) - 1), np.diff(colptr)).tolist()))
    for V in ends:
        rows = pos[(problem.var_offsets[V][:, None] + np.arange(3)).reshape(-1)]
        assert all((max(a, b), min(a, b)) in entries for a in rows.tolist() for b in rows.tolist())
    system = LinearSystem(problem)
    system.weights[:] = w
    system.assemble()
    p = system.pattern
    var = p.scalar_order // 3  # each matrix row's pose (every variable a Pose2 here)
    col = np.repeat(np.arange(p.n), np.diff(p.colptr))
    within = (var[p.rowind] == var[col]) & (p.rowind != col)
    assert np.any(system.data[within] == 0.0)  # the exact zeros the test is about


def _dense_chi2(pg, X, w, groups, signs):
    """T_G from a dense inverse of the Gauss–Newton matrix GTSAM linearizes (weight 0 = left out)."""
    native = pg.factor_graph()
    P = len(pg.keys)
    values = gtsam.Values()
    for k in range(P):
        M = X[k]
        values.insert(int(pg.keys[k]), gtsam.Pose3(M) if M.shape[0] == 4
                      else gtsam.Pose2(M[0, 2], M[1, 2], np.arctan2(M[1, 0], M[0, 0])))
    kept = gtsam.NonlinearFactorGraph()
    for k in range(native.size()):
        if w[k]:
            kept.add(native.at(k))
    ordering = gtsam.Ordering()
    for k in pg.keys.tolist():
        ordering.push_back(int(k))
    A, _ = kept.linearize(values).jacobian(ordering)
    Hinv = np.linalg.inv(A.T @ A)
    n = A.shape[1] // P
    col = {int(k): i for i, k in enumerate(pg.keys.tolist())}
    out = []
    for G, sign in zip(groups, signs):
        rows, res = [], []
        for e in G:
            f = native.at(int(e))
            Aj, bj = f.linearize(values).jacobian()  # columns in the factor's key order
            Ag = np.zeros((n, A.shape[1]))
            for i, key in enumerate(f.keys()):
                Ag[:, n * col[key]:n * col[key] + n] = Aj[:, n * i:n * i + n]
            rows.append(Ag)
            res.append(bj)
        Ag, b = np.vstack(rows), np.concatenate(res)
        M = np.eye(len(b)) + sign * Ag @ Hinv @ Ag.T
        out.append(float(b @ np.linalg.solve(M, b)))
    return np.array(out)


def test_leave_out_chi2_of_groups_sharing_poses_equals_a_dense_reference(leave_out_way):
    """Planar closures in groups whose members share a pose (one place seen from two, a run of
    closures between the same places), in the graph and out of it, and one closure alone."""
    rng = np.random.default_rng(7)
    P = 40
    graph = gtsam.NonlinearFactorGraph()
    odo = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.05, 0.02]))
    loop = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.05]))
    truth = [gtsam.Pose2(0.0, 0.0, 0.0)]
    for k in range(1, P):
        truth.append(truth[-1].compose(gtsam.Pose2(1.0, 0.0, 2 * np.pi / 20)))

    def noisy(a, b, sigmas):
        d = truth[a].between(truth[b])
        return d.retract(rng.normal(0.0, sigmas))

    for k in range(P - 1):
        graph.add(gtsam.BetweenFactorPose2(k, k + 1, noisy(k, k + 1, [0.05, 0.05, 0.02]), odo))
    closures = [(0, 20), (0, 21), (1, 21), (2, 22), (5, 25), (10, 30), (11, 31), (12, 32), (11, 30), (15, 35)]
    for a, b in closures:
        graph.add(gtsam.BetweenFactorPose2(a, b, noisy(a, b, [0.1, 0.1, 0.05]), loop))
    pg = PoseGraph.from_gtsam(graph, "Pose2", np.arange(P))
    pg = pg.with_prior(0, truth[0].matrix(), np.diag([1e4, 1e4, 1e4]))
    X = np.array([t.retract(rng.normal(0.0, [0.02, 0.02, 0.01])).matrix() for t in truth])
    e = P - 1  # the first closure's edge
    w = np.ones(len(pg.edge_keys) + 1)
    w[[e + 6, e + 7, e + 8]] = 0.0  # (10, 30), (11, 31), (12, 32) out of the graph
    groups = [[e, e + 1, e + 2, e + 3], [e + 4], [e + 9], [e + 6, e + 7, e + 8], [e + 6]]
    T = leave_out_chi2(pg, X, w, groups)
    np.testing.assert_allclose(T, _dense_chi2(pg, X, w, groups, (-1, -1, -1, 1, 1)), rtol=1e-8)


def test_closure_groups_join_runs_of_closures_between_the_same_places():
    prob, between = _chain_graph(200, seed=5)
    graph, slots = outliers.plant_clustered_false_loop_closures(between, list(range(200)), 6, 6, True,
                                                                size=(6, 6))
    pg = PoseGraph.from_gtsam(graph, "Pose3", np.arange(200))
    groups = closure_groups(pg, slots)
    assert sorted(len(g) for g in groups) == [6]
    assert sorted(np.concatenate(groups).tolist()) == sorted(slots.tolist())


# --------------------------------------------------------------------------- #
# The whole --gnc pipeline
# --------------------------------------------------------------------------- #

def _planted_dataset(n, seed, kind, fraction):
    prob, between = _chain_graph(n, seed=seed)
    lc = int(outliers.loop_closure_mask(between).sum())
    plant = (outliers.plant_false_loop_closures if kind == "uniform"
             else outliers.plant_clustered_false_loop_closures)
    graph, planted = plant(between, list(range(n)), max(3, int(fraction * lc)), seed, True)
    X = np.array([prob.initial.atPose3(k).matrix() for k in range(n)])
    return _dataset(graph, np.arange(n), X), planted, prob


@pytest.mark.parametrize("kind", ["uniform", "clustered"])
def test_gnc_with_the_consistency_stage_rejects_uniform_and_clustered_false_closures(kind):
    ds, planted, _ = _planted_dataset(200, 11, kind, 0.3)
    record, _, _ = run(ds, backend="batch", gnc="tls")
    assert set(record.outliers) == set(planted.tolist())
    assert set(record.rejected_by) == {str(k) for k in planted.tolist()}
    assert set(record.rejected_by.values()) <= {"gate", "clique", "gnc", "final"}


def test_on_a_clean_graph_the_result_is_the_plain_optimum_and_nothing_is_rejected():
    prob, between = _chain_graph(200, seed=12)
    X = np.array([prob.initial.atPose3(k).matrix() for k in range(200)])
    ds = _dataset(between, np.arange(200), X)
    record, result, _ = run(ds, backend="batch", gnc="tls")
    assert record.outliers == [] and record.rejected_by == {}
    plain_record, plain, _ = run(_dataset(between, np.arange(200), X), backend="batch")
    # the same optimum: the error to 1e-6; the poses as close as LM's stopping rule (relative
    # decrease 1e-5) brings two runs from different starts
    graph = demo.build_graph(prob, gtsam)
    assert graph.error(result.values) == pytest.approx(graph.error(plain.values), rel=1e-6)
    for k in range(200):
        d = plain.values.atPose3(k).localCoordinates(result.values.atPose3(k))
        assert np.max(np.abs(d)) < 1e-4


def test_cli_reports_the_stage_of_each_rejected_closure(tmp_path, capsys):
    ds, planted, prob = _planted_dataset(120, 13, "uniform", 0.3)
    path = tmp_path / "g.g2o"
    from lie_factors.g2o import write_g2o

    write_g2o(str(path), ds.factor_graph(), prob.initial)
    assert cli.main(["posegraph", str(path), "--gnc", "tls", "--json", "--quiet"]) == 0
    d = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert sorted(map(int, d["rejected_by"])) == d["outliers"] == sorted(planted.tolist())
    assert cli.main(["posegraph", str(path), "--gnc", "tls", "--json", "--quiet", "--no-consistency"]) == 0
    d = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert "rejected_by" not in d
    assert cli.main(["posegraph", str(path), "--no-consistency"]) == 2
    assert "--no-consistency applies to --gnc only" in capsys.readouterr().err


def test_plot_draws_each_rejected_closure_between_its_optimized_poses(tmp_path, capsys, monkeypatch):
    ds, planted, prob = _planted_dataset(120, 13, "uniform", 0.3)
    path, out, png = tmp_path / "g.g2o", tmp_path / "o.g2o", tmp_path / "o.png"
    from lie_factors.app import plotting
    from lie_factors.g2o import write_g2o

    write_g2o(str(path), ds.factor_graph(), prob.initial)
    drawn = {}
    draw = plotting.plot_trajectories

    def capture(*args, **kwargs):
        drawn.update(kwargs.get("segments") or {})
        draw(*args, **kwargs)

    monkeypatch.setattr(plotting, "plot_trajectories", capture)
    assert cli.main(["posegraph", str(path), "--gnc", "tls", "--json", "--quiet", "--output", str(out),
                     "--plot", str(png)]) == 0
    d = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert png.read_bytes()[:4] == b"\x89PNG"
    S = drawn["rejected loop closures"]
    assert S.shape == (len(d["outliers"]), 2, 3) and len(d["outliers"]) == len(planted)
    # the ends are the optimized poses as written to the output file, read back by GTSAM
    graph, values = gtsam.readG2o(str(out), True)
    edges = [graph.at(k) for k in range(graph.size()) if isinstance(graph.at(k), gtsam.BetweenFactorPose3)]
    for segment, e in zip(S, d["outliers"]):
        i, j = edges[e].keys()
        np.testing.assert_allclose(segment, [values.atPose3(i).translation(), values.atPose3(j).translation()],
                                   rtol=2e-5, atol=1e-6)  # gtsam.writeG2o keeps 6 significant digits
    # without --gnc nothing is rejected and nothing is drawn
    drawn.clear()
    assert cli.main(["posegraph", str(path), "--quiet", "--plot", str(png)]) == 0
    assert drawn == {}


# --------------------------------------------------------------------------- #
# The final check's tail model and its linear algebra
# --------------------------------------------------------------------------- #

def _f_density(x, d1, d2):
    import mpmath

    c = mpmath.gamma((d1 + d2) / 2) / (mpmath.gamma(d1 / 2) * mpmath.gamma(d2 / 2)) * (d1 / d2) ** (d1 / 2)
    return c * x ** (d1 / 2 - 1) * (1 + d1 * x / d2) ** (-(d1 + d2) / 2)


@pytest.mark.parametrize("d1, d2, p", [(3, 5, 0.5), (3, 5, 0.9999), (6, 5, 0.99), (1, 3, 0.9), (30, 5, 0.9999),
                                        (2, 2.5, 0.999), (3, 5, 1 - 1e-5), (3, 1e5, 0.99),
                                        (6, 2e5, 0.999)])
def test_f_quantile_inverts_the_integrated_density(d1, d2, p):
    import mpmath

    q = f_quantile(d1, d2, p)
    with mpmath.workdps(30):
        # the upper tail, integrated from the density's own formula (not the incomplete beta function)
        tail = mpmath.quad(lambda x: _f_density(x, mpmath.mpf(d1), mpmath.mpf(d2)), [q, 10 * q, mpmath.inf])
    assert float(tail) == pytest.approx(1 - p, rel=1e-9)


def test_f_quantile_tends_to_the_chi2_quantile_and_refuses_bad_input():
    for d in (3, 6):
        chi2 = 2 * chi2_inlier_threshold(d, 0.99)
        off = [abs(d * f_quantile(d, nu, 0.99) / chi2 - 1) for nu in (1e2, 1e3, 1e4)]
        assert off[2] < 1e-3 and off[2] < off[1] / 5 < off[0] / 25  # O(1/ν)
    for bad in ((0, 5, 0.5), (3, 0, 0.5), (3, 5, 1.0), (3, 5, 0.0)):
        with pytest.raises(ValueError):
            f_quantile(*bad)


def test_gnc_without_its_known_outliers_in_the_solver_is_the_same_gnc():
    ds, planted, prob = _planted_dataset(120, 21, "uniform", 0.3)
    graph = ds.with_first_prior().factor_graph()
    known = planted[: len(planted) // 2].tolist()
    lc = set(ds.loop_closures().tolist())
    params = gncm.GncSettings(known_inliers=[k for k in range(graph.size()) if k not in lc], known_outliers=known)
    full = gncm.gnc_optimize(inner.BatchInner(graph, prob.initial), params)
    cut_inner = inner.BatchInner(graph, prob.initial, exclude=known)
    assert cut_inner.slots.size == graph.size() - len(known)
    cut = gncm.gnc_optimize(cut_inner, params)
    np.testing.assert_array_equal(cut.weights, full.weights)
    assert cut.cost == pytest.approx(full.cost, rel=1e-9)
    a, b = full.values.to_values(), cut.values.to_values()
    assert max(np.max(np.abs(a.atPose3(k).localCoordinates(b.atPose3(k)))) for k in range(120)) < 1e-8
    assert np.all(cut_inner.factor_errors(cut_inner.initial)[known] == 0.0)
    w = np.ones(graph.size())
    with pytest.raises(ValueError, match="excluded factor slot has a nonzero weight"):
        cut_inner.optimize(w)
    # a slot whose variable nothing else holds stays in the solver's graph
    lone = gtsam.NonlinearFactorGraph()
    lone.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1.0)))
    lone.add(gtsam.BetweenFactorPose3(0, 1, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1.0)))
    values = gtsam.Values()
    values.insert(0, gtsam.Pose3())
    values.insert(1, gtsam.Pose3())
    assert inner.BatchInner(lone, values, exclude=[1]).slots.tolist() == [0, 1]


@pytest.mark.parametrize("rejected_weight", [0.0, 5e-6])
def test_final_check_drops_an_accepted_false_closure_and_takes_back_a_rejected_true_one(rejected_weight):
    """GNC's verdict stubbed: one false closure accepted, one true closure rejected; GNC's
    rejected weights exactly 0, or small where GNC stopped before its weights were binary."""
    ds, planted, prob = _planted_dataset(200, 22, "uniform", 0.1)
    pg = ds.with_first_prior()
    graph = pg.factor_graph()
    lc = pg.loop_closures()
    true = np.setdiff1d(lc, planted)
    weights = np.ones(graph.size())
    weights[planted[1:]] = rejected_weight  # all false closures but the first rejected
    weights[true[5]] = rejected_weight      # and one true closure
    scorer = inner.BatchInner(graph, prob.initial)

    def refine(v, w):
        return inner.BatchInner(graph, v, exclude=np.flatnonzero(w == 0)).optimize(w)[0].to_values()

    def run_gnc(params):
        values = refine(prob.initial, weights)
        return gncm.GncResult(values, weights.copy(), np.ones(graph.size()), 0.0, 1, 1, 1.0, "stub", 0.0)

    stub = SimpleNamespace(gnc=run_gnc, refine=refine, errors=lambda v: scorer.factor_errors(scorer.state(v)),
                           poses=lambda v: np.array([v.atPose3(int(k)).matrix() for k in pg.keys]))
    rej = reject_false_closures(pg, stub, gncm.GncSettings(), screen=False)
    assert rej.rejected_by == {int(e): ("final" if e == planted[0] else "gnc") for e in planted.tolist()}
    assert int(true[5]) in rej.readmitted
    assert set(np.unique(rej.gnc.weights[lc]).tolist()) == {0.0, 1.0}


def test_the_relaxations_iterations_follow_lms_relative_tolerance():
    # 2·⌈log₂(ln tol / ln ½)⌉: ½ squared k times is below tol once 2^k ≥ ln tol / ln ½
    assert relaxation_iterations() == 10  # GTSAM's default relativeErrorTol, 1e-5: ln 1e-5/ln ½ = 16.6
    for tol, k in [(0.1, 2), (1e-2, 3), (1e-8, 5), (0.0, 6), (1e-300, 6), (0.9, 1)]:
        p = gtsam.LevenbergMarquardtParams()
        p.setRelativeErrorTol(tol)
        assert relaxation_iterations(p) == 2 * k
        assert 0.5 ** (2 ** k) <= max(min(tol, 0.25), 1e-16) < 0.5 ** (2 ** (k - 1))


def test_tls_cost_truncates_the_closures_and_leaves_out_the_known_outliers():
    rng = np.random.default_rng(3)
    f, c = rng.exponential(2.0, 40), rng.uniform(1.0, 3.0, 40)
    closures, known = np.arange(10, 40, 2), [12, 30, 3]
    expected = sum(f[k] if k not in closures else min(f[k], c[k]) for k in range(40) if k not in known)
    assert tls_cost(f, c, closures, known) == pytest.approx(expected, rel=1e-14)


def _two_start_problem():
    ds, planted, prob = _planted_dataset(200, 11, "uniform", 0.3)
    pg = ds.with_first_prior()
    X0 = initialize(pg, "odometry").poses
    params = gncm.GncSettings(known_inliers=np.setdiff1d(np.arange(len(pg.edge_keys) + len(pg.prior_keys)),
                                                         pg.loop_closures()).tolist(),
                              first_solve_known_inliers=True, warm_start=True)
    return pg, planted, X0, params


class _Recorded(ArraySolver):
    """The batch solver, recording where each GNC starts; ``odometry_result`` replaces the run from
    the solver's own start."""

    odometry_result = None

    def gnc(self, params, start=None, proceed=None, first_iterations=None):
        self.starts = getattr(self, "starts", []) + [start]
        self.calls = getattr(self, "calls", []) + ["gnc"]
        self.first_iterations = getattr(self, "first_iterations", []) + [first_iterations]
        res = super().gnc(params, start, proceed, first_iterations)
        if start is None and self.odometry_result is not None:
            return self.odometry_result(res)
        return res

    def refine(self, state, weights):
        self.calls = getattr(self, "calls", []) + ["refine"]
        return super().refine(state, weights)


def test_the_relaxations_run_is_made_only_where_its_first_solve_is_below_the_odometrys_run():
    pg, planted, X0, params = _two_start_problem()
    solver = _Recorded(pg, X0, None)
    rej = reject_false_closures(pg, solver, params)
    first = rej.costs["relaxation's first solve"]
    assert ("relaxation" in rej.costs) == (first < rej.costs["odometry"])
    # the relaxation's first solve is its GNC run's own, asked about before GNC goes on: no LM
    # solve between the two runs
    assert solver.calls[:2] == ["gnc", "gnc"] and len(solver.starts) == 2
    assert solver.first_iterations == [None, relaxation_iterations()]  # the relaxation's solve is bounded
    assert rej.costs[rej.start] == min(v for k, v in rej.costs.items() if k != "relaxation's first solve")
    assert set(rej.outliers.tolist()) == set(planted.tolist())


@pytest.mark.parametrize("backend", ["dropin", "batch", "native"])
def test_a_graph_solver_shows_proceed_its_estimates(backend):
    pg, _, X0, params = _two_start_problem()
    factors = build_graph(pg, backend)
    initial = pg.with_landmarks(values_from_matrices(pg.group, pg.keys, X0))
    solver = GraphSolver(pg, factors, initial, backend, None)
    if backend == "native":  # GTSAM's GncOptimizer has no hook after its first solve, nor a limit on it
        with pytest.raises(ValueError, match="proceed"):
            solver.gnc(params, proceed=lambda v: True)
        with pytest.raises(ValueError, match="first_iterations"):
            solver.gnc(params, first_iterations=3)
        return
    seen = []
    res = solver.gnc(params, proceed=lambda v: seen.append(v) or False)
    assert res.stop == gncm.DECLINED and len(seen) == 1 and isinstance(seen[0], gtsam.Values)
    assert solver.errors(seen[0]) == pytest.approx(solver.errors(res.values), rel=1e-12)


def test_the_relaxations_run_is_kept_where_the_odometrys_ends_at_a_higher_cost():
    pg, planted, X0, params = _two_start_problem()
    lc = pg.loop_closures()

    def every_closure_rejected(res):  # a bent map where no closure fits: each costs its threshold
        w = res.weights.copy()
        w[lc] = 0.0
        return dataclasses.replace(res, values=solver.refine(solver.start(), w), weights=w)

    solver = _Recorded(pg, X0, None)
    solver.odometry_result = every_closure_rejected
    rej = reject_false_closures(pg, solver, params)
    kept = np.setdiff1d(np.arange(len(pg.edge_keys)), rej.screening.rejected)
    assert solver.starts[0] is None
    np.testing.assert_array_equal(solver.starts[1], initialize(pg.with_edges(kept), "chordal").poses)
    assert rej.start == "relaxation" and rej.costs["relaxation"] < rej.costs["odometry"]
    assert set(rej.outliers.tolist()) == set(planted.tolist())
    # no first stage, no kept closures to relax over: the odometry's run is the only one
    solver = _Recorded(pg, X0, None)
    assert reject_false_closures(pg, solver, params, screen=False).costs.keys() == {"odometry"}


# --------------------------------------------------------------------------- #
# The bars on real graphs (seconds of CPU each)
# --------------------------------------------------------------------------- #

DATA = Path(__file__).resolve().parents[2] / "data"


def _map_error(values, reference, is3d) -> float:
    """Position RMSE between two estimates over the reference's bounding-box diagonal."""
    P, R = positions(values, is3d), positions(reference, is3d)
    return float(np.sqrt(np.mean(np.sum((P - R) ** 2, axis=1))) / np.linalg.norm(R.max(axis=0) - R.min(axis=0)))


@pytest.mark.slow
@pytest.mark.parametrize("fraction, kind", [(0.2, "uniform"), (0.2, "clustered"), (0.5, "uniform")])
def test_intel_with_false_closures_lands_on_the_clean_map(fraction, kind):
    """intel's noise models are ~60× looser than its data: GNC alone keeps a false closure that
    bends the map by 2.6 % of the diagonal (20 % uniform, seed 0)."""
    base = read_pose_graph(str(DATA / "intel.g2o"))
    _, clean, _ = run(base, backend="batch")
    plant = (outliers.plant_false_loop_closures if kind == "uniform"
             else outliers.plant_clustered_false_loop_closures)
    count = int(round(fraction * base.loop_closures().size))
    between, planted = plant(base.factor_graph(), base.keys.tolist(), count, 0, False)
    graph = dataclasses.replace(PoseGraph.from_gtsam(between, base.group, base.keys),
                                vertices=base.vertices)
    record, result, _ = run(dataclasses.replace(graph, name=base.name, path=base.path), backend="batch", gnc="tls")
    c = outliers.classify(record.outliers, planted)
    assert c.precision >= 0.99 and c.recall >= (0.99 if fraction <= 0.2 else 0.95)
    assert _map_error(result.values, clean.values, False) <= (0.01 if fraction <= 0.2 else 0.02)


@pytest.mark.slow
def test_manhattan_without_false_closures_is_the_plain_optimum():
    """On manhattan the pairwise tests reject true closures on short cycles (false alarms of ~10⁵
    tests at 0.9999); the final check takes them back."""
    base = read_pose_graph(str(DATA / "manhattan.g2o"))
    _, plain, _ = run(base, backend="batch")
    record, result, _ = run(base, backend="batch", gnc="tls")
    assert record.outliers == [] and record.rejected_by == {}
    graph = build_graph(base, "native")
    assert graph.error(result.values) == pytest.approx(graph.error(plain.values), rel=1e-6)


def test_a_pose_graph_solve_leaves_out_the_slots_weighing_zero():
    """The solve's pattern holds no slot whose weight is 0 (a false closure there fills the factor),
    its estimate equals a solver's built without them, and the errors still cover every slot."""
    ds, planted, _ = _planted_dataset(120, 21, "uniform", 0.3)
    pg = ds.with_first_prior()
    X = pg.start_poses
    weights = np.ones(len(pg.edge_keys) + len(pg.prior_keys))
    weights[planted] = 0.0
    weights[planted[0]] = 0.25  # a false closure at a small weight stays in the pattern
    solving = inner.BatchInner.from_pose_graph(pg, X)
    state, _ = solving.optimize(weights)
    lm, slots = solving._solver_for(weights)
    assert set(slots.tolist()) == set(range(weights.size)) - set(planted[1:].tolist())
    between = [g for g in lm.problem.groups if g.kind == "between"]
    assert sum(g.fidx.size for g in between) == len(pg.edge_keys) - (planted.size - 1)
    cut = inner.BatchInner.from_pose_graph(pg, X, exclude=planted[1:])
    reference, _ = cut.optimize(weights)
    assert np.max(np.abs(state.Xs["Pose3"] - reference.Xs["Pose3"])) < 1e-9
    errors = solving.factor_errors(state)
    assert np.all(errors[planted] > 0) and np.all(cut.factor_errors(reference)[planted[1:]] == 0)
    weights[planted] = 1.0  # every slot back: the solver holding them all
    assert solving._solver_for(weights)[0] is solving.lm


def test_the_groups_in_the_graph_take_the_way_of_fewer_multiply_adds(monkeypatch):
    """smallGrid3D's closures, every one a group: one sweep of selected inversion costs less than a
    path each; one closure alone: its path costs less than the sweep."""
    pg = read_pose_graph(str(DATA / "smallGrid3D.g2o")).with_first_prior()
    X = np.asarray(lf.optimize(pg).poses)
    lc = pg.loop_closures()
    w = np.ones(len(pg.edge_keys) + 1)
    chosen = []
    rule = leave_out._selected_inverse_is_cheaper
    monkeypatch.setattr(leave_out, "_selected_inverse_is_cheaper", lambda *a: chosen.append(rule(*a)) or chosen[-1])
    many = leave_out_chi2(pg, X, w, [lc[k:k + 1] for k in range(lc.size)])
    one = leave_out_chi2(pg, X, w, [lc[:1]])
    assert chosen == [True, False]
    assert one[0] == pytest.approx(many[0], rel=1e-9)
