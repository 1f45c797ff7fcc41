"""A sweep's spec: a TOML file naming the graphs, the corruptions, the methods and the evaluation.

::

    timeout = 600                        # seconds per case (optional; the command's --timeout wins)

    [graphs]                             # name = path (relative to this file) or a GTSAM example's name
    intel = "data/intel.g2o"
    city10000 = { path = "data/city10000.g2o", groundtruth = "data/groundtruth/city10000.tum" }

    [corruption]                         # lf.corrupt's kinds, fractions and seeds (optional: clean graphs)
    kinds = ["uniform", "group"]
    fractions = [0.2, 0.5]
    seeds = [1, 2, 3]

    [methods.ours]                       # name = keywords of lf.optimize (run = "optimize", the default)
    gnc = "tls"
    [methods.gtsam]                      # GTSAM's GncOptimizer: its factors, its GNC
    backend = "native"
    gnc = "tls"
    consistency = false
    [methods.online]                     # keywords of lf.replay
    run = "replay"

    [evaluation]                         # lf.evaluate's (optional)
    align = "se3"
    delta = 1

Every key, option, graph and kind is checked before any case runs: a bad one is an
:class:`~lie_factors.errors.InputError` of one line, ``SPEC:LINE: key: what is wrong``.
"""

from __future__ import annotations

import inspect
import math
import os
import re
from dataclasses import dataclass, field
from typing import Any

from ..errors import InputError

__all__ = ["Spec", "GraphSource", "Method", "read_spec", "parse_spec", "RUNS", "ALIGNMENTS"]

#: What a method runs: the batch solver (lf.optimize) or the online replay (lf.replay).
RUNS = ("optimize", "replay")
#: lf.evaluate's alignments.
ALIGNMENTS = ("se3", "sim3", "none")
#: The keywords of lf.optimize and lf.replay a spec may not set: the graph comes from the case,
#: and events are the sweep's own.
_NOT_OPTIONS = {"graph", "initial", "params", "events", "pose_graph"}
_TOP_KEYS = ("timeout", "graphs", "corruption", "methods", "evaluation")
_CORRUPTION_KEYS = ("kinds", "fractions", "seeds")
_EVALUATION_KEYS = ("align", "delta")
_GRAPH_KEYS = ("path", "groundtruth")


@dataclass(frozen=True)
class GraphSource:
    """A graph of the spec: ``name``, the g2o file's ``path`` (absolute, or the GTSAM example it
    resolves to) and an optional ground-truth trajectory's ``groundtruth`` path."""

    name: str
    path: str
    groundtruth: str | None = None


@dataclass(frozen=True)
class Method:
    """A method: ``name``, ``run`` (``optimize`` or ``replay``) and the keywords it is called with."""

    name: str
    run: str
    options: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Spec:
    """A checked spec: its graphs, corruptions (kinds × fractions × seeds; none: the clean graphs),
    methods, evaluation (``align``, ``delta``) and per-case ``timeout`` in seconds (None: none)."""

    graphs: tuple[GraphSource, ...]
    kinds: tuple[str, ...]
    fractions: tuple[float, ...]
    seeds: tuple[int, ...]
    methods: tuple[Method, ...]
    align: str = "se3"
    delta: int = 1
    timeout: float | None = None
    path: str = ""


def read_spec(path: str) -> Spec:
    """The :class:`Spec` of the TOML file ``path``, checked (module docstring)."""
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise InputError(f"{path}: no such spec file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the spec ({exc})") from None
    return parse_spec(text, path)


def parse_spec(text: str, path: str = "<spec>") -> Spec:
    """The :class:`Spec` of TOML ``text``; relative graph paths are taken from ``path``'s directory."""
    import tomllib

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not a TOML spec: {exc}") from None
    return _Checker(text, path).spec(data)


class _Checker:
    def __init__(self, text: str, path: str):
        self.lines = text.splitlines()
        self.path = path
        self.base = os.path.dirname(os.path.abspath(path)) if path != "<spec>" else os.getcwd()

    # ------------------------------------------------------------ errors
    def fail(self, keys: tuple[str, ...], what: str) -> InputError:
        return InputError(f"{self.path}:{_line_of(self.lines, keys)}: {'.'.join(keys)}: {what}")

    def known(self, table: dict, allowed, keys: tuple[str, ...]) -> None:
        for key in table:
            if key not in allowed:
                raise self.fail((*keys, key), f"unknown key (choose from {', '.join(allowed)})")

    # ------------------------------------------------------------ the spec
    def spec(self, data: dict) -> Spec:
        self.known(data, _TOP_KEYS, ())
        if "graphs" not in data or not isinstance(data["graphs"], dict) or not data["graphs"]:
            raise InputError(f"{self.path}: graphs: a table of at least one graph is required")
        if "methods" not in data or not isinstance(data["methods"], dict) or not data["methods"]:
            raise InputError(f"{self.path}: methods: a table of at least one method is required")
        graphs = tuple(self.graph(name, entry) for name, entry in data["graphs"].items())
        kinds, fractions, seeds = self.corruption(data.get("corruption"))
        methods = tuple(self.method(name, entry) for name, entry in data["methods"].items())
        align, delta = self.evaluation(data.get("evaluation", {}))
        timeout = data.get("timeout")
        if timeout is not None and (isinstance(timeout, bool) or not isinstance(timeout, (int, float))
                                    or not 0 < timeout < math.inf):
            raise self.fail(("timeout",), f"expected seconds > 0, got {timeout!r}")
        return Spec(graphs, kinds, fractions, seeds, methods, align, delta,
                    None if timeout is None else float(timeout), self.path)

    def graph(self, name: str, entry) -> GraphSource:
        keys = ("graphs", name)
        if isinstance(entry, str):
            entry = {"path": entry}
        if not isinstance(entry, dict):
            raise self.fail(keys, "expected a path or a table {path = ..., groundtruth = ...}")
        self.known(entry, _GRAPH_KEYS, keys)
        if not isinstance(entry.get("path"), str):
            raise self.fail((*keys, "path"), "a graph file's path is required")
        path = self.graph_file(entry["path"], (*keys, "path"))
        truth = entry.get("groundtruth")
        if truth is not None:
            if not isinstance(truth, str):
                raise self.fail((*keys, "groundtruth"), f"expected a path, got {truth!r}")
            truth = self.file(truth, (*keys, "groundtruth"))
        return GraphSource(name, path, truth)

    def file(self, given: str, keys: tuple[str, ...]) -> str:
        path = os.path.join(self.base, os.path.expanduser(given))
        if not os.path.isfile(path):
            raise self.fail(keys, f"{given}: no such file")
        return os.path.abspath(path)

    def graph_file(self, given: str, keys: tuple[str, ...]) -> str:
        path = os.path.join(self.base, os.path.expanduser(given))
        if os.path.isfile(path):
            return os.path.abspath(path)
        if os.sep not in given:  # a file shipped with GTSAM, as lf.read_g2o takes it
            from ..g2o.dataset import resolve_dataset

            try:
                return resolve_dataset(given)
            except InputError:
                pass
        raise self.fail(keys, f"{given}: no such file (nor a GTSAM example of that name)")

    def corruption(self, table) -> tuple[tuple[str, ...], tuple[float, ...], tuple[int, ...]]:
        if table is None:
            return (), (), ()
        keys = ("corruption",)
        if not isinstance(table, dict):
            raise self.fail(keys, "expected a table of kinds, fractions and seeds")
        self.known(table, _CORRUPTION_KEYS, keys)
        from ..corruption import KINDS

        for key in _CORRUPTION_KEYS:
            value = table.get(key)
            if not isinstance(value, list) or not value:
                raise self.fail((*keys, key), "a non-empty list is required")
        for kind in table["kinds"]:
            if kind not in KINDS:
                raise self.fail((*keys, "kinds"), f"unknown kind {kind!r} (lf.corrupt's: {', '.join(KINDS)})")
        for f in table["fractions"]:
            if isinstance(f, bool) or not isinstance(f, (int, float)) or not 0 < f <= 10:
                raise self.fail((*keys, "fractions"), f"a fraction is a number in (0, 10], got {f!r}")
        for s in table["seeds"]:
            if isinstance(s, bool) or not isinstance(s, int) or s < 0:
                raise self.fail((*keys, "seeds"), f"a seed is a non-negative integer, got {s!r}")
        for key in _CORRUPTION_KEYS:
            if len(set(table[key])) != len(table[key]):
                raise self.fail((*keys, key), "a value is listed twice")
        return (tuple(table["kinds"]), tuple(float(f) for f in table["fractions"]),
                tuple(int(s) for s in table["seeds"]))

    def method(self, name: str, entry) -> Method:
        keys = ("methods", name)
        if not re.fullmatch(r"[A-Za-z0-9_.+-]+", name):
            raise self.fail(keys, "a method's name is letters, digits and _ . + -")
        if not isinstance(entry, dict):
            raise self.fail(keys, "expected a table of options")
        options = dict(entry)
        run = options.pop("run", "optimize")
        if run not in RUNS:
            raise self.fail((*keys, "run"), f"unknown run {run!r} (choose from {', '.join(RUNS)})")
        from .. import solve

        function = solve.optimize if run == "optimize" else solve.replay
        allowed = [p for p in inspect.signature(function).parameters if p not in _NOT_OPTIONS]
        for key in options:
            if key not in allowed:
                raise self.fail((*keys, key), f"unknown option of lf.{run} (choose from run, {', '.join(allowed)})")
        try:
            if run == "optimize":
                solve.options(**options)
            else:
                solve.replay_options(**options)
        except InputError as exc:
            # the option the message names: the one it starts with, else the one it mentions
            bad = next((k for k in options if str(exc).startswith(k)), None) or \
                next((k for k in options if re.search(rf"\b{re.escape(k)}\b", str(exc))), None)
            raise self.fail((*keys, bad) if bad else keys, str(exc)) from None
        except TypeError as exc:
            raise self.fail(keys, str(exc)) from None
        return Method(name, run, options)

    def evaluation(self, table) -> tuple[str, int]:
        keys = ("evaluation",)
        if not isinstance(table, dict):
            raise self.fail(keys, "expected a table of align and delta")
        self.known(table, _EVALUATION_KEYS, keys)
        align = table.get("align", "se3")
        if align not in ALIGNMENTS:
            raise self.fail((*keys, "align"), f"unknown alignment {align!r} (choose from {', '.join(ALIGNMENTS)})")
        delta = table.get("delta", 1)
        if isinstance(delta, bool) or not isinstance(delta, int) or delta < 1:
            raise self.fail((*keys, "delta"), f"expected an integer >= 1, got {delta!r}")
        return align, delta


_HEADER = re.compile(r"^\s*\[\[?\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
_KEY = re.compile(r"^\s*((?:\"[^\"]*\"|'[^']*'|[A-Za-z0-9_-]+)(?:\s*\.\s*(?:\"[^\"]*\"|'[^']*'|[A-Za-z0-9_-]+))*)\s*=")


def _dotted(text: str) -> tuple[str, ...]:
    return tuple(part.strip().strip("\"'") for part in re.findall(r"\"[^\"]*\"|'[^']*'|[^.]+", text))


def _line_of(lines: list[str], keys: tuple[str, ...]) -> int:
    """The 1-based line defining ``keys`` (a table header or a key), or the nearest enclosing
    one's; 1 if none does (a key missing from the file)."""
    best, best_len = 1, 0
    table: tuple[str, ...] = ()
    full: tuple[str, ...]
    for number, line in enumerate(lines, 1):
        header = _HEADER.match(line)
        if header:
            table = _dotted(header.group(1))
            full = table
        else:
            key = _KEY.match(line)
            if not key:
                continue
            full = (*table, *_dotted(key.group(1)))
        common = 0
        for a, b in zip(full, keys):
            if a != b:
                break
            common += 1
        if common == len(full) and common > best_len:
            best, best_len = number, common
    return best
