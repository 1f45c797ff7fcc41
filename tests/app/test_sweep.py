"""``lie-factors sweep``: the summary and the plot from a results file, and bad input in one line (exit 2)
before any case runs; ``import lie_factors`` loads no Dask."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

from lie_factors.sweeps.results import ResultsFile
from support.cli_helpers import assert_one_line_error, run_main

ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "data" / "smallGrid3D.g2o"
SPEC = f'[graphs]\ngrid = "{SMALL}"\n[corruption]\nkinds = ["uniform"]\nfractions = [0.1]\nseeds = [1]\n' \
       '[methods.ours]\ngnc = "tls"\n[methods.gtsam]\nbackend = "native"\ngnc = "tls"\nconsistency = false\n'


def results(tmp_path: Path) -> str:
    path = str(tmp_path / "r.csv")
    with ResultsFile(path) as out:
        for method, options, values in (("ours", "{}", (0.5, 1.0, 0.9)), ("gtsam", '{"backend": "native"}',
                                                                            (1.0, 0.25, 0.5))):
            for fraction in (0.1, 0.2):
                for seed, p in enumerate(values, 1):
                    out.add({"case": f"g/group/{fraction}/{seed}/{method}", "graph": "g", "kind": "group",
                             "fraction": fraction, "seed": seed, "method": method, "options": options,
                             "status": "ok", "precision": p, "recall": 1 - p / 2, "map_error": 10 * p,
                             "seconds": 1.0})
    return path


def test_summary_and_plot(tmp_path, capsys):
    png = tmp_path / "sweep.png"
    status, out, err = run_main(capsys, "sweep", "--summary", results(tmp_path), "--plot", str(png))
    assert status == 0, err
    lines = out.splitlines()
    ours = next(line for line in lines if line.startswith("| g | 10% | group | ours |"))
    gtsam = next(line for line in lines if line.startswith("| g | 20% | group | gtsam |"))
    assert "| 0.500 / 0.900 | 0.500 / 0.550 |" in ours  # precision, recall: worst / median
    assert "| 0.250 / 0.500 |" in gtsam and "| 10 % / 5 % |" in gtsam  # map error: the worst is the largest
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    status, out, _ = run_main(capsys, "sweep", "--summary", results(tmp_path), "--tuning-seeds", "1")
    assert status == 0 and "| 0.900 / 0.950 |" in next(line for line in out.splitlines() if "10% | group | ours" in line)


def test_bad_input_is_one_line_before_any_case_runs(tmp_path, capsys, monkeypatch):
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.replace("consistency = false", "consistency = false\nthreads = 2"))
    out = tmp_path / "r.csv"
    assert_one_line_error(*run_main(capsys, "sweep", str(spec), "--out", str(out)),
                          f"{spec}:13: methods.gtsam.threads: unknown option of lf.optimize")
    spec.write_text(SPEC)
    notes = tmp_path / "notes.csv"
    notes.write_bytes(b"name,value\nx,1\n")
    assert_one_line_error(*run_main(capsys, "sweep", str(spec), "--out", str(notes)), "not a sweep's results file")
    assert notes.read_bytes() == b"name,value\nx,1\n"
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert_one_line_error(*run_main(capsys, "sweep", str(spec), "--out", str(out), "--scheduler",
                                    f"tcp://127.0.0.1:{port}"), f"tcp://127.0.0.1:{port}")
    assert_one_line_error(*run_main(capsys, "sweep", str(spec)), "--out RESULTS")
    assert_one_line_error(*run_main(capsys, "sweep", "--summary", str(notes)), "not a sweep's results file")
    assert_one_line_error(*run_main(capsys, "sweep", "--summary", str(tmp_path / "none.csv")), "no such results file")
    monkeypatch.setitem(sys.modules, "distributed", None)  # Dask not installed
    assert_one_line_error(*run_main(capsys, "sweep", str(spec), "--out", str(out)), "pip install", "dask")
    assert not out.exists()


def test_importing_the_package_loads_no_dask():
    code = ("import sys, lie_factors as lf, lie_factors.sweeps; lf.sweep; lf.sweep_summary; "
            "assert not {'dask', 'distributed', 'pyarrow'} & set(sys.modules), sorted(sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          cwd=str(ROOT))
    assert proc.returncode == 0, proc.stderr
