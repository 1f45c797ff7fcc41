"""benchmarks/generate_posegraph.py: seeded, readable by GTSAM, vertices = composed odometry, closures one turn apart."""

from __future__ import annotations

import filecmp
import os
import subprocess
import sys

import gtsam
import numpy as np

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")
SCRIPT = os.path.join(ROOT, "benchmarks", "generate_posegraph.py")


def _write(path, *extra):
    subprocess.run([sys.executable, SCRIPT, "--poses", "2500", "--lap", "500", "--output", str(path), *extra],
                   check=True, capture_output=True)


def test_same_seed_same_file_other_seed_other_file(tmp_path):
    _write(tmp_path / "a.g2o")
    _write(tmp_path / "b.g2o")
    _write(tmp_path / "c.g2o", "--seed", "1")
    assert filecmp.cmp(tmp_path / "a.g2o", tmp_path / "b.g2o", shallow=False)
    assert not filecmp.cmp(tmp_path / "a.g2o", tmp_path / "c.g2o", shallow=False)


def test_graph_as_gtsam_reads_it(tmp_path):
    _write(tmp_path / "a.g2o")
    graph, values = gtsam.readG2o(str(tmp_path / "a.g2o"), True)
    n, lap, every = 2500, 500, 10
    closures = len(range(lap, n, every))
    assert values.size() == n and graph.size() == n - 1 + closures
    for k in range(graph.size()):
        f = graph.at(k)
        a, b = f.keys()
        if k < n - 1:  # odometry: vertex b is vertex a composed with the measurement
            assert (a, b) == (k, k + 1)
            pred = values.atPose3(a).compose(f.measured())
            assert np.max(np.abs(pred.matrix() - values.atPose3(b).matrix())) < 1e-9
        else:  # a loop closure to the pose one turn below, measured with the stated noise
            assert b - a == lap and b % every == 0
    sigmas = graph.at(0).noiseModel().sigmas()
    assert np.allclose(sigmas, [0.01, 0.01, 0.01, 0.05, 0.05, 0.05])
    # The closures agree with the truth the odometry drifted from: LM from the file brings the error
    # to about its expected value (half the residual degrees of freedom, 6 per independent cycle).
    graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
    dof = 6 * closures
    assert 0.5 * dof * 0.8 < graph.error(result) < 0.5 * dof * 1.2
