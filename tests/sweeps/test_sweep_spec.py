"""A sweep's spec: its cases, and every bad key, option, graph or kind refused in one line naming
the key and its line, before any case runs."""

from __future__ import annotations

from pathlib import Path

import pytest

from lie_factors.errors import InputError
from lie_factors.sweeps.cases import CLEAN, cases_of
from lie_factors.sweeps.spec import parse_spec, read_spec

ROOT = Path(__file__).resolve().parents[2]

GOOD = """\
timeout = 30

[graphs]
grid = "data/smallGrid3D.g2o"
city = { path = "data/city10000.g2o", groundtruth = "data/groundtruth/city10000.tum" }

[corruption]
kinds = ["uniform", "group"]
fractions = [0.1, 0.2]
seeds = [1, 2, 3]

[methods.ours]
gnc = "tls"

[methods.gtsam]
backend = "native"
gnc = "tls"
consistency = false

[methods.online]
run = "replay"
relinearize_skip = 1

[evaluation]
align = "sim3"
delta = 2
"""


def spec_of(text: str, tmp_path: Path):
    path = tmp_path / "spec.toml"
    path.write_text(text)
    (tmp_path / "data").symlink_to(ROOT / "data")
    return read_spec(str(path))


def test_a_spec_is_every_graph_kind_fraction_seed_and_method(tmp_path):
    spec = spec_of(GOOD, tmp_path)
    assert [g.name for g in spec.graphs] == ["grid", "city"]
    assert spec.graphs[0].path == str(tmp_path / "data" / "smallGrid3D.g2o") and spec.graphs[0].groundtruth is None
    assert spec.graphs[1].groundtruth == str(tmp_path / "data" / "groundtruth" / "city10000.tum")
    assert spec.timeout == 30.0 and (spec.align, spec.delta) == ("sim3", 2)
    cases = cases_of(spec)
    assert len(cases) == 2 * 2 * 2 * 3 * 3
    assert len({c.id for c in cases}) == len(cases)
    online = [c for c in cases if c.method == "online"]
    assert {c.run for c in online} == {"replay"} and online[0].options == {"relinearize_skip": 1}
    gtsam = next(c for c in cases if c.method == "gtsam")
    assert gtsam.options == {"backend": "native", "gnc": "tls", "consistency": False}
    assert cases[0].id == "grid/uniform/0.1/1/ours" and (cases[0].align, cases[0].delta) == ("sim3", 2)


def test_without_a_corruption_table_the_clean_graphs_are_the_cases(tmp_path):
    spec = spec_of('[graphs]\ngrid = "data/smallGrid3D.g2o"\n[methods.plain]\n[methods.native]\nbackend = "native"\n',
                   tmp_path)
    assert [(c.kind, c.fraction, c.seed, c.method) for c in cases_of(spec)] == [(CLEAN, 0.0, 0, "plain"),
                                                                                (CLEAN, 0.0, 0, "native")]


def test_a_gtsam_example_by_name(tmp_path):
    spec = spec_of('[graphs]\nexample = "pose3example.txt"\n[methods.plain]\n', tmp_path)
    assert spec.graphs[0].path.endswith("pose3example.txt") and Path(spec.graphs[0].path).is_file()


def _replace(old: str, new: str) -> str:
    assert old in GOOD
    return GOOD.replace(old, new)


#: (the spec, the line the error names, what the error names)
BAD = [
    (_replace("timeout = 30", "timeout = 30\nworkers = 2"), 2, "workers: unknown key"),
    (_replace('gnc = "tls"\n\n[methods.gtsam]', 'gnc = "tls"\nmax_iteration = 5\n\n[methods.gtsam]'), 14,
     "methods.ours.max_iteration: unknown option of lf.optimize"),
    (_replace('consistency = false', 'consistency = false\ngnc_loss = "tls"'), 19, "methods.gtsam.gnc_loss"),
    (_replace('[methods.ours]\ngnc = "tls"', '[methods.ours]\ngnc = "huber"'), 13, "methods.ours.gnc"),
    (_replace('backend = "native"', 'backend = "nativ"'), 16, "methods.gtsam.backend: unknown backend 'nativ'"),
    (_replace("relinearize_skip = 1", "relinearize_skip = 0"), 22, "methods.online.relinearize_skip"),
    (_replace("relinearize_skip = 1", 'gnc = "gm"'), 22, "methods.online.gnc"),
    (_replace('run = "replay"', 'run = "smooth"'), 21, "methods.online.run: unknown run 'smooth'"),
    (_replace('"data/smallGrid3D.g2o"', '"data/smallGrid.g2o"'), 4, "graphs.grid.path: data/smallGrid.g2o: no such file"),
    (_replace('groundtruth = "data/groundtruth/city10000.tum"', 'groundtruth = "data/gt.tum"'), 5,
     "graphs.city.groundtruth: data/gt.tum: no such file"),
    (_replace('path = "data/city10000.g2o",', 'path = "data/city10000.g2o", truth = "x",'), 5,
     "graphs.city.truth: unknown key"),
    (_replace('kinds = ["uniform", "group"]', 'kinds = ["uniform", "clustered"]'), 8,
     "corruption.kinds: unknown kind 'clustered'"),
    (_replace("fractions = [0.1, 0.2]", "fractions = [0.1, 0]"), 9, "corruption.fractions"),
    (_replace("seeds = [1, 2, 3]", "seeds = [1, -2]"), 10, "corruption.seeds"),
    (_replace("seeds = [1, 2, 3]", "seeds = [1, 2, 3]\nseed = 4"), 11, "corruption.seed: unknown key"),
    (_replace('align = "sim3"', 'align = "se2"'), 25, "evaluation.align"),
    (_replace("timeout = 30", "timeout = -1"), 1, "timeout: expected seconds > 0"),
]


@pytest.mark.parametrize("text, line, fragment", BAD, ids=[b[2].split(":")[0] for b in BAD])
def test_a_bad_spec_is_one_line_naming_the_key_and_its_line(tmp_path, text, line, fragment):
    with pytest.raises(InputError) as info:
        spec_of(text, tmp_path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{tmp_path / 'spec.toml'}:{line}: "), message
    assert fragment in message, message


def test_not_toml_and_no_file(tmp_path):
    with pytest.raises(InputError, match="not a TOML spec"):
        parse_spec("[graphs\n", "s.toml")
    with pytest.raises(InputError, match="no such spec file"):
        read_spec(str(tmp_path / "none.toml"))
    with pytest.raises(InputError, match="methods: a table of at least one method"):
        parse_spec('[graphs]\ng = "x"\n', "s.toml")
