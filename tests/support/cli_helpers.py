"""The ``lie-factors`` command run in the test process: its status and output, its ``--json``
record, its one-line errors (tests/app/test_cli.py, test_incremental.py, test_initialize.py)."""

from __future__ import annotations

import json

from lie_factors.app import cli


def run_main(capsys, *argv) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of ``lie-factors ARGV``."""
    status = cli.main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


def last_json(out: str) -> dict:
    """The ``--json`` record: the last line of stdout."""
    return json.loads(out.strip().splitlines()[-1])


def assert_one_line_error(status, out, err, *fragments):
    """A user error: status 2 and one line ``lie-factors: error: …`` holding every fragment, no
    traceback; before it stderr holds at most the progress lines of the stages done
    (``[elapsed, memory] stage``)."""
    assert status == 2
    lines = err.strip().splitlines()
    assert lines and all(line.startswith("[") and "] " in line for line in lines[:-1]), err
    error = lines[-1]
    assert error.startswith("lie-factors: error: ")
    assert "Traceback" not in err
    for f in fragments:
        assert f in error, error
