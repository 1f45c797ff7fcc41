"""lf.sweep on Dask: the rows against the same runs made directly, a killed sweep resumed (only the
missing cases run), the same rows from a scheduler and a worker started by hand."""

from __future__ import annotations

import csv
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed", reason="the optional extra sweep (dask, distributed) is not installed")

import lie_factors as lf  # noqa: E402
from lie_factors.errors import InputError  # noqa: E402
from lie_factors.sweeps.results import read_results  # noqa: E402
from lie_factors.testing.outliers import classify  # noqa: E402

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "data" / "smallGrid3D.g2o"
SPEC = f"""\
[graphs]
grid = "{SMALL}"
[corruption]
kinds = ["uniform"]
fractions = [0.1]
seeds = [SEEDS]
[methods.ours]
gnc = "tls"
[methods.plain]
max_iterations = 20
"""
#: The figures a case computes, the same whichever process runs it.
DETERMINISTIC = ("case", "status", "planted", "rejected", "true_positives", "precision", "recall", "planted_consistent",
                 "rejected_by", "ate_rmse", "rpe_rmse", "reference", "map_error", "final_error", "iterations")


def env() -> dict:
    """The environment of a child process: this checkout first on the path."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


def spec(tmp_path: Path, seeds: str) -> str:
    path = tmp_path / "spec.toml"
    path.write_text(SPEC.replace("SEEDS", seeds))
    return str(path)


@pytest.fixture(scope="module")
def local_rows(tmp_path_factory):
    """Two seeds, two methods, on a LocalCluster of one worker."""
    tmp = tmp_path_factory.mktemp("local")
    out = str(tmp / "r.csv")
    rows = lf.sweep(spec(tmp, "1, 2"), out, workers=1)
    return rows, out


def test_rows_are_what_the_runs_give_directly(local_rows):
    rows, out = local_rows
    assert sorted(r["case"] for r in rows) == sorted(f"grid/uniform/0.1/{s}/{m}" for s in (1, 2)
                                                     for m in ("ours", "plain"))
    assert read_results(out) == rows
    clean = lf.optimize(lf.read_g2o(str(SMALL)))
    ref = clean.poses[:, :3, 3]
    diag = np.linalg.norm(ref.max(axis=0) - ref.min(axis=0))
    for r in rows:
        assert r["status"] == "ok" and r["error"] == "", r
        c = lf.corrupt(str(SMALL), fraction=0.1, kind="uniform", seed=r["seed"])
        result = lf.optimize(c.graph, gnc="tls") if r["method"] == "ours" else lf.optimize(c.graph, max_iterations=20)
        assert r["planted"] == len(c.planted) and r["iterations"] == result.iterations
        assert math.isclose(r["final_error"], result.error, rel_tol=1e-9)
        P = result.poses[:, :3, 3]
        assert math.isclose(r["map_error"], 100 * np.sqrt(np.mean(np.sum((P - ref) ** 2, axis=1))) / diag, rel_tol=1e-9)
        ev = lf.evaluate(result, clean)
        assert math.isclose(r["ate_rmse"], ev.ate.rmse, rel_tol=1e-9) and r["reference"] == "clean optimum"
        if r["method"] == "ours":
            k = classify(result.outliers, c.planted)
            assert (r["precision"], r["recall"], r["rejected"]) == (k.precision, k.recall, len(result.outliers))
            status = result.robust_status
            assert r["robust_status"] == status["status"] + "".join(f"; {x}" for x in status["reasons"])
        else:  # plain least squares rejects nothing: no precision or recall, no status
            assert r["precision"] is None and r["rejected"] is None and r["robust_status"] == ""
        assert r["peak_rss"] > 0 and r["case_seconds"] >= r["seconds"] > 0


def test_a_killed_sweep_resumes_with_the_missing_cases_only(tmp_path):
    """The command killed once its first row is written; the rerun runs the rest, each case once."""
    path = spec(tmp_path, "1, 2, 3")
    out = tmp_path / "r.csv"
    proc = subprocess.Popen([sys.executable, "-m", "lie_factors.app.cli", "sweep", path, "--out", str(out),
                             "--workers", "1", "--quiet"], env=env(), start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if out.exists() and out.read_text().count("\n") >= 2:  # the header and a row
                break
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the command and its cluster's processes
        proc.wait()
    before = {r["case"]: r["sweep_run"] for r in read_results(str(out))}
    assert 1 <= len(before) < 6
    rows = lf.sweep(path, str(out), workers=1)
    assert len(rows) == 6 and len({r["case"] for r in rows}) == 6
    again = {r["sweep_run"] for r in rows if r["case"] not in before}
    assert len(again) == 1 and again.isdisjoint(before.values())  # the missing cases, in this run
    assert {r["case"]: r["sweep_run"] for r in rows if r["case"] in before} == before  # the done ones kept
    assert all(r["status"] == "ok" for r in rows)
    # a third run has nothing left to do and leaves the file as it was
    content = out.read_bytes()
    assert len(lf.sweep(path, str(out), workers=1)) == 6 and out.read_bytes() == content


def _started(argv: list[str], pattern: str, procs: list) -> re.Match:
    """Start ``argv`` (kept in ``procs`` to be killed) and wait for ``pattern`` in its stderr."""
    proc = subprocess.Popen(argv, env=env(), stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            start_new_session=True)
    procs.append(proc)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line and proc.poll() is not None:
            break
        found = re.search(pattern, line)
        if found:
            return found
    raise AssertionError(f"{argv[2]} did not start")


@pytest.fixture
def scheduler_by_hand():
    """``dask scheduler`` and one ``dask worker`` as separate processes; the scheduler's address."""
    procs: list[subprocess.Popen] = []
    try:
        address = _started([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                            "--port", "0", "--no-dashboard"], r"Scheduler at:\s+(tcp://\S+)", procs).group(1)
        _started([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
                  "--no-dashboard"], r"Registered to", procs)
        yield address
    finally:
        for proc in procs:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait()


def test_a_scheduler_started_by_hand_gives_the_same_rows(tmp_path, scheduler_by_hand, local_rows):
    rows = lf.sweep(spec(tmp_path, "1, 2"), str(tmp_path / "r.csv"), scheduler=scheduler_by_hand)
    by_case = {r["case"]: r for r in local_rows[0]}
    assert sorted(r["case"] for r in rows) == sorted(by_case)
    for r in rows:
        assert {k: r[k] for k in DETERMINISTIC} == {k: by_case[r["case"]][k] for k in DETERMINISTIC}


def test_workers_and_a_scheduler_are_alternatives(tmp_path):
    with pytest.raises(InputError, match="workers"):
        lf.sweep(spec(tmp_path, "1"), str(tmp_path / "r.csv"), scheduler="tcp://127.0.0.1:8786", workers=2)


def test_a_case_past_its_timeout_is_a_row_and_the_sweep_goes_on(tmp_path):
    """A timeout shorter than any run: every case killed in its child, recorded as such."""
    out = tmp_path / "r.csv"
    rows = lf.sweep(spec(tmp_path, "1"), str(out), workers=1, timeout=0.05)
    assert [r["status"] for r in rows] == ["timeout", "timeout"]
    assert all("timeout of 0.05 s" in r["error"] for r in rows)
    with open(out, newline="") as fh:
        assert len(list(csv.reader(fh))) == 3



PARALLEL_KERNEL = """
import numba


@numba.njit(parallel=True, cache=True)
def total(x):
    t = 0.0
    for i in numba.prange(x.size):
        t += x[i]
    return t
"""

WORKER_THREADS = """
import os
import sys

import numba
import numpy as np

# a worker process imports numba (its parent's main module) before its environment is set
os.environ["NUMBA_NUM_THREADS"] = str(numba.config.NUMBA_NUM_THREADS + 1)
from lie_factors.sweeps.cases import fork_safe_threads

fork_safe_threads()
sys.path.insert(0, sys.argv[1])
from kernel import total

total(np.ones(64))  # loaded from numba's cache, no compile: the threads start


@numba.njit
def later(x):  # a compile after they started re-reads the environment
    return x + 1


later(1)
print(numba.config.NUMBA_NUM_THREADS, os.environ["NUMBA_NUM_THREADS"])
"""


def test_a_case_takes_the_thread_count_the_environment_set_after_numba_was_imported(tmp_path):
    """A sweep's worker gets NUMBA_NUM_THREADS after its parent's main module imported numba: the
    case's threads start with the environment's count, so a later compile does not refuse it."""
    (tmp_path / "kernel.py").write_text(PARALLEL_KERNEL)
    child = {k: v for k, v in env().items() if k != "NUMBA_NUM_THREADS"}
    child["NUMBA_CACHE_DIR"] = str(tmp_path / "cache")
    fill = "import sys, numpy as np; sys.path.insert(0, sys.argv[1]); from kernel import total; total(np.ones(64))"
    subprocess.run([sys.executable, "-c", fill, str(tmp_path)], env=child, check=True, timeout=300)
    done = subprocess.run([sys.executable, "-c", WORKER_THREADS, str(tmp_path)], env=child, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    configured, environment = done.stdout.split()
    assert configured == environment
