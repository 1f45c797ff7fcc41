"""``lie-factors posegraph FILE --incremental``: the online replay from the command line
(the replay itself: tests/incremental/test_replay.py)."""

from __future__ import annotations

import numpy as np
import pytest

from support.cli_helpers import assert_one_line_error, last_json, run_main
from support.replay_graphs import INDETERMINATE, SMALL, TINY2D, UNREACHABLE, write
from lie_factors.app import cli
from lie_factors.g2o import read_pose_graph


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
    status, out, err = run_main(capsys, "posegraph", write(tmp_path, UNREACHABLE), "--incremental")
    assert_one_line_error(status, out, err, "pose 1 has no edge to an earlier pose")
    # an ISAM2 failure (indeterminate system: pose 1 appears with one landmark measurement only)
    status, out, err = run_main(capsys, "posegraph", write(tmp_path, INDETERMINATE, "i.g2o"), "--incremental",
                                "--backend", "native")
    assert_one_line_error(status, out, err, "ISAM2 update 2 (pose 1) failed", "Indeterminate")
    status, out, err = run_main(capsys, "posegraph", write(tmp_path, INDETERMINATE, "i.g2o"), "--incremental")
    assert_one_line_error(status, out, err, "update 2 (pose 1) failed", "undetermined")
