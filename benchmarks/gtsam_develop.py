"""The test suite against GTSAM's development wheel, ``gtsam-develop``, in a fresh virtual environment.

``gtsam-develop`` installs the same ``gtsam`` module as ``gtsam`` under another
distribution name, so ``pip install -e .`` after it would pull gtsam 4.3.0 over
it (this package depends on ``gtsam``).  Here, as ``docs/installing.md`` says:

1. a virtual environment is created (``--venv DIR``, else under a temporary
   directory removed afterwards);
2. ``gtsam-develop`` (``>=4.3.2.dev0``: it has development releases only, and
   a specifier naming one lets pip take them for it alone) and the other
   dependencies of ``pyproject.toml`` and its ``test`` extra are installed;
3. this checkout is installed with ``--no-deps -e``;
4. the environment is checked to load ``gtsam`` from ``gtsam-develop`` and to
   have no ``gtsam`` distribution;
5. ``python -m pytest -q -m "not slow"`` runs there, from the checkout, with the
   numba cache in the environment (the checkout's ``__pycache__`` is left alone).

    python benchmarks/gtsam_develop.py [--venv DIR] [--python PYTHON] [-- PYTEST_ARGS ...]

Prints the gtsam distribution and version loaded and pytest's summary line;
the exit status is non-zero if any step fails (a failing pip step prints pip's
output).  Network and CPU heavy: run it alone.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEVELOP = "gtsam-develop>=4.3.2.dev0"

#: prints the distribution that provides the imported ``gtsam`` module, its version and file
WHICH_GTSAM = """
import importlib.metadata as m, gtsam
dists = m.packages_distributions().get("gtsam", [])
print(" ".join(f"{d}=={m.version(d)}" for d in dists), gtsam.__file__)
"""


def requirements() -> list[str]:
    """pyproject.toml's dependencies and its ``test`` extra, with ``gtsam-develop`` for ``gtsam``
    (a development release: pip takes them only where the specifier names one)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    out = []
    for req in [*project["dependencies"], *project["optional-dependencies"]["test"]]:
        name = re.match(r"[A-Za-z0-9_.-]+", req)[0]
        out.append(DEVELOP if name.lower() == "gtsam" else req)
    return out


def run(step: str, cmd: list[str], **kwargs) -> subprocess.CompletedProcess:
    print(f"== {step}: {' '.join(cmd)}", flush=True)
    proc = subprocess.run(cmd, capture_output=True, text=True, **kwargs)
    if proc.returncode != 0:
        print(proc.stdout[-4000:], proc.stderr[-4000:], sep="\n", file=sys.stderr)
        raise SystemExit(f"{step} failed (exit status {proc.returncode})")
    return proc


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--venv", help="the environment's directory (created if missing; kept)")
    parser.add_argument("--python", default=sys.executable, help="interpreter to create it with")
    parser.add_argument("pytest_args", nargs="*", help="after --: extra arguments for pytest")
    args = parser.parse_args()

    temporary = None
    if args.venv is None:
        temporary = tempfile.mkdtemp(prefix="gtsam-develop-")
        venv = Path(temporary) / "venv"
    else:
        venv = Path(args.venv).resolve()
    python = str(venv / ("Scripts" if os.name == "nt" else "bin") / "python")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env["NUMBA_CACHE_DIR"] = str(venv / "numba-cache")
    try:
        if not Path(python).exists():
            run("venv", [args.python, "-m", "venv", str(venv)])
        run("pip install", [python, "-m", "pip", "install", *requirements()], env=env)
        run("pip install this checkout", [python, "-m", "pip", "install", "--no-deps", "-e", str(ROOT)], env=env)
        which = run("gtsam", [python, "-c", WHICH_GTSAM], env=env, cwd=venv).stdout.strip()
        print(f"gtsam loaded: {which}", flush=True)
        if not which.startswith("gtsam-develop==") or " gtsam==" in f" {which}":
            raise SystemExit(f"gtsam is not gtsam-develop's alone: {which}")
        cmd = [python, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-m", "not slow", *args.pytest_args]
        print(f"== pytest: {' '.join(cmd)}", flush=True)
        proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        lines = proc.stdout.strip().splitlines()
        failures = [line for line in lines if line.startswith(("FAILED", "ERROR"))]
        print("\n".join(failures))
        print(f"gtsam: {which}")
        print(f"pytest: {lines[-1] if lines else proc.stderr.strip()[-2000:]}")
        return proc.returncode
    finally:
        if temporary is not None:
            shutil.rmtree(temporary, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
