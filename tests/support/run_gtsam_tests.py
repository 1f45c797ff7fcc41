"""Run unit tests shipped in the gtsam wheel (``gtsam/tests``), as GTSAM ships them or with our classes.

    python run_gtsam_tests.py original|swapped|assigned OUT_JSON FILE [FILE ...]

Run by tests/gtsam/test_gtsam_unit_tests.py, one process per mode (``assigned``
changes the ``gtsam`` module for the rest of the process; ``gtsam_swap.py``
describes the modes).  Each ``FILE`` (a name in ``gtsam/tests``) is executed as
a module named for its file, with its own ``__file__`` (tests find data beside
it), after :func:`gtsam_swap.prepare`; its tests are its ``unittest.TestCase``
tests and its module-level ``test_*`` functions (pytest style; one that
takes arguments, fixtures, fails: unittest cannot run it), run by ``unittest``.  Written to ``OUT_JSON``:
``{file: {test id: [outcome, traceback]}}``, outcome one of ``passed``,
``failed``, ``skipped``, ``expected failure``, ``unexpected success``; a file
that cannot be executed has the one test id ``<module>``.
"""

from __future__ import annotations

import inspect
import json
import os
import sys
import traceback
import types
import unittest

import gtsam
import gtsam_swap

TESTS = os.path.join(os.path.dirname(gtsam.__file__), "tests")


class Outcomes(unittest.TestResult):
    """Every test's outcome; a failed subtest fails its test."""

    def __init__(self):
        super().__init__()
        self.outcomes: dict[str, list] = {}

    def _set(self, test, outcome: str, err=None) -> None:
        text = "".join(traceback.format_exception(*err))[-4000:] if err else ""
        if self.outcomes.get(test.id(), ["passed"])[0] == "passed":
            self.outcomes[test.id()] = [outcome, text]

    def addSuccess(self, test):
        self._set(test, "passed")

    def addFailure(self, test, err):
        self._set(test, "failed", err)

    def addError(self, test, err):
        self._set(test, "failed", err)

    def addSkip(self, test, reason):
        self._set(test, "skipped")

    def addExpectedFailure(self, test, err):
        self._set(test, "expected failure")

    def addUnexpectedSuccess(self, test):
        self._set(test, "unexpected success")

    def addSubTest(self, test, subtest, err):
        if err is not None:
            self._set(test, "failed", err)


def load(name: str, mode: str) -> unittest.TestSuite:
    """The tests of ``gtsam/tests/<name>``, executed in ``mode``."""
    path = os.path.join(TESTS, name)
    with open(path) as fh:
        source = gtsam_swap.prepare(mode, fh.read(), name)
    module = types.ModuleType(name[:-3])
    module.__file__ = path
    sys.modules[module.__name__] = module
    exec(compile(source, path, "exec"), module.__dict__)
    suite = unittest.TestLoader().loadTestsFromModule(module)
    for attr, value in vars(module).items():
        if attr.startswith("test") and inspect.isfunction(value) and value.__module__ == module.__name__:
            case = unittest.FunctionTestCase(value if not inspect.signature(value).parameters else _fixtures)
            case.id = lambda attr=attr: f"{module.__name__}.{attr}"
            suite.addTest(case)
    return suite


def _fixtures():
    raise NotImplementedError("a pytest-style test with arguments (fixtures): unittest cannot run it")


def main() -> None:
    mode, out, names = sys.argv[1], sys.argv[2], sys.argv[3:]
    gtsam_swap.start(mode)
    results: dict[str, dict] = {}
    for name in names:
        outcomes = Outcomes()
        try:
            suite = load(name, mode)
        except BaseException:  # noqa: BLE001 - recorded for the test, then the next file
            outcomes.outcomes["<module>"] = ["failed", traceback.format_exc()[-4000:]]
        else:
            suite.run(outcomes)
        results[name] = outcomes.outcomes
    with open(out, "w") as fh:
        json.dump(results, fh, indent=1)


if __name__ == "__main__":
    main()
