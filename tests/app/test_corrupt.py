"""``lie-factors corrupt FILE OUT``: the same closures as ``lf.corrupt``, the files it writes, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import lie_factors as lf
from lie_factors import corruption
from lie_factors.app import cli
from lie_factors.app import corrupt as app
from support.cli_helpers import assert_one_line_error, last_json, run_main

ROOT = Path(__file__).resolve().parents[2]
SMALL = str(ROOT / "data" / "smallGrid3D.g2o")


def test_cli_writes_what_the_python_api_plants(tmp_path, capsys):
    out = tmp_path / "bad.g2o"
    status, stdout, _ = run_main(capsys, "corrupt", SMALL, str(out), "--fraction", "0.2", "--kind", "group",
                                 "--seed", "4", "--json")
    assert status == 0
    rec = last_json(stdout)
    c = lf.corrupt(SMALL, fraction=0.2, kind="group", seed=4)
    assert rec["planted"] == c.planted.tolist() and rec["planted_list"] == str(tmp_path / "bad.planted.txt")
    back = lf.read_g2o(str(out))
    assert np.array_equal(back.edge_keys, c.graph.edge_keys)
    listed = np.loadtxt(rec["planted_list"], dtype=np.int64, ndmin=2)
    assert np.array_equal(listed[:, 0], c.planted) and np.array_equal(listed[:, 1:], c.planted_keys())


def test_cli_planted_path_option(tmp_path, capsys):
    status, _, _ = run_main(capsys, "corrupt", SMALL, str(tmp_path / "b.g2o"), "--fraction", "0.1",
                            "--planted", str(tmp_path / "list"), "--quiet")
    assert status == 0 and (tmp_path / "list").exists() and not (tmp_path / "b.planted.txt").exists()


def test_cli_bad_input(tmp_path, capsys):
    out = str(tmp_path / "bad.g2o")
    assert_one_line_error(*run_main(capsys, "corrupt", str(tmp_path / "none.g2o"), out, "--fraction", "0.2"),
                          "none.g2o")
    assert_one_line_error(*run_main(capsys, "corrupt", SMALL, SMALL, "--fraction", "0.2"), "overwrite the input")
    assert_one_line_error(*run_main(capsys, "corrupt", SMALL, out, "--fraction", "0.2", "--planted", SMALL),
                          "overwrite the input")
    assert_one_line_error(*run_main(capsys, "corrupt", SMALL, out, "--fraction", "0.2", "--planted", out),
                          "different files")
    for argv, name in ((["--fraction", "0.2", "--kind", "clustered"], "--kind"), (["--fraction", "0"], "--fraction"),
                       (["--fraction", "0.2", "--seed", "-1"], "--seed")):
        with pytest.raises(SystemExit) as info:  # argparse: one line, usage status
            cli.main(["corrupt", SMALL, out, *argv])
        assert info.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and name in err[0]
    assert not Path(out).exists()


def test_cli_kinds_are_the_library_kinds():
    assert app.KINDS == corruption.KINDS
