"""Small pose-graph files for the online replay's tests (tests/incremental/test_replay.py and the
command's, tests/app/test_incremental.py)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: GTSAM's 3-D grid (125 poses, 297 edges), shipped in data/.
SMALL = str(ROOT / "data" / "smallGrid3D.g2o")

INFO2 = "100 0 0 100 0 400"
#: Poses 0..4 on a square-ish path; edge 3 is stored backwards (4 -> 3), edge 2-0 is a loop closure.
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

#: Pose 1 has no edge to pose 0: it cannot be added online.
UNREACHABLE = (f"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n"
               f"EDGE_SE2 0 2 2 0 0 {INFO2}\nEDGE_SE2 1 2 1 0 0 {INFO2}\n")

#: Pose 1 appears with one landmark measurement only: the update that adds it is indeterminate.
INDETERMINATE = (f"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\nLANDMARK2 1 5 3 4 10 0 10\n"
                 f"EDGE_SE2 0 2 2 0 0 {INFO2}\nEDGE_SE2 1 2 1 0 0 {INFO2}\n")


def write(tmp_path, text, name="g.g2o") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)
