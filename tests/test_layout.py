"""The package's layers: every import points down, and no module imports itself back.

Ranks, bottom up (docs/architecture.md); a module takes the rank of the longest
prefix listed, and may import only modules of its rank or below:

0. utilities: ``util``, ``errors``;
1. kernels: ``kernels`` and the group modules (``so3`` … ``sim3``, ``quaternion``,
   ``dual_quaternion``);
2. ``interop`` (GTSAM objects ⇄ arrays); 3. ``factors``;
4. the data model, ``posegraph``; 5. g2o files, ``g2o``, then ``result`` (what the front door returns);
6. the solvers, ordered: ``lm`` and ``dogleg`` < ``optimizers`` < ``dropin`` < ``sparse`` <
   ``robust.losses``, ``robust.statistics`` (the batch solver's robust costs), ``robust.tail`` and
   ``robust.online`` (the closure tests the incremental smoother runs) < ``batch`` <
   ``initialization`` < ``incremental`` < the rest of ``robust`` < ``backends``;
7. the front door (``solve``, ``events``, the package's ``__init__``);
8. the app: ``app``, and ``sweeps`` (the front door's runs over many cases, on Dask: the app's
   plot styles, the test generators' scoring of rejected closures).

``testing`` (oracles and generators) stands apart: no library module imports it; the app may
(``lie-factors crosscheck`` prints the oracles' verdicts).  Every import counts, at module level
or inside a function: a deferred import is still a dependency.

Sizes (:mod:`support.code_size`), in the directories of :data:`SIZE_CHECKED`: a function has at
most 150 lines and 12 parameters, a module at most 900 lines, and at most 600 unless it is in
:data:`ONE_JOB`, with the reason it does one job that does not divide.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from support.code_size import oversized_functions, oversized_modules

PACKAGE = Path(__file__).resolve().parents[1] / "lie_factors"

#: (module prefix, rank): the longest matching prefix gives a module's rank.
RANKS = {
    "util": 0, "errors": 0,
    "kernels": 1, "so3": 1, "se3": 1, "se2": 1, "sim2": 1, "sim3": 1, "quaternion": 1, "dual_quaternion": 1,
    "interop": 2, "evaluation": 2,
    "factors": 3, "expressions": 3.5,
    "posegraph": 4,
    "g2o": 5,
    "lm": 6.0, "dogleg": 6.0, "optimizers": 6.1, "dropin": 6.2, "sparse": 6.3,
    "robust.losses": 6.4, "robust.statistics": 6.4, "robust.tail": 6.4, "robust.online": 6.4,
    "robust.leverage": 6.4,
    "batch": 6.5, "initialization": 6.6, "incremental": 6.7, "robust": 6.8, "backends": 6.9,
    "result": 5.5,
    "events": 7, "solve": 7, "files": 7, "corruption": 7, "": 7,
    "app": 8, "sweeps": 8,
}
APART = "testing"


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Every lie_factors module ``path`` imports (absolute names; ``from X import y`` counts
    ``X.y`` when that is a module, else ``X``)."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == "lie_factors")
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "lie_factors":
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                out.add(sub if sub in MODULES else target)
    out.discard(name)
    return out


FILES = sorted(PACKAGE.rglob("*.py"))
MODULES = {_module_name(p) for p in FILES}


def _unit(module: str) -> str:
    """The top-level part a module belongs to (``lie_factors.batch.graph`` → ``batch``)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _layer(module: str):
    """The rank of ``module`` (None: the test oracles, apart)."""
    if _unit(module) == APART:
        return None
    parts = module.split(".")[1:]
    for k in range(len(parts), -1, -1):
        prefix = ".".join(parts[:k])
        if prefix in RANKS:
            return RANKS[prefix]
    raise KeyError(module)


def test_every_module_has_a_layer():
    unknown = sorted({_unit(m) for m in MODULES} - set(RANKS) - {"", APART})
    assert not unknown, f"modules outside the layer table: {unknown}"


@pytest.mark.parametrize("path", FILES, ids=lambda p: _module_name(p))
def test_imports_point_down(path):
    here = _module_name(path)
    mine = _layer(here)
    wrong = []
    for target in sorted(_imports(path)):
        theirs = _layer(target)
        if theirs is None:  # testing: only the app and testing itself may import it
            if mine is not None and mine < RANKS["app"]:
                wrong.append(f"{target} (test oracles stand apart)")
        elif mine is not None and theirs > mine:
            wrong.append(f"{target} (layer {theirs} above {mine})")
    assert not wrong, f"{here} imports upward: {wrong}"


def test_no_import_cycles():
    graph = {_module_name(p): _imports(p) for p in FILES}
    # A package's __init__ re-exporting its submodules is not a cycle with them.
    edges = {m: {t for t in ts if t in graph and not (m == t.rpartition(".")[0] and
                                                       graph.get(m) is not None)}
             for m, ts in graph.items()}
    seen, stack, on_stack, cycles = set(), [], set(), []

    def visit(m):
        seen.add(m)
        stack.append(m)
        on_stack.add(m)
        for t in sorted(edges[m]):
            if t in on_stack:
                cycles.append(stack[stack.index(t):] + [t])
            elif t not in seen:
                visit(t)
        stack.pop()
        on_stack.discard(m)

    for m in sorted(edges):
        if m not in seen:
            visit(m)
    assert not cycles, "import cycles: " + "; ".join(" → ".join(c) for c in cycles)


#: The group modules are one part: each group's cores (``_exp``, ``_compose``, …, the compiled
#: single-element functions behind the public ones) are built from the others'.
GROUP_MODULES = {"so3", "se3", "se2", "sim2", "sim3", "quaternion", "dual_quaternion"}


def _part(module: str) -> str:
    unit = _unit(module)
    return "groups" if unit in GROUP_MODULES else unit


def _private_uses(path: Path) -> list[str]:
    """Private names (``_x``, not dunders) of another part of the package that ``path`` uses:
    imported by name, or read as an attribute of a module it imported."""
    here = _module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    aliases = {}  # local name → module of another part
    found = []

    def private(name: str) -> bool:
        return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))

    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "lie_factors":
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in MODULES:
                    if _part(sub) != _part(here):
                        aliases[alias.asname or alias.name] = sub
                elif private(alias.name) and _part(target) != _part(here):
                    found.append(f"{target}.{alias.name}")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in MODULES and alias.asname and _part(alias.name) != _part(here):
                    aliases[alias.asname] = alias.name
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in aliases and private(node.attr)):
            found.append(f"{aliases[node.value.id]}.{node.attr}")
    return sorted(set(found))


@pytest.mark.parametrize("path", FILES, ids=lambda p: _module_name(p))
def test_no_private_name_crosses_a_package(path):
    used = _private_uses(path)
    assert not used, f"{_module_name(path)} uses private names of another part: {used}"


def _declared_all(module: str) -> set[str] | None:
    """The names of ``module``'s ``__all__`` (read from its source), None where it declares none."""
    path = PACKAGE.parent / Path(*module.split("."))
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
            value = node.value
            if isinstance(value, ast.Call):  # sorted(...) of a literal or of a dict's keys
                value = value.args[0]
            if isinstance(value, ast.Name):  # sorted(_EXPORTS): the dict's keys
                value = next(n.value for n in ast.parse(path.read_text(encoding="utf-8")).body
                             if isinstance(n, ast.Assign) and any(isinstance(t, ast.Name) and t.id == value.id
                                                                  for t in n.targets))
            if isinstance(value, ast.Dict):
                return {k.value for k in value.keys}
            return {e.value for e in value.elts}
    return None


APP_FILES = [p for p in FILES if _unit(_module_name(p)) == "app"]


@pytest.mark.parametrize("path", APP_FILES, ids=lambda p: _module_name(p))
def test_the_app_calls_only_public_names(path):
    """The command line is a shell over the library: every name it imports from the library is in
    that module's ``__all__`` (the app's own modules and the test oracles aside)."""
    here = _module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    wrong = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level:
            base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
            target = ".".join(base + ([node.module] if node.module else []))
        else:
            target = node.module or ""
        if target.split(".")[0] != "lie_factors" or _unit(target) in ("app", APART):
            continue
        public = _declared_all(target)
        for alias in node.names:
            if f"{target}.{alias.name}" in MODULES and _declared_all(f"{target}.{alias.name}") is not None:
                continue
            if alias.name == "__version__" or (public is not None and alias.name in public):
                continue
            wrong.append(f"{target}.{alias.name}")
    assert not wrong, f"{here} imports names outside the library's __all__: {wrong}"


#: The directories of the package whose functions and modules the size limits cover.
SIZE_CHECKED = [""]  # "": the whole package

#: Modules allowed past the soft limit of 600 lines (never past 900): path → the one job each does.
ONE_JOB: dict[Path, str] = {
    PACKAGE / "sim3.py": "the Sim(3) closed forms: exp, log, D_exp and D_log with the series bands "
                         "each needs, one derivation (docs/sim3.md)",
    PACKAGE / "sparse" / "cholmod.py": "the CHOLMOD wrapper: its structures, the factor kept across "
                                       "refactorizations, its two ways in (direct and through cvxopt)",
    PACKAGE / "expressions" / "kernels.py": "the compiled operations of the vocabulary: each one's value "
                                            "and local Jacobians, and the small products of the chain rule",
    PACKAGE / "batch" / "graph.py": "the batch Problem: a graph read into arrays (groups, kinds, native "
                                    "factors), its estimate, and its evaluation, linearization and retraction",
}


@pytest.mark.parametrize("directory", SIZE_CHECKED)
def test_functions_are_short_and_take_few_parameters(directory):
    found = oversized_functions(PACKAGE / directory)
    assert not found, "functions over 150 lines or 12 parameters: " + "; ".join(map(str, found))


@pytest.mark.parametrize("directory", SIZE_CHECKED)
def test_modules_are_small(directory):
    found = oversized_modules(PACKAGE / directory, ONE_JOB)
    assert not found, f"modules over 900 lines, or over 600 and not in ONE_JOB: {found}"


def test_the_size_check_sees_long_functions_many_parameters_and_long_modules(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(150))
    (tmp_path / "long.py").write_text(f"def long():\n{body}\n\n\ndef wide(a, b, c, d, e, f, g, h, i, j, k, l, *m):\n"
                                      "    pass\n\n\nclass C:\n    def fine(self, a, b, c, d, e, f, g, h, i, j, k, l):\n"
                                      "        pass\n")
    (tmp_path / "big.py").write_text("x = 1\n" * 601)
    names = sorted(f.name for f in oversized_functions(tmp_path))
    assert names == ["long", "wide"]
    assert oversized_modules(tmp_path) == ["big.py (601 lines)"]
    assert oversized_modules(tmp_path, {tmp_path / "big.py": "one job"}) == []
    (tmp_path / "big.py").write_text("x = 1\n" * 901)
    assert oversized_modules(tmp_path, {tmp_path / "big.py": "one job"}) == ["big.py (901 lines)"]
