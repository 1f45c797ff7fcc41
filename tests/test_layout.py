"""The package's layers: every import points down, and no module imports itself back.

Layers, bottom up (docs/architecture.md):

0. utilities: ``errors``, ``stack``, ``atomic``, ``timing``, ``arrays``, ``memory``, ``lazy``;
1. kernels: ``kernels.*`` and the group modules (``so3`` … ``sim3``, ``quaternion``,
   ``dual_quaternion``);
2. ``factors``;
3. solvers: ``lm``, ``pose_graph``, ``topology``, ``batch``, ``incremental``, ``optimizers``,
   ``initialization``, ``dropin``;
4. g2o I/O: ``g2o``;
5. the app: ``app``.

``testing`` (oracles and generators) stands apart: no library module imports it; the app may
(``lie-factors crosscheck`` prints the oracles' verdicts).  Every import counts, at module level
or inside a function: a deferred import is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "lie_factors"

LAYERS = {
    "errors": 0, "stack": 0, "atomic": 0, "timing": 0, "arrays": 0, "memory": 0, "lazy": 0,
    "kernels": 1, "so3": 1, "se3": 1, "se2": 1, "sim2": 1, "sim3": 1, "quaternion": 1,
    "dual_quaternion": 1,
    "factors": 2,
    "lm": 3, "pose_graph": 3, "topology": 3, "batch": 3, "incremental": 3, "optimizers": 3,
    "initialization": 3,
    "dropin": 3,
    "g2o": 4,
    "app": 5,
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
    unit = _unit(module)
    if unit == "":
        return 0  # the package's own __init__
    if unit == APART:
        return None
    return LAYERS[unit]


def test_every_module_has_a_layer():
    unknown = sorted({_unit(m) for m in MODULES} - set(LAYERS) - {"", APART})
    assert not unknown, f"modules outside the layer table: {unknown}"


@pytest.mark.parametrize("path", FILES, ids=lambda p: _module_name(p))
def test_imports_point_down(path):
    here = _module_name(path)
    mine = _layer(here)
    wrong = []
    for target in sorted(_imports(path)):
        theirs = _layer(target)
        if theirs is None:  # testing: only the app and testing itself may import it
            if mine is not None and mine < LAYERS["app"]:
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
