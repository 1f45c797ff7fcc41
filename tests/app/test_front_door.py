"""The front door against the command line: every option of ``lie-factors posegraph`` is a keyword of
:func:`lie_factors.optimize` (or :func:`lie_factors.replay`, :func:`lie_factors.write_g2o`), and both give
the same numbers; a GTSAM graph through ``lf.optimize`` reaches GTSAM's optimum; options never
change the caller's params."""

from __future__ import annotations

import argparse
from pathlib import Path

import gtsam
import numpy as np
import pytest

import lie_factors as lf
from lie_factors.app import cli
from support.cli_helpers import last_json, run_main

ROOT = Path(__file__).resolve().parents[2]
INTEL = str(ROOT / "data" / "intel.g2o")

#: Options that change only what the command prints or draws, not what it computes.
PRESENTATION = {"--json", "--quiet", "--plot"}

#: Each option: (the command's extra arguments, the front door's keywords); ``--incremental`` and
#: its ISAM2 parameters go to lf.replay, ``--output`` to lf.write_g2o (a ``.tum`` or ``.kitti`` name to
#: lf.write_trajectory), ``--groundtruth`` to lf.evaluate, ``--covariances`` to lf.write_covariances.
CASES = {
    "--backend": [(["--backend", b], {"backend": b}) for b in cli.BACKENDS],
    "--max-iterations": [(["--max-iterations", "1"], {"max_iterations": 1})],
    "--init": [(["--init", m], {"init": m}) for m in cli.INIT_METHODS],
    "--robust": [(["--robust", "huber:1.345"], {"robust": "huber:1.345"})],
    "--robust-all": [(["--robust", "cauchy", "--robust-all"], {"robust": "cauchy", "robust_all": True})],
    "--gnc": [(["--gnc", g], {"gnc": g}) for g in ("tls", "gm")],
    "--no-consistency": [(["--gnc", "tls", "--no-consistency"], {"gnc": "tls", "consistency": False})],
    "--incremental": [(["--incremental"], {"replay": True})],
    "--relinearize-threshold": [(["--incremental", "--relinearize-threshold", "0.05"],
                                 {"replay": True, "relinearize_threshold": 0.05})],
    "--relinearize-skip": [(["--incremental", "--relinearize-skip", "3"], {"replay": True, "relinearize_skip": 3})],
    "--output": [(["--output", "{out}" + ext], {"output": ext}) for ext in (".g2o", ".tum", ".kitti")],
    "--groundtruth": [(["--groundtruth", "{truth}"], {"groundtruth": True})],
    "--covariances": [(["--covariances", "{out}.npz"], {"covariances": True})],
}


def _posegraph_options() -> set[str]:
    parser, _ = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices["posegraph"]
    return {s for a in sub._actions for s in a.option_strings if s.startswith("--") and s != "--help"}


def test_every_option_of_the_command_is_walked():
    assert _posegraph_options() == set(CASES) | PRESENTATION


def _cases():
    return [pytest.param(extra, keywords, id=" ".join(extra)) for cases in CASES.values() for extra, keywords in cases]


@pytest.fixture(scope="module")
def intel():
    return lf.read_g2o(INTEL)


@pytest.mark.parametrize("extra, keywords", _cases())
def test_the_command_and_the_front_door_give_the_same_numbers(extra, keywords, intel, tmp_path, capsys):
    truth = tmp_path / "truth.tum"
    lf.write_trajectory(intel, str(truth))  # the start as a reference: any trajectory of intel's stamps
    argv = [a.replace("{out}", str(tmp_path / "cli")).replace("{truth}", str(truth)) for a in extra]
    status, out, err = run_main(capsys, "posegraph", INTEL, "--quiet", "--json", *argv)
    keywords = dict(keywords)
    if status != 0:  # an option this graph refuses (LAGO needs diagonal noise): the same refusal
        keywords.pop("output", None)
        with pytest.raises(lf.LieFactorsError) as refused:
            lf.optimize(intel, **keywords)
        assert status == 2 and err.strip().endswith(str(refused.value))
        return
    record = last_json(out)
    if keywords.pop("replay", False):
        result = lf.replay(intel, **keywords)
        assert record["updates"] == result.updates
    else:
        output, groundtruth = keywords.pop("output", None), keywords.pop("groundtruth", False)
        covariances = keywords.pop("covariances", False)
        result = lf.optimize(intel, **keywords)
        if covariances:
            lf.write_covariances(result, str(tmp_path / "api.npz"))
            for a, b in zip(lf.read_covariances(str(tmp_path / "api.npz")), lf.read_covariances(str(tmp_path / "cli.npz"))):
                assert np.array_equal(a, b)
        if output == ".g2o":
            lf.write_g2o(result, str(tmp_path / "api.g2o"))
        elif output:
            lf.write_trajectory(result, str(tmp_path / f"api{output}"))
        if output:
            assert (tmp_path / f"api{output}").read_text() == (tmp_path / f"cli{output}").read_text()
        if groundtruth:
            assert record["ate"]["rmse"] == pytest.approx(lf.evaluate(result, str(truth)).ate.rmse, rel=1e-12)
        assert record["iterations"] == result.iterations
        assert record.get("outliers") == (None if result.outliers is None else result.outliers.tolist())
        assert record.get("rejected_by") == (None if result.rejected_by is None
                                             else {str(k): v for k, v in result.rejected_by.items()})
    assert record["final_error"] == pytest.approx(result.error, rel=1e-9)


def test_a_gtsam_graph_reaches_gtsams_optimum_and_its_params_are_left_as_they_were():
    pg = lf.read_g2o(INTEL)
    graph, initial = pg.with_first_prior().factor_graph(), pg.initial
    params = gtsam.LevenbergMarquardtParams()
    params.setlambdaInitial(1e-3)
    before = str(params)
    reference = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
    for backend in cli.BACKENDS:
        result = lf.optimize(graph, initial, params, backend=backend, max_iterations=50)
        assert str(params) == before, backend
        assert result.error == pytest.approx(graph.error(reference), rel=1e-6), backend
        assert result.values.size() == initial.size()
        np.testing.assert_allclose(result.poses[10], reference.atPose2(10).matrix(), atol=1e-6)


def test_a_result_is_short_to_print_and_holds_arrays_and_values(intel):
    result = lf.optimize(intel)
    text = repr(result)
    assert len(text) < 200 and "Pose2" in text and "converged" in text
    assert result.poses.shape == (intel.pose_count, 3, 3) and np.array_equal(result.keys, intel.keys)
    assert result.values.size() == intel.pose_count
    np.testing.assert_allclose(result.values.atPose2(5).matrix(), result.poses[5], atol=1e-12)


def test_bad_options_are_one_line_input_errors_named_as_keywords(intel):
    for keywords, fragment in [({"backend": "quantum"}, "unknown backend"), ({"gnc": "l1"}, "gnc: unknown loss"),
                               ({"robust_all": True}, "robust_all needs robust"),
                               ({"robust": "huber", "gnc": "tls"}, "alternatives"),
                               ({"consistency": False}, "consistency applies to gnc only"),
                               ({"max_iterations": -1}, "max_iterations: must be from 0"),
                               ({"init": "odometer"}, "init: unknown initializer")]:
        with pytest.raises(lf.InputError, match=fragment):
            lf.optimize(intel, **keywords)
    with pytest.raises(lf.InputError, match="relinearize_skip"):
        lf.replay(intel, relinearize_skip=0)
