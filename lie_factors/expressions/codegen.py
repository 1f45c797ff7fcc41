"""The compiled kernel of a factor kind, generated from its residual's expression.

:func:`generate` writes the source of one numba kernel that evaluates every factor of the kind
in a range: the residual's nodes in order, each a call of its compiled operation
(:mod:`lie_factors.expressions.kernels`), then, with ``jacobians``, the chain rule: the
Jacobian of node k with respect to variable j is

    J_k,j = Σ over the inputs i of k that depend on j of  D_k,i · J_i,j        (J_j,j = I)

where D_k,i is the operation's local Jacobian (a matrix it computes, or ±I, a constant or
computed factor, a diagonal, a constant matrix, a selection of rows, a place among rows, a
matrix product's factor).  Then the residual r is whitened: b = −R·e, sq = ‖R·e‖², A_j = R·J_r,j.

An operation undefined at some values (a point behind a camera, a division by zero) returns
False there; the kernel records the first such node of each factor (``status[f]`` = its
index + 1), a residual that is not finite (``status[f]`` = the number of nodes + 1), or, where
``ops.catch_cheirality`` took a projection's fault and gave its fallback instead, minus the
projection's index + 1; 0 when all is well.  :mod:`lie_factors.expressions.kind` turns a status
into GTSAM's behaviour: an exception, or the fallback.  :func:`load` writes the source to a file named by its
digest (with the package's and numba's: a kernel never links an edited callee) under the
cache directory and imports it, so numba caches the compiled kernel like any other.

The kernel's arguments, in order: the group tags its operations need (``G_Pose3`` …), then for
each variable j its values ``X<j>`` ((N, m, m) elements or (N, d) vectors) and the index of each
factor's in them ``I<j>`` (F,), then each constant ``C<c>`` (F, …), then ``R`` (U, m, m), ``ridx``
(F,), the outputs ``e`` (F, m), ``A`` (F, m, Σ d_j), ``b`` (F, m), ``sq`` (F,), ``status`` (F,)
int64, and ``f0``, ``f1``, ``jacobians``.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
from pathlib import Path

import numpy as np

from .expr import Node
from .rules import CHEIRALITY
from .types import ValueType

#: How an input's local Jacobian enters the chain rule (see the module docstring).
MATRIX, EYE, NEG, SCALE, CONST, SELECT, PLACE = "matrix", "eye", "neg", "scale", "const", "select", "place"
DIAG, LEFT, RIGHT = "diag", "left", "right"

#: The operations that run a group's cores through its tag.
_TAGGED = ("compose", "inverse", "between", "localCoordinates", "logmap", "retract", "expmap", "matrix",
           "adjoint_map")


def topological(residual: Node) -> list[Node]:
    """The nodes ``residual`` depends on, each after its inputs (one entry per node object)."""
    order, seen = [], set()
    stack = [(residual, False)]
    while stack:
        node, done = stack.pop()
        if done:
            order.append(node)
            continue
        if id(node) in seen:
            continue
        seen.add(id(node))
        stack.append((node, True))
        for x in reversed(node.inputs):
            if id(x) not in seen:
                stack.append((x, False))
    return order


class _Writer:
    def __init__(self):
        self.lines: list[str] = []

    def __call__(self, indent: int, text: str) -> None:
        self.lines.append("    " * indent + text)


def _shape(t: ValueType) -> str:
    return "(" + ", ".join(str(s) for s in t.shape) + ("," if len(t.shape) == 1 else "") + ")"


def _floats(values) -> str:
    return "[" + ", ".join(repr(float(x)) for x in values) + "]"


class Generator:
    """The source of one kind's kernel (see the module docstring)."""

    def __init__(self, name: str, variables: list[ValueType], constants: list[ValueType], residual: Node):
        self.name = name
        self.variables = variables
        self.constants = constants
        self.residual = residual
        self.nodes = topological(residual)
        self.k = {id(n): i for i, n in enumerate(self.nodes)}
        self.deps: dict[int, tuple] = {}
        for n in self.nodes:
            if n.op == "variable":
                self.deps[id(n)] = (n.attrs["index"],)
            else:
                self.deps[id(n)] = tuple(sorted({j for x in n.inputs for j in self.deps[id(x)]}))
        self.tags = sorted({x.type.name for n in self.nodes for x in (n, *n.inputs)
                            if x.type.is_group and x.type.group is not None and self._uses_tag(n)})
        self.globals: list[str] = [f"L{self.k[id(n)]} = np.array({_floats(n.attrs['value'])})"
                                   for n in self.nodes if n.op == "literal"]
        self.catches = any(n.op == "catch_cheirality" for n in self.nodes)
        self.plans = {id(n): self._plan(n) for n in self.nodes if not self._stored(n)}

    #: the status of a factor whose residual is not finite
    @property
    def nonfinite(self) -> int:
        return len(self.nodes) + 1

    @staticmethod
    def _uses_tag(n: Node) -> bool:
        return n.op in _TAGGED and not (n.inputs and n.inputs[0].type.name == "Rot2")

    @staticmethod
    def _stored(n: Node) -> bool:
        """Whether ``n`` needs no code of its own: an input, a literal, or a view of its input."""
        return n.op in ("variable", "constant", "literal", "flatten")

    # ------------------------------------------------------------------ names
    def v(self, n: Node) -> str:
        if n.op == "flatten":  # the same entries, row by row
            return self.v(n.inputs[0])
        return f"{'L' if n.op == 'literal' else 'v'}{self.k[id(n)]}"

    def J(self, n: Node, j: int) -> str:
        if n.op == "variable":
            return f"E{self.variables[j].dim}"
        if n.op == "flatten":
            return self.J(n.inputs[0], j)
        return f"J{self.k[id(n)]}_{j}"

    def D(self, n: Node, r: int) -> str:
        return f"D{self.k[id(n)]}_{r}"

    def _global(self, text: str) -> str:
        self.globals.append(text)
        return text.split(" = ", 1)[0]

    # ------------------------------------------------------------------ source
    def source(self) -> str:
        w = _Writer()
        args = [f"G_{t}" for t in self.tags]
        for j in range(len(self.variables)):
            args += [f"X{j}", f"I{j}"]
        args += [f"C{c}" for c in range(len(self.constants))]
        args += ["R", "ridx", "e", "A", "b", "sq", "status", "f0", "f1", "jacobians"]
        body = _Writer()
        self._allocate(body)
        body(1, "for f in range(f0, f1):")
        body(2, "fault = 0")
        if self.catches:
            body(2, "caught = 0")
        for n in self.nodes:
            self._node(body, n)
        self._outputs(body)
        w(0, "@kernel")
        w(0, f"def evaluate({', '.join(args)}):")
        w(1, f'"""The residual and Jacobians of the factors f0 … f1 − 1 of the kind {self.name}."""')
        head = ["# Generated by lie_factors.expressions.codegen for the factor kind "
                f"{self.name}: its residual's expression, compiled.", "import math", "",
                "import numpy as np", "", "from lie_factors.expressions import camera as Cam",
                "from lie_factors.expressions import kernels as K", "from lie_factors.kernels.jit import kernel", ""]
        return "\n".join(head + self.globals + ["", ""] + w.lines + body.lines) + "\n"

    def _allocate(self, w) -> None:
        dims = sorted({t.dim for t in self.variables})
        for d in dims:
            w(1, f"E{d} = np.eye({d})")
        for n in self.nodes:
            if self._stored(n):
                continue
            w(1, f"{self.v(n)} = np.empty({_shape(n.type)})")
            for j in self.deps[id(n)]:
                w(1, f"{self.J(n, j)} = np.empty(({n.type.dim}, {self.variables[j].dim}))")
            for r, (form, _) in enumerate(self.plans[id(n)][0]):
                if form == MATRIX:
                    w(1, f"{self.D(n, r)} = np.empty(({n.type.dim}, {n.inputs[r].type.dim}))")
        m = self.residual.type.dim
        w(1, f"scratch = np.empty({m})")

    def _node(self, w, n: Node) -> None:
        k = self.k[id(n)]
        if n.op == "variable":
            j = n.attrs["index"]
            w(2, f"v{k} = X{j}[I{j}[f]]")
            return
        if n.op == "constant":
            w(2, f"v{k} = C{n.attrs['index']}[f]")
            return
        if self._stored(n):
            return
        forms, lines, checked = self.plans[id(n)]
        if checked:  # the last line is a call that returns False where the operation is undefined
            *lines, call = lines
            lines += [f"if not {call} and fault == 0:", f"    fault = {k + 1}"]
        for line in lines:
            w(2, line)
        chain = self._catch_chain(n) if n.op == "catch_cheirality" else self._chain(n, forms)
        if chain:
            w(2, "if jacobians:")
            for line in chain:
                w(3, line)

    # ------------------------------------------------------------------ operations
    def _plan(self, n: Node) -> tuple[list, list[str], bool]:
        """(how each input's local Jacobian enters, the value's lines, whether the last line is
        a call that returns False where the operation is undefined)."""
        op, ins = n.op, n.inputs
        a = self.v(ins[0]) if ins else None
        b = self.v(ins[1]) if len(ins) > 1 else None
        out, D0 = self.v(n), self.D(n, 0)
        D1 = self.D(n, 1) if len(ins) > 1 else None
        t0 = ins[0].type if ins else None
        if op in _TAGGED[:7]:
            return self._group_op(n, a, b, out, D0, D1)
        if op in ("rotation", "translation", "scale"):
            return [(MATRIX, None)], [self._part(n, a, out, D0)], False
        if op in ("transformFrom", "transformTo", "rotate", "unrotate"):
            kind = 0 if t0.name in ("Rot2", "Rot3") else 2 if t0.name.startswith("Similarity") else 1
            fn = "transform_from" if op in ("transformFrom", "rotate") else "transform_to"
            call = f"K.{fn}({a}, {t0.rot}, {kind}, {b}, {out}, {D0}, {D1}, jacobians)"
            return [(MATRIX, None), (MATRIX, None)], [call], False
        if op in _CALLS:
            module, fn, checked = _CALLS[op]
            if op == "bearing" and t0.dim == 3:
                fn = "unit3_of"
            if op == "uncalibrate":
                fn = _UNCALIBRATE[t0.name]
            if op in ("matrix", "adjoint_map"):
                fn = "r2_matrix" if t0.name == "Rot2" else fn
                tag = [] if t0.name == "Rot2" else [f"G_{t0.name}"]
            else:
                tag = []
            Ds = [self.D(n, r) for r in range(len(ins))]
            call = f"{module}.{fn}({', '.join(tag + [self.v(x) for x in ins] + [out] + Ds)}, jacobians)"
            return [(MATRIX, None)] * len(ins), [call], checked
        return getattr(self, f"_op_{op}")(n, a, b, out)

    def _group_op(self, n: Node, a, b, out, D0, D1):
        op, t0 = n.op, n.inputs[0].type
        if op == "expmap":
            if n.type.name == "Rot2":
                return [(EYE, None)], [f"K.r2_expmap({a}, {out})"], False
            return [(MATRIX, None)], [f"K.g_expmap(G_{n.type.name}, {a}, {out}, {D0}, jacobians)"], False
        if t0.name == "Rot2":  # derivatives ±1: identities in the chain rule
            forms = {"compose": [(EYE, None), (EYE, None)], "between": [(NEG, None), (EYE, None)],
                     "inverse": [(NEG, None)], "logmap": [(EYE, None)],
                     "localCoordinates": [(NEG, None), (EYE, None)], "retract": [(EYE, None), (EYE, None)]}[op]
            name = "local" if op == "localCoordinates" else op
            return forms, [f"K.r2_{name}({', '.join([a] + ([b] if b else []))}, {out})"], False
        tag = f"G_{t0.name}"
        if op in ("compose", "between"):
            return [(MATRIX, None), (EYE, None)], [f"K.g_{op}({tag}, {a}, {b}, {out}, {D0}, jacobians)"], False
        if op in ("inverse", "logmap"):
            return [(MATRIX, None)], [f"K.g_{op}({tag}, {a}, {out}, {D0}, jacobians)"], False
        if op == "localCoordinates" and t0.kind == "unit":
            return [(MATRIX, None)] * 2, [f"K.unit3_local({a}, {b}, {out}, {D0}, {D1}, jacobians)"], False
        fn = "g_local" if op == "localCoordinates" else "g_retract"
        return [(MATRIX, None)] * 2, [f"K.{fn}({tag}, {a}, {b}, {out}, {D0}, {D1}, jacobians)"], False

    @staticmethod
    def _part(n: Node, a, out, D0) -> str:
        t0 = n.inputs[0].type
        if n.op == "rotation":
            return f"K.rotation_of({a}, {t0.rot}, {out}, {D0}, jacobians)"
        if n.op == "translation":
            first = 3 if t0.rot == 3 else 0
            sim = "True" if t0.name.startswith("Similarity") else "False"
            return f"K.translation_of({a}, {t0.rot}, {first}, {sim}, {out}, {D0}, jacobians)"
        return f"K.scale_of({a}, {out}, {D0}, jacobians)"

    def _loop(self, n: Node, expression: str) -> list[str]:
        return [f"for i in range({n.type.dim}):", f"    {self.v(n)}[i] = {expression}"]

    def _op_add(self, n, a, b, out):
        return [(EYE, None), (EYE, None)], self._loop(n, f"{a}[i] + {b}[i]"), False

    def _op_sub(self, n, a, b, out):
        return [(EYE, None), (NEG, None)], self._loop(n, f"{a}[i] - {b}[i]"), False

    def _op_neg(self, n, a, b, out):
        return [(NEG, None)], self._loop(n, f"-{a}[i]"), False

    def _op_scale_by(self, n, a, b, out):
        factor = n.attrs["factor"]
        return [(SCALE, repr(factor))], self._loop(n, f"{factor!r} * {a}[i]"), False

    def _op_emul(self, n, a, b, out):
        return [(DIAG, b), (DIAG, a)], self._loop(n, f"{a}[i] * {b}[i]"), False

    def _op_smul(self, n, a, b, out):
        call = f"K.v_smul({a}, {b}, {out}, {self.D(n, 0)}, jacobians)"
        return [(MATRIX, None), (SCALE, f"{a}[0]")], [call], False

    def _op_div(self, n, a, b, out):
        call = f"K.v_div({a}, {b}, {out}, {self.D(n, 1)}, jacobians)"
        return [(SCALE, f"1.0 / {b}[0]"), (MATRIX, None)], [call], True

    def _op_matmul(self, n, a, b, out):
        M = self._global(f"M{self.k[id(n)]} = np.array([{', '.join(_floats(row) for row in n.attrs['matrix'])}])")
        lines = [f"for i in range({n.type.dim}):", "    acc = 0.0", f"    for c in range({n.inputs[0].type.dim}):",
                 f"        acc += {M}[i, c] * {a}[c]", f"    {out}[i] = acc"]
        return [(CONST, M)], lines, False

    def _op_mat_mul(self, n, a, b, out):
        r, k, c = n.attrs["r"], n.attrs["k"], n.attrs["c"]
        return [(LEFT, (b, r, k, c)), (RIGHT, (a, r, k, c))], [f"K.mat_product({a}, {b}, {r}, {k}, {c}, {out})"], False

    def _op_select(self, n, a, b, out):
        indices = n.attrs["indices"]
        start = indices[0]
        if indices == tuple(range(start, start + len(indices))):
            return [(SELECT, f"{start} + i")], self._loop(n, f"{a}[{start} + i]"), False
        S = self._global(f"S{self.k[id(n)]} = np.array({list(indices)!r}, dtype=np.int64)")
        return [(SELECT, f"{S}[i]")], self._loop(n, f"{a}[{S}[i]]"), False

    def _op_camera_pose(self, n, a, b, out):
        # the pose is the stored array's first 16 entries; its tangent the camera's first 6
        lines = ["for i in range(4):", "    for c in range(4):", f"        {out}[i, c] = {a}[4 * i + c]"]
        return [(SELECT, "i")], lines, False

    def _op_camera_calibration(self, n, a, b, out):
        # the calibration's entries follow the pose's 16; its tangent follows the pose's 6
        lines = [f"for i in range({n.type.shape[0]}):", f"    {out}[i] = {a}[16 + i]"]
        return [(SELECT, "6 + i")], lines, False

    def _op_stack(self, n, a, b, out):
        lines, forms, off = [], [], 0
        for x in n.inputs:
            lines += [f"for i in range({x.type.dim}):", f"    {out}[{off} + i] = {self.v(x)}[i]"]
            forms.append((PLACE, off))
            off += x.type.dim
        return forms, lines, False

    def _op_catch_cheirality(self, n, a, b, out):
        k = self.k[id(n)]
        below = topological(n.inputs[0])
        codes = [self.k[id(m)] + 1 for m in below if m.op in CHEIRALITY]
        hit = " or ".join(f"fault == {c}" for c in codes) or "False"
        d = n.type.dim
        lines = [f"hit{k} = {hit}", f"if hit{k}:", "    caught = fault", "    fault = 0",
                 f"    for i in range({d}):", f"        {out}[i] = {b}[i]", "else:",
                 f"    for i in range({d}):", f"        {out}[i] = {a}[i]"]
        return [], lines, False

    def _catch_chain(self, n: Node) -> list[str]:
        k, r = self.k[id(n)], n.inputs[0]
        lines = []
        for j in self.deps[id(n)]:
            lines += [f"for i in range({n.type.dim}):", f"    for c in range({self.variables[j].dim}):",
                      f"        {self.J(n, j)}[i, c] = 0.0 if hit{k} else {self.J(r, j)}[i, c]"]
        return lines

    # ------------------------------------------------------------------ chain rule
    def _chain(self, n: Node, forms: list) -> list[str]:
        lines = []
        for j in self.deps[id(n)]:
            target = self.J(n, j)
            terms = [(r, x) for r, x in enumerate(n.inputs) if j in self.deps[id(x)]]
            first = True
            if any(forms[r][0] == PLACE for r, _ in terms):
                lines += [f"for i in range({n.type.dim}):", f"    for c in range({self.variables[j].dim}):",
                          f"        {target}[i, c] = 0.0"]
                first = False
            for r, x in terms:
                lines += self._term(n, r, x, j, target, forms[r], first)
                first = False
        return lines

    def _term(self, n: Node, r: int, x: Node, j: int, target: str, form, first: bool) -> list[str]:
        kind, param = form
        src = self.J(x, j)
        dj = self.variables[j].dim
        op = "=" if first else "+="
        if kind == MATRIX:
            D = self.D(n, r)
            if x.op == "variable":  # J_x,j = I
                return [f"K.{'copy2' if first else 'add2'}({D}, {target}, 1.0)"]
            return [f"K.{'mm_set' if first else 'mm_add'}({D}, {src}, {target})"]
        if kind in (EYE, NEG, SCALE):
            sign = {EYE: "1.0", NEG: "-1.0"}.get(kind, param)
            return [f"K.{'copy2' if first else 'add2'}({src}, {target}, {sign})"]
        if kind == CONST:
            return [f"K.{'mm_set' if first else 'mm_add'}({param}, {src}, {target})"]
        if kind == DIAG:
            return [f"for i in range({n.type.dim}):", f"    for c in range({dj}):",
                    f"        {target}[i, c] {op} {param}[i] * {src}[i, c]"]
        if kind == SELECT:
            return [f"for i in range({n.type.dim}):", f"    for c in range({dj}):",
                    f"        {target}[i, c] {op} {src}[{param}, c]"]
        if kind == PLACE:
            return [f"for i in range({x.type.dim}):", f"    for c in range({dj}):",
                    f"        {target}[{param} + i, c] += {src}[i, c]"]
        if kind in (LEFT, RIGHT):
            other, rows, inner, cols = param
            fn = "mat_chain_left" if kind == LEFT else "mat_chain_right"
            pair = f"{src}, {other}" if kind == LEFT else f"{other}, {src}"
            return [f"K.{fn}({pair}, {rows}, {inner}, {cols}, {target}, {first})"]
        raise AssertionError(kind)

    def _outputs(self, w) -> None:
        r = self.residual
        m = r.type.dim
        e = self.v(r)
        w(2, "Rf = R[ridx[f]]")
        w(2, "total = 0.0")
        w(2, f"for i in range({m}):")
        w(3, f"e[f, i] = {e}[i]")
        w(3, "acc = 0.0")
        w(3, f"for c in range({m}):")
        w(4, f"acc += Rf[i, c] * {e}[c]")
        w(3, "scratch[i] = acc")
        w(3, "total += acc * acc")
        w(2, "sq[f] = total")
        w(2, "if fault == 0 and not total < math.inf:")
        w(3, f"fault = {self.nonfinite}")
        w(2, "status[f] = fault" + (" if fault != 0 else -caught" if self.catches else ""))
        w(2, "if jacobians:")
        w(3, f"for i in range({m}):")
        w(4, "b[f, i] = -scratch[i]")
        offset = 0
        for j, t in enumerate(self.variables):
            w(3, f"for i in range({m}):")
            w(4, f"for c in range({t.dim}):")
            if j in self.deps[id(r)]:
                w(5, "acc = 0.0")
                w(5, f"for q in range({m}):")
                w(6, f"acc += Rf[i, q] * {self.J(r, j)}[q, c]")
                w(5, f"A[f, i, {offset} + c] = acc")
            else:
                w(5, f"A[f, i, {offset} + c] = 0.0")
            offset += t.dim


#: Operations that are one call of a compiled function on the inputs' values, the output and one
#: local Jacobian per input: (module, function, whether it returns False where undefined).
_CALLS = {"norm": ("K", "v_norm", False), "dot": ("K", "v_dot", False), "cross": ("K", "v_cross", False),
          "bearing": ("K", "bearing2", False), "rpy": ("K", "rot3_rpy", True), "matrix": ("K", "g_matrix", False),
          "adjoint_map": ("K", "g_adjoint_map", False), "pinhole": ("Cam", "pinhole", True),
          "uncalibrate": ("Cam", None, False), "stereo": ("Cam", "stereo", True)}
_UNCALIBRATE = {"Cal3_S2": "uncalibrate_s2", "Cal3Bundler": "uncalibrate_bundler", "Cal3DS2": "uncalibrate_ds2",
                "Cal3Fisheye": "uncalibrate_fisheye"}


def cache_directory() -> Path:
    """Where generated kernels are written: ``$NUMBA_CACHE_DIR/lie_factors_kinds`` when numba's
    cache directory is set, else ``$XDG_CACHE_HOME/lie-factors/kinds`` (``~/.cache/…``)."""
    numba_dir = os.environ.get("NUMBA_CACHE_DIR")
    if numba_dir:
        return Path(numba_dir) / "lie_factors_kinds"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "lie-factors" / "kinds"


def generated_module(module_name: str):
    """The generated module ``module_name``, written under :func:`cache_directory` by an earlier
    :func:`load` (in this process or another): what a generated module that calls another's
    kernel imports it by."""
    module = sys.modules.get(module_name)
    if module is None:
        module = _import(module_name, cache_directory() / f"{module_name}.py")
    return module


def _import(module_name: str, path: Path):
    spec = importlib.util.spec_from_file_location(module_name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    spec.loader.exec_module(module)
    return module


def load(name: str, source: str):
    """The module of ``source`` (a kind's kernel), written under :func:`cache_directory` in a file
    named by the digest of the source, the package's and numba's versions, then imported."""
    import numba

    from ..kernels.cache import package_digest

    digest = hashlib.sha256("\0".join((source, package_digest(), numba.__version__)).encode()).hexdigest()[:20]
    module_name = f"lie_factors_kind_{_identifier(name)}_{digest}"
    if module_name in sys.modules:
        return sys.modules[module_name]
    directory = cache_directory()
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{module_name}.py"
    if not path.exists() or path.read_text(encoding="utf-8") != source:
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text(source, encoding="utf-8")
        os.replace(tmp, path)  # atomic: another process writing the same kind writes the same text
    return _import(module_name, path)


def _identifier(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name)[:40]
