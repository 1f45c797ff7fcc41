"""False loop closures planted by ``lf.corrupt``: counts, determinism, each kind's geometry (checked
with GTSAM's own factor errors at the clean optimum), the files written, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import lie_factors as lf
from lie_factors.corruption import KINDS, LOCAL_SPAN, NEAR_SIGMAS, RUN_LENGTH, plant
from lie_factors.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
GRAPHS = {"Pose2": str(ROOT / "data" / "intel.g2o"), "Pose3": str(ROOT / "data" / "smallGrid3D.g2o")}


@pytest.fixture(scope="module", params=sorted(GRAPHS))
def clean(request):
    pg = lf.read_g2o(GRAPHS[request.param])
    return pg, lf.optimize(pg)


def _corrupt(clean, kind, fraction=0.2, seed=3):
    pg, opt = clean
    return plant(pg, fraction=fraction, kind=kind, seed=seed, reference=opt.poses)


def _runs(c):
    """The planted closures split into runs i+k → j+k (consecutive planted edges whose both ends
    step by one pose)."""
    idx = c.graph.index(c.planted_keys().reshape(-1)).reshape(-1, 2)
    runs, start = [], 0
    for k in range(1, len(idx) + 1):
        if k == len(idx) or not np.array_equal(idx[k] - idx[k - 1], [1, 1]):
            runs.append(np.arange(start, k))
            start = k
    return idx, runs


@pytest.mark.parametrize("kind", KINDS)
def test_counts_order_and_pairs(clean, kind):
    pg, _ = clean
    c = _corrupt(clean, kind)
    E, lc = pg.edge_count, pg.loop_closures().size
    assert len(c.planted) == round(0.2 * lc)
    assert np.array_equal(c.planted, np.arange(E, E + len(c.planted)))
    assert np.array_equal(c.graph.edge_keys[:E], pg.edge_keys)  # the input's edges first, untouched
    assert np.array_equal(c.graph.measured[:E], pg.measured)
    idx = c.graph.index(c.graph.edge_keys.reshape(-1)).reshape(-1, 2)
    pairs = {tuple(sorted(p)) for p in idx.tolist()}
    assert len(pairs) == len(idx)  # no pair twice, none on an existing edge
    assert np.all(np.abs(idx[c.planted, 0] - idx[c.planted, 1]) >= 2)  # loop closures, not odometry
    assert set(c.graph.loop_closures().tolist()) >= set(c.planted.tolist())
    c.graph.validate()
    # every planted closure's information is one of the input's loop closures'
    pool = pg.information[pg.loop_closures()]
    for info in c.graph.information[c.planted]:
        assert np.any(np.all(np.isclose(pool, info, rtol=0, atol=0), axis=(1, 2)))


@pytest.mark.parametrize("kind", KINDS)
def test_seeded(clean, kind):
    a, b, other = _corrupt(clean, kind, seed=5), _corrupt(clean, kind, seed=5), _corrupt(clean, kind, seed=6)
    assert np.array_equal(a.graph.edge_keys, b.graph.edge_keys)
    assert np.array_equal(a.graph.measured, b.graph.measured)
    assert not np.array_equal(a.planted_keys(), other.planted_keys())


def test_local_pairs_are_close_along_the_trajectory(clean):
    c = _corrupt(clean, "local")
    idx = c.graph.index(c.planted_keys().reshape(-1)).reshape(-1, 2)
    gap = np.abs(idx[:, 0] - idx[:, 1])
    assert gap.min() >= 2 and gap.max() <= LOCAL_SPAN


def _relations(c, opt):
    """Per planted closure: X_a·Z·X_b⁻¹ at the clean optimum (one matrix for a run agreeing on one
    relative pose of its two places), and the whitened offset from the optimum, √(2·error) by
    GTSAM's BetweenFactor."""
    X = opt.poses
    idx = c.graph.index(c.planted_keys().reshape(-1)).reshape(-1, 2)
    rel = np.array([X[a] @ c.graph.measured[e] @ np.linalg.inv(X[b]) for e, (a, b) in zip(c.planted, idx)])
    graph = c.graph.factor_graph()
    sigma = np.array([np.sqrt(2.0 * graph.at(int(e)).error(opt.values)) for e in c.planted])
    return rel, sigma


@pytest.mark.parametrize("kind", ["group", "near"])
def test_runs_agree_on_one_relative_pose(clean, kind):
    pg, opt = clean
    c = _corrupt(clean, kind)
    _, runs = _runs(c)
    lengths = np.array([len(r) for r in runs])
    # every run but the last drawn (cut to what is left) has RUN_LENGTH members
    assert np.sum((lengths < RUN_LENGTH[0]) | (lengths > RUN_LENGTH[1])) <= 1
    assert lengths.sum() == len(c.planted)
    rel, sigma = _relations(c, opt)
    for r in runs:
        assert np.allclose(rel[r], rel[r[0]], atol=1e-9)  # one wrong relation per run
        assert np.array_equal(c.graph.information[c.planted[r]], np.broadcast_to(
            c.graph.information[c.planted[r[0]]], (len(r),) + c.graph.information.shape[1:]))
    if kind == "near":
        assert sigma.min() >= NEAR_SIGMAS[0] * (1 - 1e-6) and sigma.max() <= NEAR_SIGMAS[1] * (1 + 1e-6)
    else:
        assert np.median(sigma) > NEAR_SIGMAS[1]  # a random relative pose: beyond what near plants


def test_uniform_closures_are_far_from_the_truth(clean):
    _, opt = clean
    _, sigma = _relations(_corrupt(clean, "uniform"), opt)
    assert np.median(sigma) > NEAR_SIGMAS[1]


def test_front_door_plants_against_the_clean_optimum(clean, tmp_path):
    pg, opt = clean
    c = lf.corrupt(pg.path, fraction=0.1, kind="near", seed=2)
    ref = _corrupt(clean, "near", fraction=0.1, seed=2)
    assert np.array_equal(c.graph.edge_keys, ref.graph.edge_keys)
    assert np.allclose(c.graph.measured, ref.graph.measured, atol=1e-9)
    out = tmp_path / "bad.g2o"
    lf.write_corruption(c, str(out))
    back = lf.read_g2o(str(out))
    assert np.array_equal(back.edge_keys, c.graph.edge_keys)
    assert np.allclose(back.measured, c.graph.measured, rtol=0, atol=1e-12)
    listed = np.loadtxt(tmp_path / "bad.planted.txt", dtype=np.int64, ndmin=2)
    assert np.array_equal(listed[:, 0], c.planted)
    assert np.array_equal(listed[:, 1:], back.edge_keys[listed[:, 0]])


def test_bad_input(clean, tmp_path):
    pg, opt = clean
    for fraction in (0, -0.1, float("nan"), 11, "0.2", True, 1e-6):
        with pytest.raises(InputError, match="fraction"):
            lf.corrupt(pg, fraction=fraction)
    with pytest.raises(InputError, match="kind"):
        lf.corrupt(pg, fraction=0.2, kind="clustered")
    for seed in (-1, 1.5, "3"):
        with pytest.raises(InputError, match="seed"):
            lf.corrupt(pg, fraction=0.2, seed=seed)
    with pytest.raises(InputError, match="no loop closures"):
        lf.corrupt(pg.with_edges(np.setdiff1d(np.arange(pg.edge_count), pg.loop_closures())), fraction=0.2)
    with pytest.raises(InputError, match="reference"):
        plant(pg, fraction=0.2, kind="group")
    with pytest.raises(InputError):
        lf.corrupt(str(tmp_path / "missing.g2o"), fraction=0.2)
    c = lf.corrupt(pg, fraction=0.05, seed=1)
    with pytest.raises(InputError, match="different files"):
        lf.write_corruption(c, str(tmp_path / "a.g2o"), str(tmp_path / "a.g2o"))
    with pytest.raises(InputError, match="overwrite the input"):
        lf.write_corruption(c, pg.path)


@pytest.mark.parametrize("kind", ["uniform", "local"])
def test_no_closure_joins_a_pose_to_itself(clean, kind):
    # Many draws: a pair (a, a) is one in P of uniform's draws, which small fractions rarely meet.
    for seed in range(4):
        c = _corrupt(clean, kind, fraction=2.0, seed=seed)
        idx = c.graph.index(c.planted_keys().reshape(-1)).reshape(-1, 2)
        assert np.all(np.abs(idx[:, 0] - idx[:, 1]) >= 2)
