"""The modules a user imports type-check: mypy, with ``[tool.mypy]`` of pyproject.toml, reports no error.

lie_factors ships ``py.typed``, so a user's mypy reads our annotations; these
modules' own annotations must hold.  One mypy run checks every file of the
configuration's ``files`` and a probe with a deliberate error (so a
configuration that silenced everything would fail here); each file is one test.
mypy is a test dependency (``pip install -e ".[test]"``): without it the run fails.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "pyproject.toml"
FILES = tomllib.loads(CONFIG.read_text())["tool"]["mypy"]["files"]
PROBE = 'count: int = "not a number"\n'
_LINE = re.compile(r"^(?P<path>[^:\n]+\.py):\d+: error: ", re.M)


@pytest.fixture(scope="module")
def mypy(tmp_path_factory) -> tuple[str, dict[str, list[str]]]:
    """mypy's output over FILES and the probe, and its error lines by file (paths as in FILES)."""
    where = tmp_path_factory.mktemp("mypy")
    probe = where / "typing_probe.py"
    probe.write_text(PROBE)
    proc = subprocess.run(
        [sys.executable, "-m", "mypy", "--config-file", str(CONFIG), "--cache-dir", str(where / "cache"),
         "--no-error-summary", "--hide-error-context", *FILES, str(probe)],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    out = proc.stdout + proc.stderr
    assert "No module named mypy" not in out, "mypy is a test dependency: pip install -e '.[test]'"
    errors: dict[str, list[str]] = {}
    for line in out.splitlines():
        m = _LINE.match(line)
        if m:  # a project file's path is relative to ROOT, as in FILES; the probe's is absolute
            errors.setdefault(m["path"], []).append(line)
    return out, errors


def test_mypy_runs_and_reports_the_probe(mypy):
    out, errors = mypy
    probe = [key for key in errors if key.endswith("typing_probe.py")]
    assert probe and "Incompatible types in assignment" in errors[probe[0]][0], out[-3000:]


@pytest.mark.parametrize("path", FILES)
def test_mypy_reports_no_error(mypy, path):
    out, errors = mypy
    assert (ROOT / path).is_file()
    assert not errors.get(path), "\n".join(errors[path])
