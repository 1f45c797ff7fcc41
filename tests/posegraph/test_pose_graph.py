"""lie_factors.posegraph.graph (the pose graph on arrays, to and from GTSAM graphs) and lie_factors.posegraph.topology."""

from __future__ import annotations

from collections import deque
from pathlib import Path

import gtsam
import numpy as np
import pytest

from lie_factors import factors, g2o
from lie_factors.posegraph import topology
from lie_factors.errors import InputError
from lie_factors import interop
from lie_factors.posegraph.graph import PRIOR_VARIANCES, PoseGraph, prior_information

DATA = Path(__file__).resolve().parents[2] / "data"


def small3d() -> PoseGraph:
    return g2o.read_arrays(g2o.check_g2o(str(DATA / "smallGrid3D.g2o")))


def pose2_graph() -> gtsam.NonlinearFactorGraph:
    """Edges 0-1, 1-2, 2-3 (one information), 0-2, 1-3 (another, full), a prior in the middle."""
    a = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.2, 0.05]))
    b = gtsam.noiseModel.Gaussian.Information(np.array([[4.0, 0.5, 0.0], [0.5, 3.0, 0.1], [0.0, 0.1, 2.0]]))
    g = gtsam.NonlinearFactorGraph()
    for i, j, model in ((0, 1, a), (1, 2, a), (2, 3, a), (0, 2, b), (1, 3, b)):
        g.add(gtsam.BetweenFactorPose2(i, j, gtsam.Pose2(1.0 + i, 0.5 * j, 0.3 * (i - j)), model))
    g.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(0.1, -0.2, 0.3), a))
    return g


# ------------------------------------------------------------------ the type

def test_fields_keep_their_order_and_priors_default_to_none():
    names = [f.name for f in PoseGraph.__dataclass_fields__.values()]
    assert names[:7] == ["group", "keys", "edge_keys", "measured", "information", "vertices", "lines"]
    pg = small3d()
    assert pg.prior_keys.shape == (0,) and pg.prior_measured.shape == (0, 4, 4)
    assert pg.prior_information.shape == (0, 6, 6) and pg.is3d and pg.info.dim == 6
    with pytest.raises(ValueError, match="a pose graph holds Pose2, Pose3, Similarity3"):
        PoseGraph("Rot3", pg.keys, pg.edge_keys, pg.measured, pg.information, None, None)


def test_loop_closures_are_the_edges_between_non_consecutive_keys():
    pg = small3d()
    k = pg.edge_keys
    expected = [e for e in range(len(k)) if abs(int(k[e, 0]) - int(k[e, 1])) != 1]
    assert pg.loop_closures().tolist() == expected and 0 < len(expected) < len(k)


def test_anchored_puts_gtsams_example_prior_on_the_smallest_key():
    pg = small3d().anchored()
    assert pg.prior_keys.tolist() == [int(pg.keys[0])]
    np.testing.assert_array_equal(pg.prior_measured[0], np.eye(4))
    np.testing.assert_array_equal(pg.prior_information[0], np.diag(1 / PRIOR_VARIANCES["Pose3"]))
    assert pg.anchored() is pg
    assert prior_information("Pose2")[2, 2] == pytest.approx(1e8)


def test_renumbered_and_with_edges_keep_the_graph():
    pg = small3d().with_prior(5, np.eye(4), np.eye(6))
    r = pg.renumbered()
    assert r.keys.tolist() == list(range(len(pg.keys)))
    np.testing.assert_array_equal(pg.keys[r.edge_keys], pg.edge_keys)
    assert pg.keys[r.prior_keys].tolist() == [5]
    sub = pg.with_edges(pg.loop_closures())
    assert len(sub.edge_keys) == len(pg.loop_closures()) and sub.keys is pg.keys
    np.testing.assert_array_equal(sub.lines, pg.lines[pg.loop_closures()])


@pytest.mark.parametrize("change, match", [
    (lambda d: d.update(edge_keys=d["edge_keys"][:-1]), "measured: expected shape"),
    (lambda d: d["edge_keys"].__setitem__((0, 1), d["edge_keys"][0, 0]), "joins pose 0 to itself"),
    (lambda d: d["edge_keys"].__setitem__((0, 1), 10**6), "key 1000000 is not among the pose keys"),
    (lambda d: d["measured"].__setitem__((0, 0, 0), np.nan), "NaN"),
    (lambda d: d["measured"].__setitem__((0, 0, 0), 2.0), "not orthonormal"),
    (lambda d: d["measured"].__setitem__((0, 3, 0), 1.0), "last row"),
    (lambda d: d["information"].__setitem__((0, 0, 1), 5.0), "symmetric"),
    (lambda d: d["information"].__setitem__((0, 0, 0), -1.0), "positive definite"),
    (lambda d: d.update(information=d["information"][:, :3, :3]), "expected shape"),
    (lambda d: d.update(keys=d["keys"][::-1]), "increasing"),
])
def test_validate_names_what_is_wrong(change, match):
    pg = small3d()
    d = {k: np.array(v, copy=True) for k, v in vars(pg).items() if isinstance(v, np.ndarray)}
    change(d)
    bad = PoseGraph(pg.group, d["keys"], d["edge_keys"], d["measured"], d["information"], pg.vertices, None)
    with pytest.raises(ValueError, match=match):
        bad.validate()
    assert small3d().validate() is not None


# --------------------------------------------------------------- from GTSAM

@pytest.mark.parametrize("F", [gtsam, factors], ids=["gtsam", "lie_factors"])
def test_from_gtsam_reads_between_and_prior_factors(F):
    ref = pose2_graph()
    graph = gtsam.NonlinearFactorGraph()
    for k in range(ref.size()):
        f = ref.at(k)
        if k == 3:  # a robust model: its Gaussian part
            model = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.0), f.noiseModel())
        else:
            model = f.noiseModel()
        graph.add(F.BetweenFactorPose2(*f.keys(), f.measured(), model) if len(f.keys()) == 2
                  else F.PriorFactorPose2(f.keys()[0], f.prior(), model))
    pg = PoseGraph.from_gtsam(graph)
    assert pg.group == "Pose2" and pg.keys.tolist() == [0, 1, 2, 3] and pg.lines.tolist() == [0, 1, 2, 3, 4]
    assert pg.edge_keys.tolist() == [[0, 1], [1, 2], [2, 3], [0, 2], [1, 3]] and pg.prior_keys.tolist() == [0]
    for k in range(5):
        f = ref.at(k)
        np.testing.assert_array_equal(pg.measured[k], f.measured().matrix())
        np.testing.assert_allclose(pg.information[k], f.noiseModel().information(), rtol=1e-15)
    np.testing.assert_array_equal(pg.prior_measured[0], ref.at(5).prior().matrix())
    assert pg.vertices is None


def test_from_gtsam_refuses_what_is_not_a_pose_graph():
    g = pose2_graph()
    g.add(gtsam.BetweenFactorPoint3(7, 8, np.zeros(3), gtsam.noiseModel.Unit.Create(3)))
    with pytest.raises(InputError, match=r"factor 6 \(BetweenFactorPoint3\) is not a Between or Prior"):
        PoseGraph.from_gtsam(g)
    g = pose2_graph()
    g.add(gtsam.BetweenFactorPose3(0, 1, gtsam.Pose3(), gtsam.noiseModel.Unit.Create(6)))
    with pytest.raises(InputError, match="mixes Pose2 and Pose3"):
        PoseGraph.from_gtsam(g)
    with pytest.raises(InputError, match="no between factors"):
        PoseGraph.from_gtsam(gtsam.NonlinearFactorGraph())
    # With the group and keys given, a graph without edges is a pose graph too.
    pg = PoseGraph.from_gtsam(gtsam.NonlinearFactorGraph(), "Pose3", [4, 2])
    assert pg.keys.tolist() == [2, 4] and pg.edge_keys.shape == (0, 2) and pg.measured.shape == (0, 4, 4)
    with pytest.raises(InputError, match="not among the pose keys"):
        PoseGraph.from_gtsam(pose2_graph(), "Pose2", [0, 1])


# ----------------------------------------------------------------- to GTSAM

def test_factor_graph_is_what_readg2o_builds():
    path = str(DATA / "smallGrid3D.g2o")
    pg = small3d()
    ref, _ = gtsam.readG2o(path, True)
    graph = pg.factor_graph()
    assert graph.size() == ref.size()
    values = gtsam.readG2o(path, True)[1]
    assert graph.error(values) == pytest.approx(ref.error(values), rel=1e-12)
    for k in (0, 100, 296):
        a, b = graph.at(k), ref.at(k)
        assert type(a) is type(b) and list(a.keys()) == list(b.keys())
        np.testing.assert_allclose(a.noiseModel().R(), b.noiseModel().R(), rtol=1e-14, atol=1e-14)
        assert type(a.noiseModel()) is type(b.noiseModel())


@pytest.mark.parametrize("name, is3d", [("intel.g2o", False), ("smallGrid3D.g2o", True)])
def test_factor_graph_and_values_are_readg2os_bit_for_bit(name, is3d):
    """Measurements and vertices go file → arrays → GTSAM objects without losing a bit: the
    native backend optimizes exactly what ``gtsam.readG2o`` reads (Pose2 through Rot2.atan2 of
    the stored cos/sin; through θ = atan2(s, c) about 2 % of the angles would move an ulp)."""
    path = str(DATA / name)
    pg = g2o.read_arrays(g2o.check_g2o(path))
    ref, ref_values = gtsam.readG2o(path, is3d)
    graph = pg.factor_graph()
    group = "Pose3" if is3d else "Pose2"
    for k in range(ref.size()):
        assert np.array_equal(graph.at(k).measured().matrix(), ref.at(k).measured().matrix()), k
    values = interop.values_from_matrices(group, pg.keys, pg.vertices)
    for key in pg.keys.tolist():
        get = getattr(values, f"at{group}")
        assert np.array_equal(get(key).matrix(), getattr(ref_values, f"at{group}")(key).matrix()), key


def test_pose2_matrix_converts_back_bit_for_bit():
    theta = np.random.default_rng(7).uniform(-np.pi, np.pi, 5000)
    for t in theta:
        p = gtsam.Pose2(1.5, -2.0, t)
        q = interop.to_gtsam("Pose2", p.matrix())
        assert np.array_equal(q.matrix(), p.matrix()) and q.theta() == p.theta()


def test_factor_graph_namespace_shared_models_priors_and_robust_loop_closures():
    pg = PoseGraph.from_gtsam(pose2_graph())
    mine = pg.factor_graph(factors)
    assert isinstance(mine.at(0), factors.BetweenFactorPose2) and isinstance(mine.at(5), factors.PriorFactorPose2)
    models = [mine.at(k).noiseModel() for k in range(5)]
    assert len({id(m) for m in models}) == 2 and models[0] is models[2] and models[3] is models[4]
    huber = gtsam.noiseModel.mEstimator.Huber.Create(1.345)
    robust = pg.factor_graph(robust=huber)
    kinds = [isinstance(robust.at(k).noiseModel(), gtsam.noiseModel.Robust) for k in range(6)]
    assert kinds == [False, False, False, True, True, False]  # the loop closures 0-2 and 1-3
    assert robust.at(3).noiseModel() is robust.at(4).noiseModel()
    every = pg.factor_graph(robust=huber, robust_all=True)
    assert all(isinstance(every.at(k).noiseModel(), gtsam.noiseModel.Robust) for k in range(5))
    back = PoseGraph.from_gtsam(pg.factor_graph())
    for name in ("edge_keys", "measured", "information", "prior_keys", "prior_measured", "prior_information"):
        np.testing.assert_allclose(getattr(back, name), getattr(pg, name), rtol=1e-12, atol=1e-14)


# ------------------------------------------------------------------ topology

def _queue_bfs(n, u, v, root):
    """The reference: adjacency lists built edge by edge, a queue."""
    adj = {}
    for e, (a, b) in enumerate(zip(u, v)):
        adj.setdefault(a, []).append((b, e))
        adj.setdefault(b, []).append((a, e))
    parent, edge = [-1] * n, [-1] * n
    parent[root] = root
    queue = deque([root])
    while queue:
        a = queue.popleft()
        for b, e in adj.get(a, ()):
            if parent[b] < 0:
                parent[b], edge[b] = a, e
                queue.append(b)
    return parent, edge


@pytest.mark.parametrize("seed", range(4))
def test_bfs_tree_is_the_queue_search_and_reached_its_nodes(seed):
    rng = np.random.default_rng(seed)
    n = 60
    u, v = rng.integers(0, n, 90), rng.integers(0, n, 90)
    keep = u != v
    u, v = u[keep], v[keep]
    parent, edge = topology.bfs_tree(n, u, v, 3)
    ref_parent, ref_edge = _queue_bfs(n, u.tolist(), v.tolist(), 3)
    assert parent.tolist() == ref_parent and edge.tolist() == ref_edge
    np.testing.assert_array_equal(topology.reached(n, u, v, [3]), parent >= 0)


def test_along_tree_sums_and_products_are_the_walks_to_the_root():
    rng = np.random.default_rng(5)
    n = 40
    parent = np.array([0] + [int(rng.integers(0, k)) for k in range(1, n)])
    parent[[7, 9]] = -1  # off the tree, and so are their subtrees
    step = rng.normal(size=n)
    total, ok = topology.along_tree(parent, step, 0, np.add)
    M = rng.normal(size=(n, 2, 2))
    prod, ok2 = topology.along_tree(parent, M, 0, np.matmul)
    for v in range(n):
        path, w = [], v
        while w not in (0, -1) and parent[w] >= 0:
            path.append(w)
            w = parent[w]
        assert ok[v] == ok2[v] == (w == 0)
        if ok[v] and v:
            assert total[v] == pytest.approx(sum(step[path]), rel=1e-12)
            ref = np.eye(2)
            for a in reversed(path):
                ref = ref @ M[a]
            np.testing.assert_allclose(prod[v], ref, rtol=1e-12, atol=1e-12)


def test_first_spanning_forest_takes_each_edge_that_joins_two_trees():
    u = np.array([0, 1, 0, 2, 3, 4, 3])
    v = np.array([1, 2, 2, 3, 4, 5, 5])
    assert topology.first_spanning_forest(7, u, v).tolist() == [True, True, False, True, True, True, False]
