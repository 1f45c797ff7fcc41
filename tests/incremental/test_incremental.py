"""``lie-factors posegraph FILE --incremental``: the online replay through ISAM2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from support.cli_helpers import assert_one_line_error, last_json, run_main
from lie_factors.app import cli, incremental
from lie_factors.backends import build_graph
from lie_factors.g2o import read_pose_graph
from lie_factors.interop import to_gtsam
from lie_factors.optimizers import ISAM2

ROOT = Path(__file__).resolve().parents[2]
SMALL = str(ROOT / "data" / "smallGrid3D.g2o")

INFO2 = "100 0 0 100 0 400"
# Poses 0..4 on a square-ish path; edge 3 is stored backwards (4 -> 3), edge 2-0 is a loop closure.
TINY2D = f"""VERTEX_SE2 0 0 0 0
VERTEX_SE2 1 1.1 0 1.5
VERTEX_SE2 2 1 1.2 3.1
VERTEX_SE2 3 -0.1 0.9 -1.6
VERTEX_SE2 4 0 -0.1 0.1
EDGE_SE2 0 1 1 0 1.5708 {INFO2}
EDGE_SE2 1 2 1 0 1.5708 {INFO2}
EDGE_SE2 2 0 1.4 1.4 -3.1 {INFO2}
EDGE_SE2 2 3 1 0 1.5708 {INFO2}
EDGE_SE2 4 3 0 -1 -1.5708 {INFO2}
EDGE_SE2 0 4 0.05 -0.02 0.01 {INFO2}
"""


def write(tmp_path, text, name="g.g2o"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def test_schedule_and_initial_values_follow_the_rules(tmp_path):
    pg = read_pose_graph(write(tmp_path, TINY2D))
    graph = build_graph(pg, "dropin")
    steps = incremental.schedule(pg, graph)
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

    result = incremental.replay(pg, "dropin", isam_class=Recording)
    # new pose = previous pose's estimate composed with the odometry edge (inverted if stored backwards)
    m01 = to_gtsam("Pose2", pg.measured[0])
    assert np.allclose(result.start.atPose2(1).matrix(), pg.initial.atPose2(0).compose(m01).matrix(), atol=1e-12)
    m43 = to_gtsam("Pose2", pg.measured[4])
    expected4 = after_update[3].atPose2(3).compose(m43.inverse())
    assert np.allclose(result.start.atPose2(4).matrix(), expected4.matrix(), atol=1e-12)
    assert result.updates == 5 and len(result.times) == 5
    # final_error: the whole graph's error at the final estimate
    assert result.final_error == pytest.approx(float(graph.error(result.values)), rel=1e-15)


def test_cli_incremental_native_and_dropin_on_small_grid(capsys):
    records = {}
    for backend in ("native", "dropin", "batch"):
        status, out, err = run_main(capsys, "posegraph", SMALL, "--incremental", "--backend", backend, "--json")
        assert status == 0, err
        records[backend] = d = last_json(out)
        assert d["incremental"] is True and d["updates"] == d["poses"] == 125 and d["factors"] == 298
        assert 0 < d["update_p50"] <= d["update_p99"] <= d["update_seconds"]
        assert d["relinearize_threshold"] == 0.1 and d["relinearize_skip"] == 10
        assert "125 updates" in out
        assert isinstance(d["relinearizations"], int) and d["relinearizations"] > 0
        assert (d["reorderings"] is None) == (backend != "batch")
    # GTSAM's Pose3 between factor and ours: the same error, Jacobians equal to rounding
    assert records["dropin"]["final_error"] == pytest.approx(records["native"]["final_error"], rel=1e-9)
    # the incremental smoother: ISAM2's policy on its own factorization, the same accuracy
    assert records["batch"]["final_error"] <= records["native"]["final_error"] * (1 + 1e-4)
    assert records["batch"]["reorderings"] >= 1
    # the replay's estimate is close to the batch optimum (the same minimum, ISAM2 stops short of it)
    status, out, _ = run_main(capsys, "posegraph", SMALL, "--backend", "native", "--json", "--init", "file")
    assert records["native"]["final_error"] == pytest.approx(last_json(out)["final_error"], rel=1e-2)


def test_cli_incremental_options_output_and_plot(tmp_path, capsys):
    out_g2o, png = tmp_path / "o.g2o", tmp_path / "p.png"
    status, out, err = run_main(capsys, "posegraph", write(tmp_path, TINY2D), "--incremental", "--json",
                                "--relinearize-threshold", "0.01", "--relinearize-skip", "1",
                                "--output", str(out_g2o), "--plot", str(png))
    assert status == 0, err
    d = last_json(out)
    assert d["relinearize_threshold"] == 0.01 and d["relinearize_skip"] == 1 and d["dimension"] == 2
    again = read_pose_graph(str(out_g2o))
    assert again.pose_count == 5 and again.edge_count == 6
    assert png.stat().st_size > 0


@pytest.mark.parametrize("name,backend", [("pose3example-grid.txt", "dropin"), ("noisyToyGraph.txt", "dropin"),
                                          ("known_landmark_localization_20.g2o", "dropin"),
                                          ("pose3example-grid.txt", "batch"),
                                          ("known_landmark_localization_20.g2o", "batch")])
def test_cli_incremental_on_gtsam_example_files(capsys, name, backend):
    status, out, err = run_main(capsys, "posegraph", name, "--incremental", "--backend", backend, "--json")
    assert status == 0, err
    d = last_json(out)
    pg = read_pose_graph(name)
    assert d["updates"] == pg.pose_count and d["landmarks"] == pg.landmark_count
    assert np.isfinite(d["final_error"])


def test_cli_incremental_sim3(tmp_path, capsys):
    status, out, err = run_main(capsys, "demo", "--scenario", "sim3", "--poses", "30", "--output",
                              str(tmp_path), "--quiet")
    assert status == 0, err
    for backend in ("native", "dropin", "batch"):
        status, out, err = run_main(capsys, "posegraph", str(tmp_path / "optimized.g2o"), "--incremental",
                                    "--backend", backend, "--json", "--quiet")
        assert status == 0, err
        d = last_json(out)
        assert d["updates"] == 30 and d["dimension"] == 3 and np.isfinite(d["final_error"])


@pytest.mark.parametrize("backend", ["native", "batch"])
def test_progress_line_every_1000_updates(capsys, backend):
    status, out, err = run_main(capsys, "posegraph", "cityTrees_reduced_1k.g2o", "--incremental",
                                "--backend", backend)
    assert status == 0
    assert [line.split(":")[0] for line in err.splitlines() if line.startswith("update ")] == ["update 1000/1000"]


def test_incremental_errors_are_one_line(tmp_path, capsys):
    status, out, err = run_main(capsys, "posegraph", SMALL, "--incremental", "--robust", "huber")
    assert_one_line_error(status, out, err, "--robust does not apply to --incremental")
    status, out, err = run_main(capsys, "posegraph", SMALL, "--incremental", "--init", "chordal")
    assert_one_line_error(status, out, err, "--init does not apply")
    status, out, err = run_main(capsys, "posegraph", SMALL, "--relinearize-skip", "2")
    assert_one_line_error(status, out, err, "apply to --incremental only")
    with pytest.raises(SystemExit) as info:
        cli.main(["posegraph", SMALL, "--incremental", "--relinearize-threshold", "0"])
    assert info.value.code == 2
    capsys.readouterr()
    # pose 1 has no edge to pose 0: it cannot be added online
    text = (f"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n"
            f"EDGE_SE2 0 2 2 0 0 {INFO2}\nEDGE_SE2 1 2 1 0 0 {INFO2}\n")
    status, out, err = run_main(capsys, "posegraph", write(tmp_path, text), "--incremental")
    assert_one_line_error(status, out, err, "pose 1 has no edge to an earlier pose")
    # an ISAM2 failure (indeterminate system: pose 1 appears with one landmark measurement only)
    text = (f"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\nLANDMARK2 1 5 3 4 10 0 10\n"
            f"EDGE_SE2 0 2 2 0 0 {INFO2}\nEDGE_SE2 1 2 1 0 0 {INFO2}\n")
    status, out, err = run_main(capsys, "posegraph", write(tmp_path, text, "i.g2o"), "--incremental",
                              "--backend", "native")
    assert_one_line_error(status, out, err, "ISAM2 update 2 (pose 1) failed", "Indeterminate")
    status, out, err = run_main(capsys, "posegraph", write(tmp_path, text, "i.g2o"), "--incremental")
    assert_one_line_error(status, out, err, "update 2 (pose 1) failed", "undetermined")
