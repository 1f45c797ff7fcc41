"""Fuzzing the g2o reader: every input ends in a correct load or ONE clear error line.

Most cases run in-process against lie_factors.g2o / lie_factors.g2o.read_pose_graph (hypothesis); a few go through
the CLI in a subprocess (exit status 2, one stderr line, no traceback, no partly written output).
Properties checked on every generated file:
* ``load`` either succeeds or raises InputError with a one-line message (nothing else escapes:
  no traceback, no crash inside GTSAM — GTSAM only ever sees checked files);
* the vectorized parse and the exact line-by-line parse agree (same rows, or the same error), and the
  numba scan reads the same rows or gives up;
* a successful load has exactly the factors and variables the file's lines describe.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import gtsam
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lie_factors import g2o
import lie_factors.g2o.load as loading
from lie_factors.g2o import parse
from support.runs import run
from lie_factors.g2o import read_pose_graph
from lie_factors.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
FUZZ = settings(max_examples=120, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

SE2_INFO = "1 0 0 1 0 1"
SE3_INFO = " ".join(" ".join(["1"] + ["0"] * (5 - r)) for r in range(6))


def base_2d(n: int = 5) -> str:
    lines = [f"VERTEX_SE2 {i} {i}.5 0.25 0.1" for i in range(n)]
    lines += [f"EDGE_SE2 {i} {i + 1} 1 0 0.1 {SE2_INFO}" for i in range(n - 1)]
    lines += ["VERTEX_XY 7 2 3", "LANDMARK2 0 7 2.5 3 10 0 10", "BR 1 8 0.3 2.0 0.05 0.1",
              "LANDMARK 2 9 1.5 -1 0.4 0 0.4"]
    return "\n".join(lines) + "\n"


def base_3d(n: int = 4) -> str:
    lines = [f"VERTEX_SE3:QUAT {i} {i} 0.5 0 0 0 0 1" for i in range(n)]
    lines += [f"EDGE_SE3:QUAT {i} {i + 1} 1 0 0 0 0 0 1 {SE3_INFO}" for i in range(n - 1)]
    lines += ["VERTEX_TRACKXYZ 3 4 1 2", "PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1",
              "EDGE_SE3_TRACKXYZ 0 3 0 4 1 2 1 0 0 1 0 1",
              "EDGE_SE3_TRACKXYZ 1 3 0 3 1 2 1 0 0 1 0 1"]
    return "\n".join(lines) + "\n"


BASES = [base_2d(), base_3d(), (ROOT / "data" / "smallGrid3D.g2o").read_text()[:6000].rsplit("\n", 1)[0] + "\n"]


def _write(tmp_path: Path, content: bytes) -> str:
    path = tmp_path / "fuzz.g2o"
    path.write_bytes(content)
    return str(path)


def _expected_counts(content: bytes):
    """Factors and variables the lines describe (independent of lie_factors' parser)."""
    factors, poses, landmarks = 0, set(), set()
    for line in content.split(b"\n"):
        tok = line.split()
        if not tok or tok[0].startswith(b"#"):
            continue
        rec = g2o.RECORDS[tok[0].decode()]
        ids = [int(t) for t in tok[1:1 + len(rec.ids)]]
        if rec.kind == "pose":
            poses.add(ids[0])
        elif rec.kind == "landmark":
            landmarks.add(ids[0])
        elif rec.kind == "between":
            factors += 1
            poses.update(ids)
        elif rec.kind == "observation":
            factors += 1
            poses.add(ids[0])
            landmarks.add(ids[1])
    return factors, len(poses), len(landmarks)


def _outcome(path: str):
    """(rows summary, None) or (None, error message) — from the given parser."""
    try:
        s = g2o.check_g2o(path)
    except InputError as exc:
        return None, str(exc)
    return {t: (r.ids.tolist(), r.values.tolist(), r.lines.tolist()) for t, r in s.rows.items()}, None


def _check_one(tmp_path: Path, content: bytes) -> None:
    path = _write(tmp_path, content)
    # 1. fast and slow parses agree.
    try:
        slow = parse.slow_parse("fuzz.g2o", content)
        slow_rows = {t: (r.ids.tolist(), r.values.tolist(), r.lines.tolist()) for t, r in slow[0].items()}
        slow_err = None
    except InputError as exc:
        slow_rows, slow_err = None, str(exc)
    try:
        fast = parse.fast_parse("fuzz.g2o", content)
    except InputError as exc:
        assert str(exc) == slow_err  # the same first bad line and message
    else:
        if fast is not None:  # None: leading whitespace, the slow parse is used
            assert slow_err is None, slow_err
            fast_rows = {t: (r.ids.tolist(), r.values.tolist(), r.lines.tolist())
                         for t, r in fast[0].items()}
            assert fast_rows == slow_rows
            assert fast[1] == slow[1] and fast[2] == slow[2]  # comments, fragile lines
    # 1b. the numba scan takes only files the exact parse accepts, and reads the same rows.
    scanned = parse.scan_parse(content)
    if scanned is not None:
        assert slow_err is None, slow_err
        scan_rows = {t: (r.ids.tolist(), r.values.tolist(), r.lines.tolist())
                     for t, r in scanned[0].items()}
        assert scan_rows == slow_rows
        assert scanned[1] == slow[1] and scanned[2] == slow[2]
    # 2. load: success with the right sizes, or one clear line.
    try:
        pg = read_pose_graph(path)
    except InputError as exc:
        msg = str(exc)
        assert msg and "\n" not in msg and "Traceback" not in msg
        return
    factors, poses, landmarks = _expected_counts(content)
    assert pg.edge_count + pg.observation_count == factors
    assert pg.pose_count == poses and pg.landmark_count == landmarks
    try:
        run(pg, "native", max_iterations=2)
    except InputError as exc:  # e.g. a coordinate of 1e154 whose square overflows
        assert "\n" not in str(exc) and "initial error" in str(exc)


def _tokens_mutation(content: str, data) -> str:
    lines = content.splitlines()
    k = data.draw(st.integers(0, len(lines) - 1))
    tok = lines[k].split()
    choice = data.draw(st.sampled_from(["swap", "replace", "drop", "extra", "dup", "selfloop"]))
    if choice == "swap" and len(tok) > 2:
        i, j = data.draw(st.integers(1, len(tok) - 1)), data.draw(st.integers(1, len(tok) - 1))
        tok[i], tok[j] = tok[j], tok[i]
    elif choice == "replace" and len(tok) > 1:
        i = data.draw(st.integers(0, len(tok) - 1))
        tok[i] = data.draw(st.sampled_from(
            ["nan", "inf", "-inf", "1e400", "-1e400", "1e-400", "1e308", "-0", "+3", ".5", "-.5",
             "1_0", "0x10", "1e", "--1", "1.0", "1e3", "-1", "99999999999999999999", "72057594037927936",
             "٣", "é", "\x00", "EDGE_SE2", "VERTEX_SE3:QUAT", "#", "1,5", "1.2.3", "1e+5", "0"]))
    elif choice == "drop" and len(tok) > 1:
        del tok[data.draw(st.integers(0, len(tok) - 1))]
    elif choice == "extra":
        tok.append(data.draw(st.sampled_from(["0", "1", "x"])))
    elif choice == "dup":
        lines.insert(k, lines[k])
    elif choice == "selfloop" and len(tok) > 2:
        tok[2] = tok[1]
    if choice != "dup":
        lines[k] = " ".join(tok)
    return "\n".join(lines) + "\n"


@FUZZ
@given(base=st.sampled_from(BASES), data=st.data())
def test_token_mutations(tmp_path, base, data):
    text = base
    for _ in range(data.draw(st.integers(1, 3))):
        text = _tokens_mutation(text, data)
    _check_one(tmp_path, text.encode("utf-8", "surrogatepass"))


@FUZZ
@given(base=st.sampled_from(BASES), cut=st.floats(0, 1), crlf=st.booleans(),
       comment=st.booleans(), indent=st.booleans())
def test_truncations_line_ends_comments(tmp_path, base, cut, crlf, comment, indent):
    raw = base.encode()
    raw = raw[: int(len(raw) * cut)]
    if comment:
        raw = b"# a comment \xc3\xa9\n" + raw.replace(b"\n", b"\n# .5 x\n", 1)
    if indent:
        raw = raw.replace(b"\n", b"\n  ", 2)
    if crlf:
        raw = raw.replace(b"\n", b"\r\n")
    _check_one(tmp_path, raw)


@FUZZ
@given(raw=st.binary(max_size=400))
def test_arbitrary_bytes(tmp_path, raw):
    _check_one(tmp_path, raw)


@FUZZ
@given(text=st.text(alphabet=st.sampled_from(list("0123456789 .-+eE\n\tVERTX_S2EDG#é")), max_size=300))
def test_arbitrary_g2o_like_text(tmp_path, text):
    _check_one(tmp_path, text.encode())


@FUZZ
@given(values=st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=3, max_size=3))
def test_huge_and_nonfinite_vertex_values(tmp_path, values):
    text = base_2d().replace("VERTEX_SE2 1 1.5 0.25 0.1",
                             "VERTEX_SE2 1 " + " ".join(repr(v) for v in values))
    _check_one(tmp_path, text.encode())


# ------------------------------------------------------------------ specific cases

def test_fast_and_slow_paths_agree_on_clean_files(tmp_path):
    for text in BASES:
        content = text.encode()
        fast = parse.fast_parse("x", content)
        slow = parse.slow_parse("x", content)
        assert fast is not None
        for tag in slow[0]:
            np.testing.assert_array_equal(fast[0][tag].ids, slow[0][tag].ids)
            np.testing.assert_array_equal(fast[0][tag].values, slow[0][tag].values)


def test_ids_at_the_56_bit_limit_fast_and_slow_agree():
    """2^56 − 1 is the largest id; 2^56 and the next integers (2^56 as floats) are refused by both parses."""
    ok = b"VERTEX_SE2 72057594037927935 0 0 0\n"
    assert parse.fast_parse("x", ok)[0]["VERTEX_SE2"].ids.tolist() == [[2 ** 56 - 1]]
    for i in (2 ** 56, 2 ** 56 + 1, 2 ** 56 + 4, 2 ** 56 + 8, 2 ** 57 - 1, 2 ** 57):
        data = b"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 %d 0 0 0\n" % i
        message = f"x:2: field 2: id {i} is larger than 2^56 - 1"
        for fn in (parse.fast_parse, parse.slow_parse):
            with pytest.raises(InputError, match=re.escape(message)):
                fn("x", data)


def test_fragile_vertex_value_does_not_cost_edges(tmp_path):
    # GTSAM's 2-D second pass reads '.5' as an id, fails, and drops every later edge.
    text = base_2d().replace("VERTEX_SE2 1 1.5", "VERTEX_SE2 1 .5").replace("VERTEX_SE2 2 2.5", "VERTEX_SE2 2 -.5")
    path = _write(tmp_path, text.encode())
    raw_graph, _ = gtsam.readG2o(path, False)
    assert raw_graph.size() == 0  # what GTSAM alone makes of it
    pg = read_pose_graph(path)
    assert pg.edge_count == 4 and pg.observation_count == 3
    assert pg.initial.atPose2(1).x() == 0.5 and pg.initial.atPose2(2).x() == -0.5


def test_empty_file_and_directory(tmp_path):
    with pytest.raises(InputError, match="empty graph"):
        read_pose_graph(_write(tmp_path, b""))
    with pytest.raises(InputError, match="is a directory"):
        read_pose_graph(str(tmp_path))
    with pytest.raises(InputError, match="is a directory"):
        g2o.check_g2o(str(tmp_path))


def test_file_vanishing_between_check_and_read(tmp_path, monkeypatch):
    path = _write(tmp_path, base_2d().encode())
    real = g2o.check_g2o

    def check_then_delete(p):
        summary = real(p)
        os.unlink(p)
        return summary

    monkeypatch.setattr(loading, "check_g2o", check_then_delete)
    with pytest.raises(InputError) as info:
        read_pose_graph(path)
    assert "\n" not in str(info.value)


def test_file_vanishing_mid_read(tmp_path, monkeypatch):
    path = _write(tmp_path, base_2d().encode())

    class Vanishing:
        def __init__(self, *a, **k):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def read(self):
            raise FileNotFoundError(2, "No such file or directory")

    monkeypatch.setattr("builtins.open", Vanishing)
    with pytest.raises(InputError, match="cannot read"):
        g2o.check_g2o(path)


def test_duplicate_ids_and_self_loops(tmp_path):
    with pytest.raises(InputError, match=r":2: vertex 0 already defined on line 1"):
        read_pose_graph(_write(tmp_path, b"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 1 0 0\n"))
    with pytest.raises(InputError, match=r"landmark vertex 3 already defined"):
        read_pose_graph(_write(tmp_path, base_3d().replace("VERTEX_TRACKXYZ 3 4 1 2", "VERTEX_TRACKXYZ 3 4 1 2\nVERTEX_TRACKXYZ 3 4 1 2").encode()))
    with pytest.raises(InputError, match="edge connects vertex 1 to itself"):
        read_pose_graph(_write(tmp_path, f"VERTEX_SE2 1 0 0 0\nEDGE_SE2 1 1 1 0 0 {SE2_INFO}\n".encode()))
    # A pose and a landmark may share an id: different GTSAM keys.
    pg = read_pose_graph(_write(tmp_path, base_3d().replace("VERTEX_TRACKXYZ 3", "VERTEX_TRACKXYZ 0")
                       .replace("EDGE_SE3_TRACKXYZ 0 3", "EDGE_SE3_TRACKXYZ 0 0")
                       .replace("EDGE_SE3_TRACKXYZ 1 3", "EDGE_SE3_TRACKXYZ 1 0").encode()))
    assert pg.landmark_count == 1 and pg.pose_count == 4


# ------------------------------------------------------------------ through the CLI

def _cli(*args, cwd=None):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "lie_factors.app.cli", *args], capture_output=True,
                          text=True, env=env, cwd=cwd, timeout=300)


@pytest.mark.parametrize("content", [b"", b"\xff\xfe\x00garbage\r\n", "VERTEX_SE2 0 0 0 ٣\n".encode(),
                                     b"VERTEX_SE2 0 0 0 0\r\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 nan\r\n"])
def test_cli_bad_files_one_line_no_output(tmp_path, content):
    bad = tmp_path / "bad.g2o"
    bad.write_bytes(content)
    out = tmp_path / "out.g2o"
    out.write_text("precious\n")
    p = _cli("posegraph", str(bad), "--backend", "native", "--output", str(out))
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lie-factors: error: "), p.stderr
    assert "Traceback" not in p.stderr
    assert out.read_text() == "precious\n"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["bad.g2o", "out.g2o"]


def test_cli_directory_and_crlf_landmark_file(tmp_path):
    p = _cli("posegraph", str(tmp_path), "--backend", "native")
    assert p.returncode == 2 and "is a directory" in p.stderr and len(p.stderr.strip().splitlines()) == 1
    crlf = tmp_path / "crlf.g2o"
    crlf.write_bytes(base_2d().replace("\n", "\r\n").encode())
    out = tmp_path / "o.g2o"
    p = _cli("posegraph", str(crlf), "--backend", "native", "--quiet", "--json", "--output", str(out))
    assert p.returncode == 0, p.stderr
    assert "LANDMARK2" in out.read_text() and "VERTEX_XY" in out.read_text()
