"""GTSAM's own Python examples as the client: run with our factors, they print GTSAM's numbers.

Each example shipped in the gtsam wheel that builds Pose2/Pose3/Rot3 Between or
Prior factors (directly, or through GTSAM's readers) is run three ways by
``run_gtsam_example.py`` (``gtsam_swap.py``): as shipped, with only its import
lines changed to ``lie_factors.dropin``, and as shipped with our names assigned
into ``gtsam``'s namespace first.  Examples that build none of these
(IMUKittiExampleGPS, SFM, view-graph, EqF ...) are not run.  Every number
printed (and plotted, and written to a file) must agree to 1e-9, relative
where larger than 1.

Our factors, and graphs holding them, print what GTSAM's print (their keys,
measured value and noise model), so printed graphs are compared as they are;
the LAGO example, whose numbers are all GTSAM's (its initializer runs on
GTSAM's factors, :mod:`lie_factors.optimizers.compat`), must print exactly the
same text.  What may differ elsewhere, and is normalised before comparing:

* The last three columns of Levenberg–Marquardt's SUMMARY table are timings.
* Eigen and numpy pad printed matrices to the widest entry: whitespace is not compared.
* A number printed to different digits on the two sides agrees to the coarser
  side's last digit (GTSAM's C++ LM leaves std::cout at precision 2 after its
  SUMMARY table for the rest of the example; a Python drop-in LM does not, so
  its later prints carry more digits).  Numbers printed alike are held to 1e-9.

Time: one process per mode runs the cases (starting Python, gtsam,
matplotlib and our kernels is most of an example's time; the two LM-SUMMARY
examples get processes of their own); the three modes run at the same time
where there are three cores for them, else one after another.  Its example
runs are marked slow.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass, field

import gtsam
import pytest

EXAMPLES = os.path.join(os.path.dirname(gtsam.__file__), "examples")
RUNNER = os.path.join(os.path.dirname(__file__), "..", "support", "run_gtsam_example.py")
TOL = 1e-9


@dataclass(frozen=True)
class Case:
    name: str
    args: tuple[str, ...] = ()
    #: classes of lie_factors.factors the swapped run must construct
    ours: frozenset = field(default_factory=frozenset)
    #: run in a process of its own: GTSAM's C++ LM with SUMMARY verbosity
    #: leaves std::cout at precision 2 for the rest of the process, which would
    #: leak into the next examples' prints (and only in the mode whose LM is GTSAM's).
    own_process: bool = False

    @property
    def id(self) -> str:
        return self.name + ("[" + " ".join(self.args) + "]" if self.args else "")


P2 = frozenset({"BetweenFactorPose2", "PriorFactorPose2"})
P3 = frozenset({"BetweenFactorPose3", "PriorFactorPose3"})

CASES = [
    Case("Pose2ISAM2Example", ours=P2),
    Case("Pose3ISAM2Example", ours=P3),
    Case("VisualISAM2Example", ours=frozenset({"PriorFactorPose3"})),
    # readG2o, Gauss-Newton, prints the graph and the values
    Case("Pose2SLAMExample_g2o", ours=P2),
    Case("Pose3SLAMExample_g2o", ours=P3),
    Case("Pose3SLAMExample_g2o", ("-o", "result.g2o"), ours=P3),  # writeG2o
    Case("Pose2SLAMExample_lago", ours=P2),  # lago.initialize
    Case("Pose2SLAMExample_lago", ("-o", "result.g2o"), ours=P2),
    Case("Pose3SLAMExample_initializePose3Chordal", ours=P3),  # InitializePose3
    # 4 s of simulated navigation instead of 12 (the time goes into plotting)
    # and the covariances, so Marginals runs on a graph with our priors.
    Case("ImuFactorExample", ("-T", "4", "--compute_covariances"),
         ours=frozenset({"PriorFactorPose3"}), own_process=True),
    # (its --compute_covariances fails as shipped: NameError BIAS_KEY)
    Case("CombinedImuFactorExample", ("-T", "4"), ours=frozenset({"PriorFactorPose3"}),
         own_process=True),
    # prints nothing: its plotted estimates are compared
    Case("ImuFactorISAM2Example", ours=frozenset({"PriorFactorPose3"})),
    # A module, driven by run_gtsam_example.DRIVERS: writeG2o with landmark
    # factors (GTSAM's BearingRangeFactor3D) beside our BetweenFactorPose3.
    Case("LandmarkLocalizationDataset", ours=frozenset({"BetweenFactorPose3"})),
    # Its factors come from parse3DFactors (ours return our factors) and serve only
    # to recover the translations; its writeG2o of the result is ours.
    Case("ShonanAveragingCLI", ours=frozenset({"BetweenFactorPose3"})),
]

#: shipped examples that build Between/Prior factors on Rot3/Pose2/Pose3/Similarity2/3
#: (or read them with one of GTSAM's readers) and are not run here, with the reason.
NOT_RUN: dict[str, str] = {}

_BUILDS_OURS = re.compile(
    r"\b(?:BetweenFactor|PriorFactor)(?:Rot3|Pose2|Pose3|Similarity2|Similarity3)\b(?!s)"
    r"|\b(?:readG2o|load2D|load3D|parse2DFactors|parse3DFactors)\b")


def test_every_example_building_our_factor_types_is_run():
    shipped = {f[:-3] for f in os.listdir(EXAMPLES) if f.endswith(".py")}
    builds = set()
    for name in shipped:
        with open(os.path.join(EXAMPLES, name + ".py")) as fh:
            if _BUILDS_OURS.search(fh.read()):
                builds.add(name)
    covered = {c.name for c in CASES} | set(NOT_RUN)
    assert builds - covered == set()
    assert {"Pose2ISAM2Example", "Pose3ISAM2Example", "VisualISAM2Example",
            "Pose3SLAMExample_initializePose3Chordal", "Pose2SLAMExample_lago",
            "Pose2SLAMExample_g2o", "Pose3SLAMExample_g2o"} <= builds


# --------------------------------------------------------------------------- #
# Comparing outputs
# --------------------------------------------------------------------------- #

_NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?|\b[-+]?(?:nan|inf)\b")
#: LM's SUMMARY table: GTSAM 4.3's timing columns, or the single iter_time of earlier versions
_LM_HEADER = re.compile(r"^\s*iter\s+cost\s+cost_change\s+lambda\s+success\s+"
                        r"(?:lin_time\s+solve_time\s+total_time|iter_time)\s*$")


def _without_lm_timings(text: str) -> str:
    out, in_table, width = [], False, 0
    for line in text.split("\n"):
        fields = line.split()
        if _LM_HEADER.search(line):
            in_table, width = True, len(fields)
            line = " ".join(fields[:5])
        elif in_table and len(fields) == width and fields[0].isdigit():
            line = " ".join(fields[:5])
        else:
            in_table = False
        out.append(line)
    return "\n".join(out)


def _text(piece: str) -> str:
    # Eigen and numpy pad to the widest entry (a sign adds a blank), so
    # whitespace between numbers is not compared; everything else is.
    return re.sub(r"\s+", "", piece)


def _resolution(token: str) -> float | None:
    """Half a unit in the last digit printed (None for nan/inf)."""
    m = re.fullmatch(r"[-+]?(\d*)(?:\.(\d*))?(?:[eE]([-+]?\d+))?", token)
    if m is None:
        return None
    return 0.5 * 10.0 ** (int(m[3] or 0) - len(m[2] or ""))


def _tolerance(ta: str, tb: str, x: float, y: float) -> float:
    """TOL, relative above 1; for two numbers printed to different digits, the coarser one's.

    The same value printed to fewer digits on one side (GTSAM's C++ LM leaves
    std::cout at precision 2 after its SUMMARY table, a Python drop-in does
    not) agrees only to the digits printed.  Numbers printed alike are held
    to TOL.
    """
    tol = TOL * max(1.0, abs(x), abs(y))
    ra, rb = _resolution(ta), _resolution(tb)
    if ra is not None and rb is not None and ra != rb:
        tol = max(tol, ra, rb)
    return tol


def compare_outputs(original: str, swapped: str) -> None:
    """Same text apart from numbers; every number within :func:`_tolerance` (TOL, relative above 1)."""
    a = _without_lm_timings(original)
    b = _without_lm_timings(swapped)
    text_a = [_text(t) for t in _NUMBER.split(a)]
    text_b = [_text(t) for t in _NUMBER.split(b)]
    tokens_a, tokens_b = _NUMBER.findall(a), _NUMBER.findall(b)
    nums_a = [float(x) for x in tokens_a]
    nums_b = [float(x) for x in tokens_b]
    assert len(nums_a) == len(nums_b), "the outputs print different numbers of numbers"
    for k, (x, y) in enumerate(zip(text_a, text_b)):
        assert x == y, f"text differs before number {k}: {x!r} vs {y!r}"
    for k, (x, y) in enumerate(zip(nums_a, nums_b)):
        if x == y:  # also inf == inf
            continue
        tol = _tolerance(tokens_a[k], tokens_b[k], x, y)
        if not abs(x - y) <= tol:  # NaN on one side only lands here too
            context = "".join(text_a[max(0, k - 3):k + 1])[-200:]
            raise AssertionError(f"number {k} differs: {tokens_a[k]} vs {tokens_b[k]} "
                                 f"(|diff| {abs(x - y):.3g} > {tol:.3g}) after ...{context!r}")


def test_compare_outputs_catches_differences():
    base = "x = 1.0000000000\ny = 2500.0000000\n"
    compare_outputs(base, "x = 1.0000000009\ny = 2500.0000024\n")  # 1e-9 absolute, relative above 1
    with pytest.raises(AssertionError, match="number 1 differs"):
        compare_outputs(base, "x = 1.0000000000\ny = 2500.0000026\n")
    with pytest.raises(AssertionError, match="number 0 differs"):
        compare_outputs(base, "x = 1.0000000011\ny = 2500.0000000\n")
    with pytest.raises(AssertionError, match="text differs"):
        compare_outputs(base, "x = 1.0000000000\nz = 2500.0000000\n")
    with pytest.raises(AssertionError, match="numbers of numbers"):
        compare_outputs(base, base + "7")
    with pytest.raises(AssertionError, match="differs"):
        compare_outputs("v = 1\n", "v = nan\n")
    # A factor printed as CustomFactor (no measured value) is not GTSAM's print.
    gtsam_print = ("Factor 0: BetweenFactor(0,1)\n  measured:  (1, 2, 0.3)\n  noise model: unit (3) \n"
                   "Factor 1: PriorFactor on 0\n  prior mean:  (0, 0, 0)\n  noise model: unit (3) \n")
    custom_print = ("Factor 0: CustomFactor on 0, 1\n  noise model: unit (3) \n"
                    "Factor 1: CustomFactor on 0\n  noise model: unit (3) \n")
    with pytest.raises(AssertionError):
        compare_outputs(gtsam_print, custom_print)
    # LM's timing columns are ignored, its cost columns are not.
    table = ("iter      cost      cost_change    lambda  success lin_time  solve_time total_time\n"
             "   0  3.45506e+06      2.1e+08      1e-05      1    0.00066     0.0013     0.0021\n")
    compare_outputs(table, table.replace("0.0013", "0.0034"))
    with pytest.raises(AssertionError):
        compare_outputs(table, table.replace("3.45506e+06", "3.45507e+06"))
    old_table = ("iter      cost      cost_change    lambda  success iter_time\n"
                 "   0  3.45506e+06      2.1e+08      1e-05      1    0.0087\n")
    compare_outputs(table, old_table)
    with pytest.raises(AssertionError):
        compare_outputs(table, old_table.replace("1e-05", "1e-06"))
    # Printed to different digits: agreement to the coarser side's digits ...
    compare_outputs("p: 0.87 -0.13\n", "p: 0.869072 -0.130928\n")
    compare_outputs("e: 57533.1\n", "e: 57533.1165348969\n")
    with pytest.raises(AssertionError, match=r"0.87 vs 0.859072"):
        compare_outputs("p: 0.87\n", "p: 0.859072\n")
    # ... printed alike: TOL, whatever the digits.
    with pytest.raises(AssertionError, match=r"0.869072 vs 0.869073"):
        compare_outputs("p: 0.869072\n", "p: 0.869073\n")


# --------------------------------------------------------------------------- #
# The examples
# --------------------------------------------------------------------------- #

#: cores this process may run on: the modes' runners run at the same time only where each has one
CORES = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Every case run each way: ``{mode: directory}`` (see run_gtsam_example.py for its layout).

    One runner process per mode runs the cases that share a process, then one
    per mode for each ``own_process`` case; the three modes run at the same time
    where there are three cores (:data:`CORES`), one after another otherwise.
    """
    shared = [[i, c.name, list(c.args)] for i, c in enumerate(CASES) if not c.own_process]
    groups = [shared] + [[[i, c.name, list(c.args)]] for i, c in enumerate(CASES) if c.own_process]
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    dirs = {mode: tmp_path_factory.mktemp(mode) for mode in ("original", "swapped", "assigned")}
    batches = [list(dirs)] if CORES >= len(dirs) else [[mode] for mode in dirs]
    for group in groups:
        for batch in batches:
            procs = {mode: subprocess.Popen([sys.executable, RUNNER, mode, str(dirs[mode]), json.dumps(group)],
                                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
                     for mode in batch}
            for mode, proc in procs.items():
                out, _ = proc.communicate(timeout=600)
                assert proc.returncode == 0, f"the {mode} runner failed:\n{out[-3000:]}"
    return dirs


def _result(runs, case: Case, mode: str) -> tuple[str, dict]:
    where = runs[mode] / str(CASES.index(case))
    error = where / "error"
    assert not error.exists(), f"{case.id} ({mode}) raised:\n{error.read_text()[-3000:]}"
    return (where / "stdout").read_text(), json.loads((where / "made.json").read_text())


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["swapped", "assigned"])
@pytest.mark.parametrize("case", CASES, ids=lambda c: c.id)
def test_example_with_our_factors_prints_gtsams_numbers(case, mode, runs):
    original, _ = _result(runs, case, "original")
    ours, made = _result(runs, case, mode)
    assert set(made) == set(case.ours), f"constructed {made}"
    compare_outputs(original, ours)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["swapped", "assigned"])
@pytest.mark.parametrize("case", [c for c in CASES if c.name == "Pose2SLAMExample_lago"], ids=lambda c: c.id)
def test_lago_example_with_our_factors_prints_gtsams_text(case, mode, runs):
    """``print(graph)`` of our factors (read by our readG2o, and our prior) and GTSAM's LAGO
    estimate: the same text, character for character, as with GTSAM's factors."""
    original, _ = _result(runs, case, "original")
    ours, made = _result(runs, case, mode)
    assert set(made) == set(case.ours), f"constructed {made}"
    assert "BetweenFactor(" in original and "prior mean:" in original
    assert ours == original
