"""The ``lie-factors`` CLI: demo, posegraph, bad input, JSON, subcommand registry."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from support.cli_helpers import assert_one_line_error, last_json, run_main
from lie_factors.app import cli
from lie_factors import factors  # noqa: F401  (the dropin backend; a broken import must fail, not skip)

ROOT = Path(__file__).resolve().parents[2]
SMALL = str(ROOT / "data" / "smallGrid3D.g2o")


# -------------------------------------------------------------------- demo

def test_demo_small_native(tmp_path, capsys):
    status, out, err = run_main(capsys, "demo", "--poses", "40", "--seed", "3", "--backend", "native",
                                "--output", str(tmp_path / "d"), "--json")
    assert status == 0
    rec = last_json(out)
    for key in ("backend", "dataset", "poses", "factors", "iterations", "initial_error",
                "final_error", "seconds", "converged", "ate_rmse_initial", "ate_rmse"):
        assert key in rec
    assert rec["poses"] == 40 and rec["converged"]
    assert rec["final_error"] < rec["initial_error"]
    assert rec["ate_rmse"] < rec["ate_rmse_initial"]
    assert "ATE" in out and "iter" in err  # report on stdout, progress on stderr
    assert (tmp_path / "d" / "trajectory.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "d" / "optimized.g2o").read_text().count("EDGE_SE3:QUAT") == rec["factors"] - 1


def test_demo_is_seeded(tmp_path, capsys):
    recs = []
    for k in range(2):
        status, out, _ = run_main(capsys, "demo", "--poses", "30", "--backend", "native", "--quiet",
                                  "--json", "--output", str(tmp_path / f"d{k}"))
        recs.append(last_json(out))
    assert recs[0]["final_error"] == recs[1]["final_error"]
    assert recs[0]["ate_rmse"] == recs[1]["ate_rmse"]


def test_demo_quiet_prints_only_json(tmp_path, capsys):
    status, out, err = run_main(capsys, "demo", "--poses", "20", "--backend", "native", "--quiet",
                                "--json", "--output", str(tmp_path))
    assert status == 0 and err == ""
    assert len(out.strip().splitlines()) == 1


def test_demo_dropin_backend(tmp_path, capsys):
    results = {}
    for backend in ("native", "dropin"):
        status, out, _ = run_main(capsys, "demo", "--poses", "40", "--backend", backend, "--quiet",
                                  "--json", "--output", str(tmp_path / backend))
        assert status == 0
        results[backend] = last_json(out)
    assert results["dropin"]["final_error"] == pytest.approx(results["native"]["final_error"], rel=1e-6)


def test_demo_output_is_a_file(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    assert_one_line_error(*run_main(capsys, "demo", "--poses", "10", "--backend", "native",
                                    "--output", str(f)), "not a directory")


# --------------------------------------------------------------- posegraph

def test_posegraph_native_outputs(tmp_path, capsys):
    out_g2o, out_png = tmp_path / "o.g2o", tmp_path / "o.png"
    status, out, err = run_main(capsys, "posegraph", SMALL, "--backend", "native", "--json",
                                "--init", "file", "--output", str(out_g2o), "--plot", str(out_png))
    assert status == 0
    rec = last_json(out)
    assert rec["backend"] == "native" and rec["dataset"] == "smallGrid3D.g2o"
    assert rec["poses"] == 125 and rec["factors"] == 298 and rec["converged"]
    assert rec["final_error"] == pytest.approx(517.9253346774, rel=1e-9)
    assert err.count("iter ") == rec["iterations"]
    assert out_g2o.read_text().count("VERTEX_SE3:QUAT") == 125
    assert out_png.read_bytes()[:4] == b"\x89PNG"


def test_posegraph_gtsam_example_by_name(capsys):
    # sphere2500.txt: EDGE3 lines only, initialized from a spanning tree.
    status, out, err = run_main(capsys, "posegraph", "sphere2500.txt", "--backend", "native",
                                "--max-iterations", "1", "--quiet", "--json")
    assert status == 0 and err == ""
    rec = last_json(out)
    assert rec["poses"] == 2500 and rec["iterations"] == 1 and not rec["converged"]


@pytest.mark.parametrize("backend", ["batch", "native"])
def test_posegraph_progress_lines_per_stage_and_iteration(backend, tmp_path, capsys):
    """Every stage and every iteration says on stderr how long the command has run and its memory."""
    import re

    out_file = tmp_path / "out.g2o"
    status, out, err = run_main(capsys, "posegraph", SMALL, "--backend", backend, "--output", str(out_file),
                                "--json")
    assert status == 0
    stamp = r"\[ *(\d+\.\d\d) s, RSS \d+(?:\.\d\d)? [MG]iB, peak \d+(?:\.\d\d)? [MG]iB\]"
    stages = [(m.group(2), float(m.group(1))) for m in re.finditer(stamp + r" (\w+(?: \w+)*)", err)]
    assert [name for name, _ in stages] == ["read and checked", "initialized", "set up", "optimized", "wrote"]
    iterations = [line for line in err.splitlines() if line.startswith("iter ")]
    assert iterations and all(re.search(stamp + "$", line) for line in iterations)
    elapsed = [t for _, t in stages]
    assert elapsed == sorted(elapsed)
    assert last_json(out)["iterations"] == len(iterations)
    status, out, err = run_main(capsys, "posegraph", SMALL, "--backend", backend, "--quiet", "--json")
    assert status == 0 and err == ""


def test_posegraph_dropin_matches_native(capsys):
    recs = {}
    for backend in ("native", "dropin"):
        status, out, _ = run_main(capsys, "posegraph", SMALL, "--backend", backend, "--quiet", "--json")
        assert status == 0
        recs[backend] = last_json(out)
    assert recs["dropin"]["final_error"] == pytest.approx(recs["native"]["final_error"], rel=1e-6)


def test_posegraph_batch_matches_native(tmp_path, capsys):
    recs = {}
    for backend in ("native", "batch"):
        out_file = tmp_path / f"{backend}.g2o"
        status, out, err = run_main(capsys, "posegraph", SMALL, "--backend", backend, "--json",
                                    "--output", str(out_file))
        assert status == 0
        recs[backend] = last_json(out)
        assert out_file.read_text().count("EDGE_SE3:QUAT") == recs[backend]["factors"] - 1
        assert err.count("iter ") == recs[backend]["iterations"]  # one progress line per iteration
    assert recs["batch"]["backend"] == "batch"
    assert recs["batch"]["iterations"] == recs["native"]["iterations"]
    assert recs["batch"]["final_error"] == pytest.approx(recs["native"]["final_error"], rel=1e-6)


# --------------------------------------------------------------- bad input

SE2_INFO = "1 0 0 1 0 1"


@pytest.mark.parametrize(
    "text, fragments",
    [
        ("EDGE_SE3:QUAT 0 1 1 2 3 0 0 0 1 1 1 1\n", ["bad.g2o:1:", "EDGE_SE3:QUAT expects 30 fields", "got 12"]),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 5 6 1 0 0 " + SE2_INFO + "\n",
         ["bad.g2o", "not connected", "pose 1 cannot be reached from pose 0"]),
        ("VERTEX_SE2 0 0 0 0\n", ["empty graph"]),
        ("", ["empty graph"]),
        ("VERTEX_SE2 0 0 0 0\nWHAT 1\n", ["bad.g2o:2:", "unknown tag 'WHAT'"]),
        ("EDGE_SE2 0 1 1 0 nan " + SE2_INFO + "\n", ["bad.g2o:1:", "not finite"]),
        ("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 -1\n", ["bad.g2o:1:", "not positive definite"]),
    ],
)
def test_bad_files(tmp_path, capsys, text, fragments):
    path = tmp_path / "bad.g2o"
    path.write_text(text)
    assert_one_line_error(*run_main(capsys, "posegraph", str(path), "--backend", "native"), *fragments)


def test_missing_file(tmp_path, capsys):
    assert_one_line_error(*run_main(capsys, "posegraph", str(tmp_path / "nope.g2o"), "--backend", "native"),
                          "no such file")
    assert_one_line_error(*run_main(capsys, "posegraph", "nope-not-in-gtsam.g2o", "--backend", "native"),
                          "not a dataset shipped with GTSAM")


def test_unknown_backend(capsys):
    assert_one_line_error(*run_main(capsys, "posegraph", SMALL, "--backend", "quantum"),
                          "unknown backend 'quantum'")
    assert_one_line_error(*run_main(capsys, "demo", "--backend", "quantum", "--poses", "5"),
                          "unknown backend 'quantum'")


def test_unwritable_output_checked_before_optimizing(tmp_path, capsys):
    target = str(tmp_path / "no" / "such" / "dir" / "out.g2o")
    status, out, err = run_main(capsys, "posegraph", SMALL, "--backend", "native", "--output", target)
    assert_one_line_error(status, out, err, "does not exist")
    assert "iter" not in err and out == ""  # nothing was optimized
    assert_one_line_error(*run_main(capsys, "posegraph", SMALL, "--backend", "native",
                                    "--plot", str(tmp_path)), "is a directory")


def test_existing_output_not_clobbered_by_failed_run(tmp_path, capsys):
    out_file = tmp_path / "result.g2o"
    out_file.write_text("previous result\n")
    bad = tmp_path / "bad.g2o"
    bad.write_text("EDGE_SE2 0 1 1 0 0\n")
    assert_one_line_error(*run_main(capsys, "posegraph", str(bad), "--backend", "native",
                                    "--output", str(out_file)), "EDGE_SE2 expects")
    assert out_file.read_text() == "previous result\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.g2o", "result.g2o"]


def test_usage_errors_exit_2(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["demo", "--poses", "-3"])
    assert info.value.code == 2
    with pytest.raises(SystemExit) as info:
        cli.main([])
    assert info.value.code == 2


# ---------------------------------------------------------- process level

def run_module(*argv, cwd=None):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "lie_factors.app.cli", *argv], capture_output=True,
                          text=True, env=env, cwd=cwd, timeout=120)


def test_python_m_entry_point_json_last_line(tmp_path):
    p = run_module("posegraph", SMALL, "--backend", "native", "--json", "--max-iterations", "3")
    assert p.returncode == 0, p.stderr
    rec = json.loads(p.stdout.strip().splitlines()[-1])
    assert rec["iterations"] == 3
    assert p.stderr.count("iter ") == 3


def test_python_m_bad_input_no_traceback(tmp_path):
    bad = tmp_path / "sphere.g2o"
    bad.write_text("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n" * 1 + "EDGE_SE3:QUAT 0 1 1 2 3\n")
    p = run_module("posegraph", str(bad), "--backend", "native")
    assert p.returncode == 2
    assert p.stderr.strip() == ("lie-factors: error: sphere.g2o:2: EDGE_SE3:QUAT expects 30 fields "
                                "(id1 id2 x y z qx qy qz qw + 21 information (6×6 upper triangle)), "
                                "got 5")
    assert p.stdout == ""


def test_help_lists_subcommands():
    p = run_module("--help")
    assert p.returncode == 0
    assert "demo" in p.stdout and "posegraph" in p.stdout


# ------------------------------------------------------- subcommand registry

def test_optional_subcommand_absent_is_not_offered(monkeypatch):
    monkeypatch.setitem(cli.OPTIONAL_SUBCOMMANDS, "ghost", ("lie_factors._no_such_module", "x"))
    parser, commands = cli.build_parser()
    assert "ghost" not in commands


def test_optional_subcommand_is_one_table_entry(monkeypatch, tmp_path, capsys):
    mod = tmp_path / "lf_extra_cmd.py"
    mod.write_text('"""say hello"""\n'
                   "def add_arguments(p):\n    p.add_argument('--name', default='x')\n"
                   "def main(args):\n    print('hello', args.name)\n    return 0\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(cli.OPTIONAL_SUBCOMMANDS, "hello", ("lf_extra_cmd", "say hello"))
    status, out, _ = run_main(capsys, "hello", "--name", "world")
    assert status == 0 and out == "hello world\n"


def test_broken_optional_subcommand_does_not_break_cli(monkeypatch, tmp_path, capsys):
    mod = tmp_path / "lf_broken_cmd.py"
    mod.write_text("import lf_definitely_missing_dependency\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(cli.OPTIONAL_SUBCOMMANDS, "broken", ("lf_broken_cmd", "broken"))
    assert_one_line_error(*run_main(capsys, "broken"), "broken is unavailable")
    status, out, _ = run_main(capsys, "demo", "--poses", "5", "--backend", "native", "--quiet",
                              "--json", "--output", str(tmp_path / "d"))
    assert status == 0


def test_optional_subcommand_parsing_its_own_argv(monkeypatch, tmp_path, capsys):
    # The crosscheck style: no add_arguments, main(argv) gets the raw arguments.
    mod = tmp_path / "lf_argv_cmd.py"
    mod.write_text("def main(argv=None):\n    print('got', argv)\n    return 3\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(cli.OPTIONAL_SUBCOMMANDS, "raw", ("lf_argv_cmd", "raw"))
    status, out, _ = run_main(capsys, "raw", "--samples", "2", "--help")
    assert status == 3 and out == "got ['--samples', '2', '--help']\n"


# ------------------------------------------------- startup and numeric options

def test_help_imports_no_heavy_module():
    """--help (top level and per subcommand) must not import GTSAM, numba, matplotlib or numpy."""
    code = ("import sys\nfrom lie_factors.app import cli\n"
            "for argv in (['--help'], ['posegraph', '--help'], ['demo', '--help']):\n"
            "    try:\n        cli.main(argv)\n    except SystemExit as e:\n        assert e.code == 0\n"
            "print(sorted(m for m in ('gtsam', 'numba', 'matplotlib', 'numpy') if m in sys.modules),"
            " file=sys.stderr)\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stderr.strip() == "[]"
    assert "crosscheck" in p.stdout  # deferred optional subcommands are still listed


def test_backend_names_match_the_library_and_one_default_everywhere():
    from lie_factors import backends, solve

    assert cli.BACKENDS == backends.BACKENDS == solve.BACKENDS
    assert cli.BACKENDS[0] == backends.DEFAULT_BACKEND == "batch"
    parser, _ = cli.build_parser()
    for command in ("posegraph", "demo"):
        args = parser.parse_args([command] + (["x.g2o"] if command == "posegraph" else []))
        assert args.backend == backends.DEFAULT_BACKEND
    import inspect

    import lie_factors as lf

    assert inspect.signature(lf.optimize).parameters["backend"].default == backends.DEFAULT_BACKEND
    assert inspect.signature(lf.replay).parameters["backend"].default == backends.DEFAULT_BACKEND


@pytest.mark.parametrize("argv, fragment", [
    (["demo", "--poses", "0"], "--poses: must be from 2"),
    (["demo", "--poses", "1"], "--poses: must be from 2"),
    (["demo", "--poses", str(10**9)], f"--poses: must be from 2 to {cli.MAX_DEMO_POSES}"),
    (["demo", "--poses", "many"], "--poses: expected an integer"),
    (["demo", "--seed", "-1"], "--seed: must be from 0"),
    (["demo", "--seed", str(2**64)], "--seed: must be from 0"),
    (["demo", "--max-iterations", str(10**30)], "--max-iterations: must be from 0 to"),
    (["demo", "--max-iterations", "-1"], "--max-iterations: must be from 0 to"),
    (["posegraph", SMALL, "--max-iterations", str(10**30)], "--max-iterations: must be from 0 to"),
    (["posegraph", SMALL, "--max-iterations", "1.5"], "--max-iterations: expected an integer"),
    (["bogus"], "invalid choice"),
    ([], "required"),
])
def test_numeric_and_usage_errors_are_one_line(capsys, argv, fragment):
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    assert info.value.code == 2
    out, err = capsys.readouterr()
    assert_one_line_error(2, out, err, fragment)
    assert out == ""


def test_largest_accepted_values_run(tmp_path, capsys):
    # The limits are accepted (bounded work): the largest iteration limit and seed with a tiny demo.
    status, out, _ = run_main(capsys, "demo", "--poses", "2", "--seed", str(cli.MAX_SEED),
                              "--max-iterations", str(cli.MAX_ITERATIONS), "--backend", "native",
                              "--quiet", "--json", "--output", str(tmp_path / "d"))
    assert status == 0
    assert last_json(out)["poses"] == 2


def test_console_script_is_main_then_gc_freeze(monkeypatch):
    """The installed ``lie-factors`` runs ``cli.entry``: ``main``'s status, then ``gc.freeze()``
    so that the interpreter's exit skips its sweep of every object."""
    import gc
    import re

    scripts = (ROOT / "pyproject.toml").read_text()
    assert re.search(r'^lie-factors = "lie_factors\.app\.cli:entry"$', scripts, re.M)
    calls = []
    monkeypatch.setattr(gc, "freeze", lambda: calls.append("freeze"))
    monkeypatch.setattr(cli, "main", lambda argv=None: calls.append("main") or 7)
    assert cli.entry() == 7 and calls == ["main", "freeze"]


_CRASH_IN_MAIN = """
import ctypes
from lie_factors.app import cli
cli.main = lambda argv=None: ctypes.string_at(0)   # a fatal signal where a run would be
cli.entry()
"""


def test_a_crash_in_the_console_script_prints_where_it_happened():
    out = subprocess.run([sys.executable, "-c", _CRASH_IN_MAIN], capture_output=True, text=True, timeout=120)
    assert out.returncode < 0 or out.returncode == 139
    assert "Fatal Python error: Segmentation fault" in out.stderr
    assert re.search(r'File ".*cli\.py", line \d+ in entry', out.stderr), out.stderr


def test_main_called_from_python_leaves_the_collector_alone(capsys):
    import gc

    frozen = gc.get_freeze_count()
    assert run_main(capsys, "posegraph", SMALL, "--backend", "native", "--max-iterations", "1")[0] == 0
    assert gc.get_freeze_count() == frozen
