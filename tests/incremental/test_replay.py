"""The online replay (:mod:`lie_factors.incremental.replay`): its schedule and start values, its
result, its refusals, and the command line reporting what it returns."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import gtsam
import numpy as np
import pytest

from support.cli_helpers import last_json, run_main
from support.replay_graphs import INDETERMINATE, SMALL, TINY2D, UNREACHABLE, write
from lie_factors.errors import InputError
from lie_factors.g2o import read_pose_graph
from lie_factors.incremental.replay import factor_graph, new_isam, replay, replay_graph, schedule
from lie_factors.interop import to_gtsam
from lie_factors.optimizers import ISAM2
from lie_factors.result import ReplayResult

ROOT = Path(__file__).resolve().parents[2]


def test_schedule_and_initial_values_follow_the_rules(tmp_path):
    pg = read_pose_graph(write(tmp_path, TINY2D))
    graph = factor_graph(pg, "dropin")
    steps = schedule(pg, graph)
    assert [s.key for s in steps] == [0, 1, 2, 3, 4]
    # every factor in the update of its later pose: prior (factor 6) first, edge 2-0 with pose 2,
    # the reversed edge 4->3 and 0-4 with pose 4
    assert [s.factors for s in steps] == [[6], [0], [1, 2], [3], [4, 5]]
    assert [s.odometry for s in steps] == [None, (0, True), (1, True), (3, True), (4, False)]
    after_update = []  # the estimate after each update

    class Recording(ISAM2):
        def update(self, *args, **kwargs):
            result = super().update(*args, **kwargs)
            after_update.append(self.calculateEstimate())
            return result

    result = replay_graph(pg, graph, Recording(gtsam.ISAM2Params()), backend="dropin")
    # new pose = previous pose's estimate composed with the odometry edge (inverted if stored backwards)
    m01 = to_gtsam("Pose2", pg.measured[0])
    assert np.allclose(result.start.atPose2(1).matrix(), pg.initial.atPose2(0).compose(m01).matrix(), atol=1e-12)
    m43 = to_gtsam("Pose2", pg.measured[4])
    expected4 = after_update[3].atPose2(3).compose(m43.inverse())
    assert np.allclose(result.start.atPose2(4).matrix(), expected4.matrix(), atol=1e-12)
    assert result.updates == 5 and len(result.times) == 5
    # error: the whole graph's error at the final estimate; initial_error: at the online start
    assert result.error == pytest.approx(float(graph.error(result.values)), rel=1e-15)
    assert result.initial_error == pytest.approx(float(graph.error(result.start)), rel=1e-15)


@pytest.mark.parametrize("backend", ["batch", "dropin", "native"])
def test_replay_returns_a_replay_result(tmp_path, backend):
    pg = read_pose_graph(write(tmp_path, TINY2D))
    r = replay(pg, backend=backend)
    assert isinstance(r, ReplayResult)
    assert r.backend == backend and r.pose_graph is pg and r.converged
    assert r.updates == r.iterations == 5 and len(r.times) == 5 and r.factors == 7
    assert 0 < r.update_p50 <= r.update_p99 <= r.update_seconds
    assert r.keys.tolist() == [0, 1, 2, 3, 4] and r.poses.shape == (5, 3, 3) and r.group == "Pose2"
    graph = factor_graph(pg, "native")
    assert r.error == pytest.approx(float(graph.error(r.values)), rel=1e-9)
    assert r.initial_error == pytest.approx(float(graph.error(r.start)), rel=1e-9)
    assert r.error < r.initial_error
    assert (r.reorderings is None) == (backend != "batch") and r.relinearizations >= 0
    d = r.to_dict()
    assert d["updates"] == 5 and d["final_error"] == r.error and (d["reorderings"] is None) == (backend != "batch")


def test_replay_of_a_landmark_graph_runs_the_smoother_on_its_factors():
    pg = read_pose_graph("known_landmark_localization_20.g2o")
    r = replay(pg)
    assert r.converged and r.updates == pg.pose_count
    assert r._values is not None and r.values.size() == pg.pose_count + pg.landmark_count
    assert r.error == pytest.approx(float(factor_graph(pg, "batch").error(r.values)), rel=1e-12)


@pytest.mark.parametrize("backend", ["batch", "native"])
def test_replay_equals_what_the_command_reports(capsys, backend):
    pg = read_pose_graph(SMALL)
    r = replay(pg, backend=backend)
    status, out, err = run_main(capsys, "posegraph", SMALL, "--incremental", "--backend", backend, "--json")
    assert status == 0, err
    d = last_json(out)
    assert d["updates"] == r.updates == pg.pose_count
    assert d["final_error"] == pytest.approx(r.error, rel=1e-9, abs=1e-9)
    assert d["relinearizations"] == r.relinearizations and d["reorderings"] == r.reorderings


def test_max_seconds_stops_early():
    r = replay(read_pose_graph(SMALL), max_seconds=0.0)
    assert r.updates == 1 and not r.converged and math.isnan(r.error) and math.isnan(r.initial_error)
    assert r.keys.tolist() == [0]


def test_progress_every_1000_updates():
    calls = []
    r = replay(read_pose_graph("cityTrees_reduced_1k.g2o"), progress=lambda *a: calls.append(a))
    assert [c[:2] for c in calls] == [(1000, r.updates)] and calls[0][2] >= 0


def test_refusals_name_the_update_and_the_pose(tmp_path):
    pg = read_pose_graph(write(tmp_path, TINY2D))
    with pytest.raises(InputError, match="unknown backend"):
        replay(pg, backend="custom")
    with pytest.raises(InputError, match="relinearize_skip"):
        replay(pg, relinearize_skip=0)
    with pytest.raises(InputError, match="relinearize_threshold"):
        replay(pg, relinearize_threshold=math.nan)
    with pytest.raises(InputError, match="pose 1 has no edge to an earlier pose"):
        replay(read_pose_graph(write(tmp_path, UNREACHABLE, "u.g2o")))
    indeterminate = read_pose_graph(write(tmp_path, INDETERMINATE, "i.g2o"))
    with pytest.raises(InputError, match=r"^update 2 \(pose 1\) failed: .*undetermined"):
        replay(indeterminate)
    with pytest.raises(InputError, match=r"^ISAM2 update 2 \(pose 1\) failed: Indeterminate"):
        replay(indeterminate, backend="native")


def test_lower_level_pieces_run_our_factors_in_plain_isam2(tmp_path):
    """What benchmarks/incremental.py's plain leg runs: lie_factors' factors in gtsam.ISAM2."""
    pg = read_pose_graph(write(tmp_path, TINY2D))
    plain = replay_graph(pg, factor_graph(pg, "dropin"), gtsam.ISAM2(gtsam.ISAM2Params()), backend="dropin")
    dropin = replay_graph(pg, factor_graph(pg, "dropin"), new_isam("dropin"), backend="dropin")
    assert plain.error == pytest.approx(dropin.error, rel=1e-12)



#: Run in a fresh process: the smoother's dispatchers' signatures after warm_up_smoother, then
#: after a replay and its final error.
WARM_UP_CHECK = """
import importlib, pkgutil
import numba
import lie_factors.incremental as inc
from lie_factors.batch import loops
from lie_factors.g2o import read_pose_graph
from lie_factors.incremental.replay import replay_arrays, warm_up_smoother
from lie_factors.incremental.smoother import Smoother

modules = [importlib.import_module("lie_factors.incremental." + m.name) for m in pkgutil.iter_modules(inc.__path__)]
dispatchers = {id(d): d for mod in modules + [loops] for d in vars(mod).values()
               if isinstance(d, numba.core.registry.CPUDispatcher)}

def signatures():
    return {k: len(d.overloads) for k, d in dispatchers.items()}

pg = read_pose_graph("data/smallGrid3D.g2o")
warm_up_smoother(pg.group)
before = signatures()
s = Smoother()
replay_arrays(pg, s)
assert s.bf.compactions > 0
assert signatures() == before, [dispatchers[k].py_func.__name__ for k, n in signatures().items() if before[k] != n]
print("ok", sum(before.values()))
"""


def test_after_the_warm_up_a_replay_compiles_and_loads_no_kernel():
    # every kernel a replay runs is compiled or loaded by warm_up_smoother, outside the timed
    # updates: the replay adds no signature to any of the smoother's dispatchers, even with a
    # pool compaction (smallGrid3D's replay compacts once)
    out = subprocess.run([sys.executable, "-c", WARM_UP_CHECK], capture_output=True, text=True, cwd=ROOT,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("ok")
