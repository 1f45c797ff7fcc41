"""A sweep's results file: rows written and read back with their types, a cut-short row dropped,
a file that is not a sweep's refused and left byte-identical; the summary's worst and median."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lie_factors.errors import InputError
from lie_factors.sweeps.results import COLUMNS, EARLIER_COLUMNS, ResultsFile, read_results
from lie_factors.sweeps.summary import summary


def row(case: str, seed: int, precision: float | None, status: str = "ok", **more) -> dict:
    graph, kind, fraction, _, method = case.split("/")
    return {"case": case, "graph": graph, "kind": kind, "fraction": float(fraction), "seed": seed,
            "method": method, "run": "optimize", "options": '{"gnc": "tls"}', "status": status,
            "error": "" if status == "ok" else "boom", "precision": precision, "recall": 0.25,
            "map_error": 1.5, "seconds": 0.1 * seed, "planted": 7, "ate_rmse": 1 / 3, **more}


def test_rows_round_trip_with_their_types(tmp_path):
    path = str(tmp_path / "r.csv")
    with ResultsFile(path) as results:
        assert results.rows == [] and not (tmp_path / "r.csv").exists()  # nothing written before a case ends
        results.add(row("g/uniform/0.2/1/ours", 1, 0.1 + 0.2, rejected_by="gate 2, gnc 1"))
        results.add(row("g/uniform/0.2/2/ours", 2, None))
    back = read_results(path)
    assert list(back[0]) == list(COLUMNS)
    assert back[0]["precision"] == 0.1 + 0.2 and back[0]["ate_rmse"] == 1 / 3  # floats exactly
    assert back[0]["seed"] == 1 and back[0]["planted"] == 7 and back[0]["rejected_by"] == "gate 2, gnc 1"
    assert back[1]["precision"] is None and back[1]["iterations"] is None and back[1]["error"] == ""
    assert ResultsFile(path).done == {"g/uniform/0.2/1/ours", "g/uniform/0.2/2/ours"}


def test_a_case_has_one_row(tmp_path):
    """A case handed back a second time (in this sweep or after a resume) adds no row."""
    path = str(tmp_path / "r.csv")
    with ResultsFile(path) as results:
        assert results.add(row("g/uniform/0.2/1/ours", 1, 0.5))
        assert not results.add(row("g/uniform/0.2/1/ours", 1, 0.25))
    with ResultsFile(path) as results:
        assert not results.add(row("g/uniform/0.2/1/ours", 1, 0.75))
        assert results.add(row("g/uniform/0.2/2/ours", 2, 0.75))
    assert [(r["case"], r["precision"]) for r in read_results(path)] == [("g/uniform/0.2/1/ours", 0.5),
                                                                        ("g/uniform/0.2/2/ours", 0.75)]


def test_a_row_cut_short_is_dropped_and_its_case_runs_again(tmp_path):
    path = tmp_path / "r.csv"
    with ResultsFile(str(path)) as results:
        results.add(row("g/uniform/0.2/1/ours", 1, 0.5))
    whole = path.read_bytes()
    path.write_bytes(whole + b"g/uniform/0.2/2/ours,g,unif")
    results = ResultsFile(str(path))
    assert results.done == {"g/uniform/0.2/1/ours"}
    results.add(row("g/uniform/0.2/2/ours", 2, 0.75))
    results.close()
    assert [r["precision"] for r in read_results(str(path))] == [0.5, 0.75]


@pytest.mark.parametrize("name, content", [("notes.csv", b"a,b\n1,2\n"), ("empty.csv", b""),
                                           ("other.parquet", b"PAR1 not really")])
def test_a_file_that_is_not_a_sweeps_is_refused_and_left_as_it_was(tmp_path, name, content):
    if name.endswith(".parquet"):
        pytest.importorskip("pyarrow", reason="the optional extra parquet (pyarrow) is not installed")
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError, match="not a sweep's results file"):
        ResultsFile(str(path))
    assert path.read_bytes() == content


def test_parquet_round_trip(tmp_path):
    pytest.importorskip("pyarrow", reason="the optional extra parquet (pyarrow) is not installed")
    path = str(tmp_path / "r.parquet")
    with ResultsFile(path) as results:
        results.add(row("g/uniform/0.2/1/ours", 1, 0.5))
        results.add(row("g/uniform/0.2/2/ours", 2, None, status="timeout"))
    back = read_results(path)
    assert [r["case"] for r in back] == ["g/uniform/0.2/1/ours", "g/uniform/0.2/2/ours"]
    assert back[0]["precision"] == 0.5 and back[1]["precision"] is None and back[1]["status"] == "timeout"
    assert ResultsFile(path).done == {r["case"] for r in back}


def test_parquet_without_pyarrow_is_one_line(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "pyarrow", None)
    with pytest.raises(InputError) as info:
        ResultsFile(str(tmp_path / "r.parquet"))
    assert "pyarrow" in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(InputError, match="is .csv or .parquet"):
        ResultsFile(str(tmp_path / "r.txt"))


def test_summary_is_the_worst_and_the_median_per_cell(tmp_path):
    precisions = [0.5, 0.8, 1.0, 0.9]
    rows = [row(f"g/uniform/0.2/{s}/ours", s, p) for s, p in enumerate(precisions)]
    rows += [row(f"g/uniform/0.2/{s}/gtsam", s, 1.0, status="timeout" if s == 3 else "ok") for s in range(4)]
    table = summary(rows, tuning=[0]).splitlines()
    ours = next(line for line in table if "| ours |" in line).split(" | ")
    gtsam = next(line for line in table if "| gtsam (1 past the timeout) |" in line).split(" | ")
    # seeds 1, 2, 3 (0 is a tuning seed): precision 0.8, 1.0, 0.9 -> worst 0.8, median 0.9
    assert ours[4] == "1,2,3" and ours[5] == "0.800 / 0.900"
    # a timeout counts as failed: precision 0, map error infinite
    assert gtsam[5] == "0.000 / 1.000" and gtsam[7] == "inf % / 1.5 %"
    assert ours[8].startswith(f"{0.3:.2f} / {np.median([0.1, 0.2, 0.3]):.2f}")
    assert not math.isnan(float(ours[6].split(" / ")[0]))


def test_summary_counts_the_uncertain_cases_per_cell():
    said = ["ok", "uncertain; GNC stopped at its iteration limit", "ok", "uncertain; final check at its bound"]
    rows = [row(f"g/group/0.5/{s}/ours", s, 1.0, robust_status=x) for s, x in enumerate(said, start=1)]
    rows.append(row("g/group/0.5/5/ours", 5, None, status="failed"))  # no status: not counted
    rows += [row(f"g/group/0.5/{s}/plain", s, None) for s in (1, 2)]  # a method without rejection
    table = summary(rows).splitlines()
    assert table[1].split(" | ")[-1] == "uncertain |"
    ours = next(line for line in table if "| ours (1 failed) |" in line).split(" | ")
    plain = next(line for line in table if "| plain |" in line).split(" | ")
    assert ours[-1] == "2 of 4 |" and plain[-1] == "– |"


def test_an_earlier_sweeps_file_is_read_and_resumed_with_the_status_column(tmp_path):
    """A file written before robust_status: read (the status empty), and resumed: rewritten with
    every column, its rows kept bit for bit, then the new row appended."""
    import csv

    path = tmp_path / "r.csv"
    earlier = [row(f"g/uniform/0.2/{s}/ours", s, 0.1 * s + 0.05) for s in (1, 2)]
    with open(path, "w", newline="", encoding="utf-8") as fh:
        out = csv.writer(fh, lineterminator="\n")
        out.writerow(EARLIER_COLUMNS)
        for r in earlier:
            out.writerow(["" if r.get(c) is None else (repr(r[c]) if isinstance(r.get(c), float) else r[c])
                          for c in EARLIER_COLUMNS])
    path.write_bytes(path.read_bytes() + b"g/uniform/0.2/3/ours,g,unif")  # and a row cut short
    back = read_results(str(path))
    assert [r["precision"] for r in back] == [0.15000000000000002, 0.25] and all(r["robust_status"] == "" for r in back)
    with ResultsFile(str(path)) as results:
        assert results.done == {"g/uniform/0.2/1/ours", "g/uniform/0.2/2/ours"}
        results.add(row("g/uniform/0.2/3/ours", 3, 0.5, robust_status="ok"))
    assert path.read_bytes().split(b"\n", 1)[0].decode() == ",".join(COLUMNS)
    again = read_results(str(path))
    assert again[:2] == back and again[2]["robust_status"] == "ok" and again[2]["precision"] == 0.5
