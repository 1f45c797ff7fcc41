"""GTSAM's own ISAM2 tests as the judge of the incremental smoother: with ``gtsam.ISAM2 =
lf.Smoother`` (and ``gtsam.IncrementalFixedLagSmoother = lf.IncrementalFixedLagSmoother``)
assigned before they import, every test of these files passes; the one that compares a
floating-point accident may fail, by rounding only (docs/incremental.md, "GTSAM's tests")."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

RUNNER = os.path.join(os.path.dirname(__file__), "..", "support", "run_gtsam_tests.py")

FILES = ["test_ISAM2.py", "test_ISAM2FillIn.py", "test_ISAM2ResultKeys.py", "test_VisualISAMExample.py",
         "test_FixedLagSmootherExample.py", "test_FixedLagSmootherAccessors.py"]

#: ``error(VectorValues)`` compared with a literal to 7 decimals of 3.4e7, a relative 1.5e-15:
#: the value is set by the linearization point to the last bits (docs/incremental.md).
ROUNDING = {"test_VisualISAMExample.TestVisualISAMExample.test_isam2_error"}


@pytest.mark.slow
def test_gtsams_isam2_tests_pass_with_our_smoother(tmp_path):
    out = tmp_path / "smoother.json"
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    proc = subprocess.run([sys.executable, RUNNER, "smoother", str(out), *FILES], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    results = json.loads(out.read_text())
    assert set(results) == set(FILES)
    counts = {name: len(tests) for name, tests in results.items()}
    assert counts["test_ISAM2.py"] == 4 and counts["test_ISAM2FillIn.py"] == 7 and counts["test_ISAM2ResultKeys.py"] == 4
    failed = {t: text for tests in results.values() for t, (o, text) in tests.items() if o != "passed"}
    assert set(failed) <= ROUNDING, "\n".join(f"{t}:\n{text}" for t, text in failed.items() if t not in ROUNDING)
    for text in failed.values():  # off by rounding only: 34212421.14732 to 7 decimals
        assert "34212421.1473" in text and "within 7 places" in text
