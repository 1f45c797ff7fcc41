"""lie_factors.lm: GTSAM's stopping rule, its convergence test and its prints, written once.

The λ schedule is checked iteration by iteration against GTSAM's optimizer in
test_optimizers.py (the drop-in) and test_batch.py (the batch solver).  Here:
``checkConvergence`` and ``defaultOptimize`` against GTSAM's own, C++'s number
format against printf, and the text every optimizer prints at each verbosity
against what GTSAM 4.3's ``LevenbergMarquardtOptimizer`` prints (the SUMMARY
table's timing columns aside).
"""

from __future__ import annotations

import ctypes
import itertools
import math
import os
import re
import subprocess
import sys

import gtsam
import numpy as np
import pytest

from lie_factors import lm

# --------------------------------------------------------------------------- #
# checkConvergence, defaultOptimize, number format
# --------------------------------------------------------------------------- #

_ERRORS = [0.0, 1e-12, 0.5, 1.0, 2.0, 1e6, math.inf, math.nan]


@pytest.mark.parametrize("tols", [(1e-5, 1e-5, 0.0), (0.0, 1e-5, 0.0), (1e-5, 0.0, 0.6), (0.0, 0.0, 0.0),
                                  (1e-3, -1.0, -1.0)])
def test_check_convergence_is_gtsams(tols):
    for current, new in itertools.product(_ERRORS, repeat=2):
        expected = gtsam.checkConvergence(*tols, current, new)
        assert lm.check_convergence(*tols, current, new) == expected, (tols, current, new)


_libc = ctypes.CDLL(None)


def _printf(width: int, precision: int, x: float) -> str:
    buf = ctypes.create_string_buffer(64)
    _libc.snprintf(buf, 64, b"%*.*g", ctypes.c_int(width), ctypes.c_int(precision), ctypes.c_double(x))
    return buf.value.decode()


def test_numbers_print_as_cpp_streams_do():
    cout = lm._Cout()
    values = [0.0, -0.0, 1.0, 38.5445750082, 0.740455208811, 1e-5, 1.5e-5, -1.1e-12, 123456789.0,
              9.99999e5, 999999.5, 1e300, 5e-324, math.inf, -math.inf, math.nan, -math.nan]
    for precision, width, x in itertools.product((2, 6, 12, 15), (0, 10, 12), values):
        assert cout.num(x, width, precision) == _printf(width, precision, x), (precision, width, x)
    # setprecision stays in force, as on std::cout
    cout.num(1.0, precision=2)
    assert cout.num(0.740455208811) == "0.74"


def _pose2_problem():
    native, initial = gtsam.load2D(gtsam.findExampleDataFile("w100.graph"))
    graph = gtsam.NonlinearFactorGraph(native)
    graph.add(gtsam.PriorFactorPose2(0, initial.atPose2(0), gtsam.noiseModel.Diagonal.Sigmas(
        np.array([1e-3, 1e-3, 1e-4]))))
    return graph, initial


@pytest.mark.parametrize("settings", [{}, {"MaxIterations": 0}, {"MaxIterations": 1}, {"MaxIterations": 2},
                                      {"ErrorTol": 1e6}, {"RelativeErrorTol": 0.0, "AbsoluteErrorTol": 0.0},
                                      {"AbsoluteErrorTol": 0.1}, {"lambdaInitial": 1e3}])
def test_default_optimize_stops_where_gtsams_does(settings):
    graph, initial = _pose2_problem()

    def params(hooks):
        p = gtsam.LevenbergMarquardtParams()
        for name, value in settings.items():
            getattr(p, "set" + name)(value)
        p.iterationHook = lambda i, before, after: hooks.append((i, before, after))
        return p

    ref_hooks, our_hooks = [], []
    ref = gtsam.LevenbergMarquardtOptimizer(graph, initial, params(ref_hooks))
    ref.optimize()
    p = params(our_hooks)
    stepped = gtsam.LevenbergMarquardtOptimizer(graph, initial, p)
    seen = []
    result = lm.default_optimize(stepped, p, seen.append)
    assert result.iterations == stepped.iterations() == ref.iterations()
    assert our_hooks == ref_hooks  # the same iterations, bit for bit: it is GTSAM's own optimizer
    assert len(result.history) == len(our_hooks)  # one per iterate() (the last may accept no step)
    assert seen == result.history
    assert result.errors == [initial_error := graph.error(initial)] + [h[2] for h in our_hooks]
    assert result.initial_error == initial_error and result.final_error == stepped.error()
    assert result.lambdas[1:] == [info.lambda_ for info in result.history]
    assert result.inner_iterations == 0  # GTSAM's Python wrapper does not say how many λ it tried
    last = our_hooks[-1] if our_hooks else (0, initial_error, initial_error)
    expected = (initial_error <= p.getErrorTol() if not our_hooks
                else gtsam.checkConvergence(p, last[1], last[2]))
    assert result.converged == expected


# --------------------------------------------------------------------------- #
# What every optimizer prints, against GTSAM's own
# --------------------------------------------------------------------------- #

#: One process per optimizer runs every case in order (C++'s std::cout precision carries
#: from one print to the next, and from one case to the next, in GTSAM as here).
SCRIPT = r'''
import os, sys
import gtsam
import numpy as np

mode, outdir = sys.argv[1], sys.argv[2]
from lie_factors import factors as ours

# w100's factors as ours (exact Jacobians, where GTSAM's Pose2 BetweenFactor loses digits at small
# angles), for every optimizer: the prints compare the same arithmetic
native, initial = gtsam.load2D(gtsam.findExampleDataFile("w100.graph"))
graph = gtsam.NonlinearFactorGraph()
for i in range(native.size()):
    f = native.at(i)
    graph.add(ours.BetweenFactorPose2(f.keys()[0], f.keys()[1], f.measured(), f.noiseModel()))
graph.add(ours.PriorFactorPose2(0, initial.atPose2(0), gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))))


def uphill(this, values, H):
    # The Jacobian's sign is wrong: every step goes uphill, λ grows until LM gives up.
    if H is not None:
        H[0] = -np.eye(1)
    return values.atVector(this.keys()[0]) - 1.0


wrong = gtsam.NonlinearFactorGraph()
wrong.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [7], uphill))
wrong_initial = gtsam.Values()
wrong_initial.insert(7, np.array([3.0]))


def lm(verbosity_lm, verbosity, **settings):
    p = gtsam.LevenbergMarquardtParams()
    p.setVerbosityLM(verbosity_lm)
    p.setVerbosity(verbosity)
    for name, value in settings.items():
        getattr(p, "set" + name)(value)
    return p


def gn(verbosity):
    p = gtsam.GaussNewtonParams()
    p.setVerbosity(verbosity)
    return p


CASES = [
    (graph, initial, lm("SUMMARY", "SILENT")),
    (graph, initial, lm("TRYLAMBDA", "ERROR", DiagonalDamping=True)),
    (graph, initial, lm("DAMPED", "TERMINATION", MaxIterations=2)),
    (wrong, wrong_initial, lm("SUMMARY", "TERMINATION", lambdaUpperBound=10.0,
                              LogFile=os.path.join(outdir, mode + ".log"))),
    (wrong, wrong_initial, lm("TRYLAMBDA", "SILENT", lambdaUpperBound=10.0, UseFixedLambdaFactor=False)),
    (graph, initial, lm("SILENT", "VALUES", MaxIterations=1)),
    (graph, initial, lm("SUMMARY", "VALUES", MaxIterations=1)),
    (graph, initial, lm("TRYDELTA", "SILENT", MaxIterations=1)),
    (graph, initial, lm("SILENT", "ERROR", ErrorTol=1e6)),
    (graph, initial, lm("SILENT", "TERMINATION", MaxIterations=0)),
    (graph, initial, lm("SUMMARY", "ERROR")),
    (graph, initial, gn("ERROR")),
]
for k, (g, values, params) in enumerate(CASES):
    print(f"--- case {k}", flush=True)
    is_lm = isinstance(params, gtsam.LevenbergMarquardtParams)
    if mode in ("gtsam", "stepped"):
        opt = (gtsam.LevenbergMarquardtOptimizer if is_lm else gtsam.GaussNewtonOptimizer)(g, values, params)
        if mode == "gtsam":
            opt.optimize()
        else:
            from lie_factors.lm import default_optimize
            default_optimize(opt, params)
    elif mode == "dropin":
        from lie_factors import optimizers
        cls = optimizers.LevenbergMarquardtOptimizer if is_lm else optimizers.GaussNewtonOptimizer
        cls(g, values, params).optimize()
    else:
        from lie_factors import batch
        batch.BatchLevenbergMarquardt(g, values, params, linear_solver="gtsam").optimize()
'''

#: ours (mode) → relative tolerance of its numbers against GTSAM's: the drop-in and GTSAM's
#: own optimizer stepped from Python compute with GTSAM; the batch solver solves its own
#: normal equations (rounding, amplified in the model fidelity of the last tiny steps).
MODES = {"stepped": 1e-12, "dropin": 1e-9, "batch": 1e-6}

_NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?|[-+]?\b(?:nan|inf)\b")
_ROW = re.compile(r"^(\s*\d+\s+\S+\s+\S+\s+\S+\s+\d+)(?:\s+\S+){3}$")


def _without_timings(text: str) -> list[str]:
    """Lines, with the SUMMARY table's three timing columns cut off its rows (which other
    prints may separate, once its header has been printed)."""
    out, table = [], False
    for line in text.splitlines():
        if line == lm.SUMMARY_HEADER:
            table = True
        elif table and (m := _ROW.match(line)):
            line = m[1]
        out.append(line)
    return out


def _digits(token: str) -> str:
    mantissa = re.split(r"[eE]", token)[0]
    return re.sub(r"\D", "", mantissa).lstrip("0") or "0"


def _significant_digits(token: str) -> int:
    return len(_digits(token))


def _same_precision(ta: str, tb: str) -> bool:
    """Whether two tokens of close values were printed at one precision: as many significant
    digits, ± 1, or the longer one's extra digits a run of zeros (or nines) but its last, which
    the shorter one's value rounded to and %g dropped (…188 against …18801)."""
    a, b = sorted((_digits(ta), _digits(tb)), key=len)
    if len(b) - len(a) <= 1:
        return True
    extra = b[len(a):-1]
    return set(extra) <= {"0"} or set(extra) <= {"9"}


def _half_unit(token: str) -> float:
    m = re.fullmatch(r"[-+]?(\d*)(?:\.(\d*))?(?:[eE]([-+]?\d+))?", token)
    return 0.5 * 10.0 ** (int(m[3] or 0) - len(m[2] or "")) if m else 0.0


def compare_prints(reference: str, ours: str, rtol: float) -> None:
    """The same lines; where a line differs, only in its numbers: each within ``rtol``
    (or half a unit of its last printed digit), printed to as many significant digits
    (± 1, or fewer where %g dropped the zeros a value rounded to: :func:`_same_precision`), so
    that the precision state is GTSAM's."""
    a_lines, b_lines = _without_timings(reference), _without_timings(ours)
    assert len(a_lines) == len(b_lines), "\n".join(
        f"{x!r:70} | {y!r}" for x, y in itertools.zip_longest(a_lines, b_lines))
    for n, (a, b) in enumerate(zip(a_lines, b_lines)):
        if a == b:
            continue
        where = f"line {n + 1}: {a!r} vs {b!r}"
        assert [" ".join(t.split()) for t in _NUMBER.split(a)] == [" ".join(t.split()) for t in _NUMBER.split(b)], where
        for ta, tb in zip(_NUMBER.findall(a), _NUMBER.findall(b)):
            if ta == tb:
                continue
            x, y = float(ta), float(tb)
            assert abs(x - y) <= max(rtol * abs(x), _half_unit(ta), _half_unit(tb)), where
            assert _same_precision(ta, tb), where


@pytest.fixture(scope="module")
def prints(tmp_path_factory):
    """mode → (stdout, log file) of :data:`SCRIPT` run by GTSAM and by each of ours."""
    out = tmp_path_factory.mktemp("prints")
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    procs = {mode: subprocess.Popen([sys.executable, "-c", SCRIPT, mode, str(out)], env=env, text=True,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for mode in ("gtsam", *MODES)}
    result = {}
    for mode, proc in procs.items():
        stdout, stderr = proc.communicate(timeout=300)
        assert proc.returncode == 0, f"{mode}:\n{stderr[-3000:]}"
        result[mode] = (stdout, (out / f"{mode}.log").read_text())
    return result


def test_compare_prints_catches_differences():
    table = (f"Initial error: 38.5445750082, values: 100\n{lm.SUMMARY_HEADER}\n"
             "   0 0.740455208811           38      1e-05      1    0.00016     0.0088      0.009\n"
             "   1         0.57         0.17      1e-06      1    0.00017    0.00044    0.00061\n")
    compare_prints(table, table.replace("0.0088", "0.0123"), 1e-12)  # timings are not compared
    compare_prints(table, table.replace("0.740455208811", "0.740455208812"), 1e-9)
    # a value that rounds to …800 at 12 digits prints as …8: the same precision
    compare_prints("x = -0.005098615188\n", "x = -0.00509861518801\n", 1e-9)
    for wrong in ("0.740455209811", "0.740455", "0.74"):  # another value, another precision
        with pytest.raises(AssertionError):
            compare_prints(table, table.replace("0.740455208811", wrong), 1e-9)
    with pytest.raises(AssertionError):
        compare_prints(table, table.replace("0.57", "0.568935494789"), 1e-9)
    with pytest.raises(AssertionError):
        compare_prints(table, table.replace("values:", "values ="), 1e-9)
    with pytest.raises(AssertionError):
        compare_prints(table, table + "iterations: 2 >? 100\n", 1e-9)


@pytest.mark.parametrize("mode", MODES)
def test_prints_are_gtsams(prints, mode):
    reference, ours = prints["gtsam"][0], prints[mode][0]
    assert reference.count("--- case") == 12 and "giving up" in reference and lm.SUMMARY_HEADER in reference
    compare_prints(reference, ours, MODES[mode])


@pytest.mark.parametrize("mode", ["dropin", "batch"])
def test_log_file_is_gtsams(prints, mode):
    """GTSAM's ``writeLogFile``: inner iterations, seconds, error, λ, iterations (seconds not compared)."""
    def rows(text):
        return [line.split(",") for line in text.splitlines()]

    reference, ours = rows(prints["gtsam"][1]), rows(prints[mode][1])
    assert len(reference) == len(ours) > 2
    for a, b in zip(reference, ours):
        assert [a[0], a[4]] == [b[0], b[4]]
        for x, y in ((a[2], b[2]), (a[3], b[3])):
            assert float(y) == pytest.approx(float(x), rel=MODES[mode], abs=_half_unit(x))
            assert _significant_digits(x) == _significant_digits(y)
