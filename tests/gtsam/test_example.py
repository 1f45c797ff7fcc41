"""examples/pose_graph_se3.py runs as documented and improves error and ATE."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_pose_graph_example_runs_and_improves(tmp_path):
    png = tmp_path / "example.png"
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "pose_graph_se3.py"), str(png)],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    err = re.search(r"error:\s+([\d.]+) -> ([\d.]+)", proc.stdout)
    ate = re.search(r"ATE:\s+([\d.]+) m -> ([\d.]+) m", proc.stdout)
    assert err and ate, proc.stdout
    assert float(err.group(2)) < 0.01 * float(err.group(1))
    assert float(ate.group(2)) < 0.5 * float(ate.group(1))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
