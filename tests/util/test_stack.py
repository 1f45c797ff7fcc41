"""lie_factors.util.stack, and both backends on a 100k-pose SE(3) chain (GTSAM's recursion needs > 8 MiB of stack)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import pytest

from lie_factors.util import stack

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")


def test_call_returns_and_runs_on_a_large_stack_thread():
    seen = {}

    def f(a, b=0):
        seen["thread"] = threading.current_thread()
        return a + b

    assert stack.call(f, 1, b=2) == 3
    assert seen["thread"] is not threading.current_thread()
    assert seen["thread"].name == "lie_factors-large-stack"


def test_nested_calls_run_inline():
    outer = {}

    def inner():
        return threading.current_thread()

    def f():
        outer["thread"] = threading.current_thread()
        return stack.call(inner)

    assert stack.call(f) is outer["thread"]


@pytest.mark.parametrize("exc", [ValueError("bad"), KeyboardInterrupt(), SystemExit(3)])
def test_exceptions_propagate(exc):
    def f():
        raise exc

    with pytest.raises(type(exc)) as info:
        stack.call(f)
    assert info.value is exc
    assert threading.stack_size() == 0  # the process-wide default is restored


@pytest.mark.parametrize("through_stack", [True, False])
def test_deep_c_recursion_needs_the_large_stack(through_stack):
    """Comparing two 300000-deep nested lists recurses in C: SIGSEGV on the main thread's 8 MiB, fine through call."""
    code = (
        "import sys; sys.setrecursionlimit(10**7);"
        "from lie_factors.util import stack;"
        "x = []; y = []\nfor _ in range(300000): x = [x]; y = [y]\n"
        "f = lambda: x == y;"
        f"print(stack.call(f) if {through_stack} else f())"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    if through_stack:
        assert out.returncode == 0, out.stderr[-500:]
        assert out.stdout.strip() == "True"
    else:  # the cause, shown: without the worker thread the same call overflows the stack
        assert out.returncode != 0


@pytest.fixture(scope="module")
def chain100k(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("chain") / "chain100k.g2o")
    subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "generate_posegraph.py"),
                    "--poses", "100000", "--closure-every", "0", "--output", path], check=True,
                   capture_output=True)
    return path


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["native", "batch"])
def test_100k_pose_chain_completes(chain100k, backend):
    """Used to die with SIGSEGV in GTSAM's InitializePose3 and LM (elimination recursing over the chain)."""
    out = subprocess.run([sys.executable, "-m", "lie_factors.app.cli", "posegraph", chain100k, "--backend", backend,
                          "--json", "--quiet"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    rec = json.loads(out.stdout.strip().splitlines()[-1])
    assert rec["poses"] == 100000 and rec["factors"] == 100000
    assert rec["converged"] and rec["final_error"] < 1e-6


def test_platform_without_settable_stack_runs_inline(monkeypatch):
    def refuse(size=None):
        raise ValueError("size not valid")

    monkeypatch.setattr(threading, "stack_size", refuse)
    assert stack.call(threading.current_thread) is threading.current_thread()
