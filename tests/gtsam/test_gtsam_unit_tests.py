"""GTSAM's own unit tests as the client: every one that passes as shipped passes with our classes swapped in.

The gtsam wheel ships its Python unit tests in ``gtsam/tests``.  Those that name
anything lie_factors.dropin replaces (``dropin.REPLACED``: our factors, the
optimizer drop-ins, compat's functions and classes; :func:`selected`) are run
by ``run_gtsam_tests.py`` three ways (``gtsam_swap.py``): as shipped, with
their import lines changed to ``lie_factors.dropin``, and with our names
assigned into ``gtsam``'s namespace before they run.  Each way runs in a
process of its own (assignment changes the ``gtsam`` module); the three run at
the same time.

What it guards: a drop-in that calls GTSAM's class through the ``gtsam``
namespace calls itself once assigned there (RecursionError); a drop-in that
refuses what GTSAM's optimizer accepts (a custom ordering in the params, an
iterative linear solver); GTSAM's Python utilities keyed by GTSAM's classes
(``gtsam.utils.logging_optimizer``); GTSAM functions and classes that pick
factors by their C++ class (fastSync, ShonanAveraging from a list of factors)
or return GTSAM's (``parse3DFactors``).

The runs are marked slow (with ours, most of their time is starting lie_factors).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import gtsam
import pytest

import lie_factors.dropin as dropin

TESTS = os.path.join(os.path.dirname(gtsam.__file__), "tests")
RUNNER = os.path.join(os.path.dirname(__file__), "..", "support", "run_gtsam_tests.py")


def selected() -> list[str]:
    """The test files of the wheel that name (as a whole word) anything lie_factors.dropin replaces."""
    names = re.compile(r"\b(?:" + "|".join(map(re.escape, sorted(dropin.REPLACED))) + r")\b")
    out = []
    for name in sorted(os.listdir(TESTS)):
        if name.startswith("test_") and name.endswith(".py"):
            with open(os.path.join(TESTS, name)) as fh:
                if names.search(fh.read()):
                    out.append(name)
    return out


FILES = selected()


def test_selection_holds_the_tests_of_what_we_replace():
    # One file at least for each kind of name replaced; and the totals.
    for name in ("test_ISAM2.py", "test_FixedLagSmootherAccessors.py",  # ISAM2, IncrementalFixedLagSmoother
                 "test_NonlinearOptimizer.py", "test_logging_optimizer.py",  # LM, GN, Dogleg
                 "test_dataset.py", "test_lago.py", "test_initialize_pose3.py",  # compat
                 "test_fast_sync.py", "test_ShonanAveraging.py", "test_PriorFactor.py"):
        assert name in FILES
    assert len(FILES) >= 30


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory):
    """``{mode: {file: {test id: [outcome, traceback]}}}`` of the selected files, run each way."""
    where = tmp_path_factory.mktemp("gtsam_tests")
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    procs = {mode: subprocess.Popen([sys.executable, RUNNER, mode, str(where / f"{mode}.json"), *FILES],
                                    cwd=where, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    text=True)
             for mode in ("original", "swapped", "assigned")}
    out = {}
    for mode, proc in procs.items():
        log, _ = proc.communicate(timeout=600)
        assert proc.returncode == 0, f"the {mode} runner failed:\n{log[-3000:]}"
        out[mode] = json.loads((where / f"{mode}.json").read_text())
    return out


@pytest.mark.slow
def test_files_run_as_shipped(outcomes):
    original = outcomes["original"]
    assert set(original) == set(FILES)
    for name, tests in original.items():
        assert "<module>" not in tests, f"{name} does not run as shipped:\n{tests['<module>'][1]}"
        assert tests, f"{name}: no test found"
        cannot = [t for t, (_, text) in tests.items() if "unittest cannot run it" in text]
        assert not cannot, f"{name}: tests the runner cannot run: {cannot}"
    passed = sum(o == "passed" for tests in original.values() for o, _ in tests.values())
    assert passed >= 150


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["swapped", "assigned"])
@pytest.mark.parametrize("name", FILES)
def test_what_passes_as_shipped_passes_with_ours(name, mode, outcomes):
    original, ours = outcomes["original"][name], outcomes[mode][name]
    failures = {t: ours.get(t, ["not run", ""]) for t, (o, _) in original.items()
                if o == "passed" and ours.get(t, ["not run"])[0] != "passed"}
    assert not failures, "\n".join(f"{t}: {o}\n{text}" for t, (o, text) in failures.items())
