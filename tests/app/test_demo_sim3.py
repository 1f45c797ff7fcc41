"""The scale-drift scenario: lie_factors.app.demo_sim3, `lie-factors demo --scenario sim3`, and
examples/sim3_scale_drift.py (small sizes)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import gtsam
import numpy as np
import pytest

from lie_factors.app import cli, demo_sim3
from lie_factors import factors

ROOT = Path(__file__).resolve().parents[2]


def test_simulation_drifts_in_scale_and_rotation():
    p = demo_sim3.simulate(60, seed=4)
    assert len(p.odometry) == 59 and len(p.closures) == len(demo_sim3.loop_closure_pairs(60)) >= 3
    # Dead reckoning accumulates the scale bias: s_i ≈ e^{i·DRIFT_λ}.
    s_last = p.initial.atSimilarity3(59).scale()
    assert abs(np.log(s_last) - 59 * demo_sim3.DRIFT[6]) < 5 * np.sqrt(59) * demo_sim3.SIGMAS[6]
    assert all(T.scale() == 1.0 for T in p.truth)
    # Closures join poses one lap apart, at the same angle.
    for i, j, _ in p.closures:
        ci, cj = (p.truth[k].transformFrom(np.zeros(3)) for k in (i, j))
        assert np.linalg.norm(ci - cj) < 1.5
    again = demo_sim3.simulate(60, seed=4)
    assert np.array_equal(again.initial.atSimilarity3(59).matrix(), p.initial.atSimilarity3(59).matrix())


def test_ate_uses_camera_centres():
    truth = [gtsam.Similarity3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0]), 1.0)]
    values = gtsam.Values()
    values.insert(0, gtsam.Similarity3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0]), 2.0))  # centre s·t = (2, 0, 0)
    assert demo_sim3.ate_rmse(values, truth) == pytest.approx(1.0, abs=1e-15)


def test_true_gradient_matches_central_differences():
    """The gradient from our exact Jacobians is that of the cost GTSAM evaluates (central
    differences of graph.error along X·Exp(δ)), at the drifted start."""
    p = demo_sim3.simulate(12, seed=1)
    graph = demo_sim3.build_graph(p, factors)
    g = graph.linearize(p.initial).gradientAtZero()
    # central differences of graph.error along the right retraction, key by key
    h = 1e-6
    fd = []
    for k in range(12):
        x0 = p.initial.atSimilarity3(k)
        for j in range(7):
            d = np.zeros(7)
            d[j] = h
            vp, vm = gtsam.Values(p.initial), gtsam.Values(p.initial)
            vp.update(k, x0.retract(d))
            vm.update(k, x0.retract(-d))
            fd.append((graph.error(vp) - graph.error(vm)) / (2 * h))
    fd = np.array(fd)
    ours = np.concatenate([g.at(k) for k in range(12)])
    assert np.max(np.abs(ours - fd)) <= 1e-6 * np.max(np.abs(fd))
    assert demo_sim3.true_gradient_norm(graph, p.initial) == pytest.approx(np.linalg.norm(ours), rel=1e-12)


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim3demo")
    proc = subprocess.run([sys.executable, "-m", "lie_factors.app.cli", "demo", "--scenario", "sim3",
                           "--poses", "40", "--seed", "1", "--output", str(out), "--json"],
                          capture_output=True, text=True, timeout=600)
    return proc, out


def test_demo_sim3_reaches_stationary_point_native_does_not(demo_run):
    proc, out = demo_run
    assert proc.returncode == 0, proc.stderr
    rec = json.loads(proc.stdout.strip().splitlines()[-1])
    for key in ("backend", "dataset", "poses", "factors", "iterations", "initial_error", "final_error",
                "seconds", "converged", "ate_rmse_initial", "ate_rmse", "native_ate_rmse",
                "native_final_error", "gradient_norm_initial", "gradient_norm", "native_gradient_norm"):
        assert key in rec
    assert rec["scenario"] == "sim3" and rec["poses"] == 40 and rec["backend"] == "batch"
    # ours at a stationary point, native's gradient beside it.
    assert rec["gradient_norm"] <= 1e-6 * rec["gradient_norm_initial"]
    assert rec["native_gradient_norm"] > 100 * rec["gradient_norm"]
    assert rec["final_error"] <= rec["native_final_error"]
    assert rec["ate_rmse"] < 0.2 * rec["ate_rmse_initial"]
    assert rec["native_ate_rmse"] < 0.2 * rec["ate_rmse_initial"]
    # The human-readable table on stdout: both columns, the verdict.
    assert "GTSAM native" in proc.stdout and "ours reached a stationary point" in proc.stdout
    assert "iter" in proc.stderr
    assert (out / "trajectory.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = (out / "optimized.g2o").read_text()
    assert text.count("EDGE_SIM3:EXPMAP") == rec["factors"] - 1 and text.count("VERTEX_SIM3:EXPMAP") == 40


def test_demo_sim3_rejects_native_backend(tmp_path, capsys):
    status = cli.main(["demo", "--scenario", "sim3", "--backend", "native", "--poses", "10",
                       "--output", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and err[0].startswith("lie-factors: error: ")
    assert "native" in err[0]


def test_demo_unknown_scenario_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["demo", "--scenario", "sim4"])
    assert info.value.code == 2
    assert "sim4" in capsys.readouterr().err


def test_example_runs(tmp_path):
    png = tmp_path / "s.png"
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "sim3_scale_drift.py"), "40", str(png)],
                          capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    grads = {m.group(1): float(m.group(2))
             for m in re.finditer(r"^(\w+)\s*:.*\|gradient\| \S+ \((\S+) of initial\)", proc.stdout, re.M)}
    assert set(grads) == {"ours", "native"}, proc.stdout
    assert grads["ours"] <= 1e-6 < grads["native"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
