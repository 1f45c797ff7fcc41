"""The numba scan of g2o bytes (lie_factors.g2o.scan, run by parse.scan_parse) against the numpy and exact parses.

Where the scan reads a file, its result is the numpy parse's, array for array and bit for bit (the
same tags in the same order, dtypes, shapes, line numbers, comment and fragile lines); where it
gives up, ``parse`` ends exactly as before: every refusal names the same line with the same words.
"""

from __future__ import annotations

import os
import random
import subprocess
import sys
from pathlib import Path

import gtsam
import pytest

from lie_factors import g2o
from lie_factors.errors import InputError
from lie_factors.g2o import parse

ROOT = Path(__file__).resolve().parents[2]
GENERATOR = ROOT / "benchmarks" / "generate_posegraph.py"

GTSAM_FILES = ["pose2example.txt", "pose3example.txt", "pose3example-grid.txt", "pose3example-offdiagonal.txt",
               "pose3Localizationexample.txt", "sphere2500.txt", "w20000.txt", "victoria_park.txt",
               "cityTrees_reduced_1k.g2o", "victoriaPark_reduced_1k.g2o", "toyExample.g2o", "Klaus3.g2o",
               "example_with_vertices.g2o", "w100_30.g2o", "noisyToyGraph.txt", "edge_se3_trackxyz_example.g2o",
               "known_landmark_localization_3.g2o", "example.graph"]


def _before(name: str, data: bytes):
    """What parse did before the scan: the numpy parse, or the exact one where it gives up."""
    parsed = parse.fast_parse(name, data)
    return parsed if parsed is not None else parse.slow_parse(name, data)


def _outcome(fn, *args):
    try:
        return fn(*args), None
    except InputError as exc:
        return None, str(exc)


def _assert_identical(a, b):
    """Two parses' results: the same tags in the same order, arrays equal in dtype, shape, layout and bits."""
    rows_a, comments_a, fragile_a = a
    rows_b, comments_b, fragile_b = b
    assert list(rows_a) == list(rows_b)
    for tag, ra in rows_a.items():
        rb = rows_b[tag]
        assert ra.tag == rb.tag
        for field in ("ids", "values", "lines"):
            x, y = getattr(ra, field), getattr(rb, field)
            assert (x.dtype, x.shape, x.flags.c_contiguous) == (y.dtype, y.shape, y.flags.c_contiguous), (tag, field)
            assert x.tobytes() == y.tobytes(), (tag, field)
        assert (ra.fragile is None) == (rb.fragile is None), tag
        if ra.fragile is not None:
            assert ra.fragile.dtype == rb.fragile.dtype and ra.fragile.tolist() == rb.fragile.tolist(), tag
    assert comments_a == comments_b and fragile_a == fragile_b


def _assert_same_rows_as_exact(scanned, data: bytes):
    slow = parse.slow_parse("x", data)
    assert sorted(scanned[0]) == sorted(slow[0])
    for tag, r in scanned[0].items():
        s = slow[0][tag]
        assert r.ids.tolist() == s.ids.tolist() and r.lines.tolist() == s.lines.tolist()
        assert r.values.tobytes() == s.values.tobytes()
    assert scanned[1] == slow[1] and scanned[2] == slow[2]


# --------------------------------------------------------------------------- files

def _data_files():
    """The benchmark graphs in data/, and those of LIE_FACTORS_DATA if it names another directory."""
    files = sorted((ROOT / "data").glob("*.g2o"))
    other = os.environ.get("LIE_FACTORS_DATA")
    if other and Path(other).is_dir() and Path(other).resolve() != (ROOT / "data").resolve():
        files += sorted(Path(other).glob("*.g2o"))
    return files


@pytest.mark.parametrize("path", _data_files(), ids=lambda p: f"{p.parent.parent.name}/{p.name}")
def test_benchmark_files(path):
    data = path.read_bytes()
    scanned = parse.scan_parse(data)
    assert scanned is not None
    _assert_identical(scanned, _before(path.name, data))


@pytest.mark.parametrize("name", GTSAM_FILES)
def test_files_shipped_with_gtsam(name, monkeypatch):
    """Accepted or refused, the outcome is the one before the scan (some hold records we refuse)."""
    data = Path(gtsam.findExampleDataFile(name)).read_bytes()
    before, error = _outcome(_before, name, data)
    monkeypatch.setattr(parse, "SCAN_MIN_BYTES", 0)
    now, now_error = _outcome(parse.parse, name, data)
    assert now_error == error
    if before is not None:
        _assert_identical(now, before)


def test_generated_helix(tmp_path):
    """17-digit numbers (repr of doubles), the benchmark graphs' form."""
    path = tmp_path / "helix.g2o"
    subprocess.run([sys.executable, str(GENERATOR), "--poses", "3000", "--lap", "500", "--output", str(path)],
                   check=True, capture_output=True)
    data = path.read_bytes()
    scanned = parse.scan_parse(data)
    assert scanned is not None and len(scanned[0]["EDGE_SE3:QUAT"]) > 3000
    _assert_identical(scanned, _before("helix.g2o", data))


# --------------------------------------------------------------------------- every record type, every form

#: Number forms C++ reads: repr, printf, signs, no integer part, no fraction, exponents, many digits,
#: subnormal and underflowing values (those go to the exact conversion).
def _number(rng: random.Random) -> str:
    x = rng.uniform(-50, 50)
    return rng.choice([
        repr(x), "%.17g" % x, "%g" % x, "%.3e" % x, "%.6f" % x, "%d" % int(x), "+%.4f" % abs(x),
        ".5", "-.5", "+.25", "5.", "-5.", "1E5", "2.5e-3", "-7e+2", "007.50", "0", "-0", "0.0",
        "1234567890.12345678901234567890", "4.9406564584124654e-324", "1e-310", "2.2250738585072011e-308",
        "1.7976931348623157e308", "9007199254740993", "123456789012345678901234.5",
        "18446744073709551615.0", "18446744073709551616.0", "-18446744073709551617", "1e-400",
    ])


def _id(rng: random.Random) -> str:
    return rng.choice([str(rng.randint(0, 50)), str(rng.randint(0, 10 ** 6)), "0", "007",
                       str(g2o.MAX_ID), str(2 ** 53 + 1), "0" * 25 + "3"])


def _family_file(family, rng: random.Random) -> bytes:
    """Lines of every record type of a family in random order and spacing, with comments and blank lines."""
    lines = []
    for rec in (r for r in g2o.RECORDS.values() if r.family == family):
        for _ in range(rng.randint(1, 6)):
            fields = [rec.tag] + [_id(rng) for _ in rec.ids] + [_number(rng) for _ in range(len(rec.values) + rec.info)]
            text = fields[0]
            for f in fields[1:]:
                text += rng.choice([" ", "  ", "\t", " \t ", "\v", "\f"]) + f
            lines.append(text + rng.choice(["", " ", "\t", "\r", " \r"]))
    rng.shuffle(lines)
    for _ in range(rng.randint(0, 4)):
        lines.insert(rng.randint(0, len(lines)), rng.choice(["# comment", "#", "#VERTEX_SE2 1 2 3 4", "", " ",
                                                             "\t# indented comment"]))
    if rng.random() < 0.2:  # indented records: the exact parse's order of tags (first appearance)
        lines = [" " + line if rng.random() < 0.3 else line for line in lines]
    end = rng.choice(["\n", "\r\n"])
    text = end.join(lines) + rng.choice([end, ""])
    return text.encode()


FAMILIES = sorted({r.family for r in g2o.RECORDS.values()})


@pytest.mark.parametrize("family", FAMILIES, ids=lambda f: f"{f[0]}D-{f[1]}")
def test_every_record_type_and_number_form(family):
    rng = random.Random(FAMILIES.index(family))
    exact_conversions = 0
    for _ in range(60):
        data = _family_file(family, rng)
        scanned = parse.scan_parse(data)
        assert scanned is not None, data[:200]
        _assert_identical(scanned, _before("x", data))
        _assert_same_rows_as_exact(scanned, data)
        exact_conversions += data.count(b"1e-310")
    assert exact_conversions  # the exact conversion's route was taken


def test_repeated_information_text():
    """Rows whose information is written with the same bytes as the previous row's are copied by the
    scan, not read again: every near miss (a longer or shorter number, other spacing, a trailing
    token, a number left to the exact conversion, a line of another tag between) reads as the numpy parse."""
    rng = random.Random(11)
    infos = ["400 0 0 0 0 0 400 0 0 0 0 400 0 0 0 10000 0 0 10000 0 10000",
             "400 0 0 0 0 0 400 0 0 0 0 400 0 0 0 10000 0 0 10000 0 100000",
             "400 0 0 0 0 0 400 0 0 0 0 400 0 0 0 10000 0 0 10000 0 1000",
             "400 0 0 0 0 0 400 0 0 0 0 400 0 0 0 10000 0 0 10000 0  10000",
             "400 0 0 0 0 0 400 0 0 0 0 400 0 0 0 10000 0 0 10000 0 10000 ",
             "400 0 0 0 0 0 400 0 0 0 0 400 0 0 0 10000 0 0 10000 0 1e-310",
             "4.9406564584124654e-324 0 0 0 0 0 400 0 0 0 0 400 0 0 0 10000 0 0 10000 0 10000",
             "1234567890.12345678901234567890 0 0 0 0 0 400 0 0 0 0 400 0 0 0 10000 0 0 10000 0 10000"]
    for trial in range(40):
        lines = []
        for k in range(rng.randint(2, 40)):
            if rng.random() < 0.1:
                lines.append(f"VERTEX_SE3:QUAT {k} 1 2 3 0 0 0 1")
            info = infos[0] if rng.random() < 0.6 else rng.choice(infos)
            lines.append(f"EDGE_SE3:QUAT {k} {k + 1} {rng.uniform(-5, 5)!r} 0.5 -1 0 0 0.6 0.8 {info}")
        end = rng.choice(["\n", "\r\n"])
        data = (end.join(lines) + rng.choice([end, ""])).encode()
        scanned = parse.scan_parse(data)
        assert scanned is not None, trial
        _assert_identical(scanned, _before("x", data))
    bad = b"EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1 7\n"  # a repeat, then a field too many
    assert parse.scan_parse(bad) is None
    assert _outcome(parse.parse, "x", bad)[1] == _outcome(_before, "x", bad)[1]


def test_fragile_2d_lines():
    """2-D vertex values GTSAM's second pass cannot read as size_t: listed as before (and only those)."""
    lines = ["VERTEX_SE2 0 .5 0 0", "VERTEX_SE2 1 -.5 0 0", "VERTEX_SE2 2 +.5 0 0", "VERTEX_SE2 3 0.5 0 0",
             "VERTEX_SE2 4 -0.5 0 0", "VERTEX_SE2 5 1e5 0 0", "VERTEX_XY 6 .25 1",
             "VERTEX_SE2 7 18446744073709551615.0 0 0", "VERTEX_SE2 8 18446744073709551616.0 0 0",
             "VERTEX_SE2 9 123456789012345678901234.5 0 0", "VERTEX_SE2 10 +3 0 0",
             "LANDMARK2 0 6 2.5 3 10 0 10", "VERTEX_SE2 11 00000000000000000000000001.5 0 0",
             "EDGE_SE2 0 1 .5 0 0 1 0 0 1 0 1"]
    data = ("\n".join(lines) + "\n").encode()
    scanned = parse.scan_parse(data)
    assert scanned is not None
    _assert_identical(scanned, _before("x", data))
    assert scanned[2] == [1, 2, 3, 7, 9, 10]


# --------------------------------------------------------------------------- refusals

REPLACEMENTS = ["nan", "inf", "-inf", "1e400", "-1e400", "1e-400", "+3", "-3", "-0", ".5", "1_0", "0x10", "1e",
                "--1", "1.0", "1e3", "99999999999999999999", "72057594037927936", "72057594037927935", "٣", "é",
                "\x00", "EDGE_SE2", "VERTEX_SE3:QUAT", "#", "1,5", "1.2.3", "x"]


def _bases():
    se2 = "1 0 0 1 0 1"
    se3 = " ".join(" ".join(["1"] + ["0"] * (5 - r)) for r in range(6))
    sim3 = " ".join(" ".join(["1"] + ["0"] * (6 - r)) for r in range(7))
    return {
        "2d": ["VERTEX_SE2 0 0.5 0.25 0.1", "VERTEX_SE2 1 1.5 0.25 0.1", "EDGE_SE2 0 1 1 0 0.1 " + se2,
               "VERTEX_XY 7 2 3", "LANDMARK2 0 7 2.5 3 10 0 10", "BR 1 8 0.3 2.0 0.05 0.1",
               "LANDMARK 1 9 1.5 -1 0.4 0 0.4", "ODOMETRY 1 2 1 0 0 " + se2],
        "3d": ["VERTEX_SE3:QUAT 0 0 0.5 0 0 0 0 1", "VERTEX_SE3:QUAT 1 1 0.5 0 0 0 0 1",
               "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 " + se3, "VERTEX_TRACKXYZ 3 4 1 2",
               "PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1", "EDGE_SE3_TRACKXYZ 0 3 0 4 1 2 1 0 0 1 0 1",
               "VERTEX3 2 1 2 3 0.1 0.2 0.3", "EDGE3 1 2 1 0 0 0 0 0 " + se3],
        "sim3": ["VERTEX_SIM3:EXPMAP 0 0 0 0 0 0 0 0 1 1 0 0", "VERTEX_SIM3:EXPMAP 1 0 0 0 1 0 0 0 1 1 0 0",
                 "EDGE_SIM3:EXPMAP 0 1 0 0 0 1 0 0 0 " + sim3],
    }


def _mutations(lines: list[str]):
    """Every field of every line replaced by each bad token, dropped, doubled; lines indented, added, foreign."""
    for k, line in enumerate(lines):
        tokens = line.split()
        for j in range(len(tokens)):
            for r in REPLACEMENTS:
                yield k, " ".join(tokens[:j] + [r] + tokens[j + 1:])
            yield k, " ".join(tokens[:j] + tokens[j + 1:])
        yield k, line + " 0"
        yield k, " " + line
        yield k, "\t" + line
        yield k, "UNKNOWN_TAG 1 2 3"
        yield k, "VERTEX_SE2 9 0 0 0" if "SE2" not in line else "VERTEX_SE3:QUAT 9 0 0 0 0 0 0 1"


@pytest.mark.parametrize("base", ["2d", "3d", "sim3"])
def test_every_refusal_names_the_same_line(base, monkeypatch):
    """Each malformed file: the scan gives up, and parse raises what it raised before (line and words)."""
    monkeypatch.setattr(parse, "SCAN_MIN_BYTES", 0)
    lines = _bases()[base]
    refused = 0
    for k, mutated in _mutations(lines):
        data = ("\n".join(lines[:k] + [mutated] + lines[k + 1:]) + "\n").encode("utf-8")
        before, error = _outcome(_before, "f.g2o", data)
        now, now_error = _outcome(parse.parse, "f.g2o", data)
        assert now_error == error, (mutated, now_error, error)
        if error is None:
            _assert_identical(now, before)
            scanned = parse.scan_parse(data)
            if scanned is not None:
                _assert_identical(scanned, before)
        else:
            refused += 1
            assert parse.scan_parse(data) is None, mutated
            assert f"f.g2o:{error.split(':')[1]}:" in error and error.split(":")[1].isdigit()
    assert refused > 100


# --------------------------------------------------------------------------- files on disk

def test_parse_file_scans_large_files(tmp_path, monkeypatch):
    """Files of SCAN_MIN_BYTES and more are scanned; a refusal is worded as before."""
    scanned = []
    real = parse.scan_parse

    def spy(data):
        scanned.append(len(data))
        return real(data)

    monkeypatch.setattr(parse, "scan_parse", spy)
    monkeypatch.setattr(parse, "SCAN_MIN_BYTES", 64)
    good = tmp_path / "good.g2o"
    text = "\n".join(_bases()["3d"]) + "\n"
    good.write_text(text)
    _assert_identical(parse.parse_file(str(good)), _before("good.g2o", text.encode()))
    bad = tmp_path / "bad.g2o"
    bad.write_text(text.replace("VERTEX_TRACKXYZ 3 4 1 2", "VERTEX_TRACKXYZ 3 4 1e400 2"))
    with pytest.raises(InputError) as info:
        parse.parse_file(str(bad))
    assert str(info.value) == _outcome(parse.slow_parse, "bad.g2o", bad.read_bytes())[1]
    assert "bad.g2o:4: field 4 ('1e400') is not finite" in str(info.value)
    assert scanned == [len(text), len(bad.read_bytes())]


def test_parse_file_of_an_empty_file_a_directory_and_a_missing_file(tmp_path):
    empty = tmp_path / "empty.g2o"
    empty.write_bytes(b"")
    parse.parse_file(str(empty))
    with pytest.raises(InputError, match="is a directory"):
        parse.parse_file(str(tmp_path))
    with pytest.raises(InputError, match="cannot read"):
        parse.parse_file(str(tmp_path / "missing.g2o"))


def test_large_file_check_scans_small_file_check_stays_numpy(tmp_path):
    """In a fresh process: a file of SCAN_MIN_BYTES or more loads numba (the scan); a small one does not."""
    big = tmp_path / "big.g2o"
    subprocess.run([sys.executable, str(GENERATOR), "--poses", "25000", "--output", str(big)],
                   check=True, capture_output=True)
    assert big.stat().st_size >= parse.SCAN_MIN_BYTES
    small = ROOT / "data" / "sphere2500.g2o"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    code = ("import sys\nfrom lie_factors import g2o\n"
            "g2o.check_g2o(sys.argv[1])\nprint('numba' in sys.modules)\n")
    seen = [subprocess.run([sys.executable, "-c", code, str(p)], capture_output=True, text=True, env=env,
                           timeout=600, check=True).stdout.strip() for p in (big, small)]
    assert seen == ["True", "False"]


# --------------------------------------------------------------------------- the check's refusals

def _whole_file_refusals():
    """Files every record of which parses, refused by a check of its records or of the graph."""
    b = _bases()
    se2 = "1 0 0 1 0 1"
    se3 = " ".join(" ".join(["1"] + ["0"] * (5 - r)) for r in range(6))
    v2 = ["VERTEX_SE2 0 0 0 0", "VERTEX_SE2 1 1 0 0"]
    v3 = ["VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1", "VERTEX_SE3:QUAT 1 1 0 0 0 0 0 1"]
    e3 = "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 " + se3
    return {
        "duplicate vertex": v2 + ["VERTEX_SE2 0 2 0 0", "EDGE_SE2 0 1 1 0 0 " + se2],
        "duplicate landmark vertex": b["2d"] + ["VERTEX_XY 7 1 1"],
        "duplicate offset": b["3d"] + ["PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1"],
        "self-loop": v2 + ["EDGE_SE2 1 1 1 0 0 " + se2],
        "information 2-D": v2 + ["EDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1"],
        "information TORO order": v2 + ["EDGE_SE2 0 1 1 0 0 1 0 1 1 0 0"],
        "information 3-D": v3 + ["EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 " + se3.replace("1", "-1", 1)],
        "information Sim(3)": b["sim3"][:2] + ["EDGE_SIM3:EXPMAP 0 1 0 0 0 1 0 0 0 " + " ".join(["0"] * 28)],
        "quaternion": ["VERTEX_SE3:QUAT 0 0 0 0 0 0 0 0", v3[1], e3],
        "landmark range": v2 + ["EDGE_SE2 0 1 1 0 0 " + se2, "LANDMARK 1 9 0 0 0.4 0 0.4"],
        "bearing-range range": v2 + ["EDGE_SE2 0 1 1 0 0 " + se2, "BR 1 8 0.3 -2.0 0.05 0.1"],
        "bearing-range deviation": v2 + ["EDGE_SE2 0 1 1 0 0 " + se2, "BR 1 8 0.3 2.0 0 0.1"],
        "landmark covariance": v2 + ["EDGE_SE2 0 1 1 0 0 " + se2, "LANDMARK 1 9 1.5 -1 0.4 0 0.9"],
        "log-scale": ["VERTEX_SIM3:EXPMAP 0 0 0 0 0 0 0 800 1 1 0 0"] + b["sim3"][1:],
        "edge to a pose without vertex": v3 + ["EDGE_SE3:QUAT 0 2 1 0 0 0 0 0 1 " + se3],
        "track without landmark vertex": v3 + [e3, "PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1",
                                               "EDGE_SE3_TRACKXYZ 0 3 0 4 1 2 1 0 0 1 0 1"],
        "missing offset": v3 + [e3, "VERTEX_TRACKXYZ 3 4 1 2", "EDGE_SE3_TRACKXYZ 0 3 5 4 1 2 1 0 0 1 0 1"],
        "offset not the identity": v3 + [e3, "VERTEX_TRACKXYZ 3 4 1 2", "PARAMS_SE3OFFSET 0 1 0 0 0 0 0 1",
                                         "EDGE_SE3_TRACKXYZ 0 3 0 4 1 2 1 0 0 1 0 1"],
        "not connected": v2 + ["VERTEX_SE2 2 0 0 0", "VERTEX_SE2 3 0 0 0", "EDGE_SE2 0 1 1 0 0 " + se2,
                               "EDGE_SE2 2 3 1 0 0 " + se2],
        "no edges": v2,
        "empty": ["# nothing but a comment"],
    }


@pytest.mark.parametrize("case", sorted(_whole_file_refusals()))
def test_every_check_refusal_is_the_same_with_the_scan(case, tmp_path, monkeypatch):
    """check_g2o on files the scan reads: refused with the same line and words as when the numpy
    or the exact parse reads them."""
    path = tmp_path / "f.g2o"
    path.write_text("\n".join(_whole_file_refusals()[case]) + "\n")
    scanned = []
    real = parse.scan_parse

    def spy(data):
        scanned.append(real(data))
        return scanned[-1]

    monkeypatch.setattr(parse, "SCAN_MIN_BYTES", 0)
    monkeypatch.setattr(parse, "scan_parse", spy)
    with pytest.raises(InputError) as now:
        g2o.check_g2o(str(path))
    assert scanned and scanned[-1] is not None  # the scan read the file
    monkeypatch.setattr(parse, "scan_parse", lambda data: None)
    with pytest.raises(InputError) as before:
        g2o.check_g2o(str(path))
    assert str(now.value) == str(before.value)
    assert str(now.value).startswith("f.g2o")
