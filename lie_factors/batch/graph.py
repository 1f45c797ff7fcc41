"""Reading a NonlinearFactorGraph + Values into arrays; linearizing, evaluating, retracting them.

* lie_factors factors with Gaussian noise are grouped by (kind, group): their
  constants (``M⁻¹``, ``Ad(M⁻¹)``, whitening ``R``, variable indices) become
  arrays, and the numba loops of :mod:`lie_factors.batch.loops` linearize and
  evaluate a whole group per call;
* factors of a kind (:mod:`lie_factors.expressions`: a user's own, the ready ones) with
  Gaussian noise are grouped by kind (:mod:`lie_factors.batch.kinds`): their keys, constants
  and whitening become arrays, and the kind's kernel linearizes and evaluates them in one call;
  their variables of other types (Rot2, points, vectors, calibrations) are arrays too;
* GTSAM's own factors with a twin kind (:mod:`lie_factors.expressions.twins`: GTSAM's
  Between, Prior, projection, range, bearing, … factors) with Gaussian noise join their twin
  kind's group, as that kind's own factors do;
* every other factor (native GTSAM factors on any variable type — Pose2/3,
  Point2/3 landmarks, ... — and factors with robust or constrained
  noise) is *native*: GTSAM linearizes it (one ``NonlinearFactorGraph.linearize``
  call), and its augmented information matrix is copied into one flat array for
  the assembly kernel;
* a native factor with a constrained noise model (``noiseModel.Constrained``, a
  ``NonlinearEquality``) is a hard constraint: its rows of σ = 0 enter that matrix
  with GTSAM's weight μ (its ``squaredMahalanobisDistance``, as its error does), and
  one that fixes a whole variable (one key, every row constrained, as many rows as
  the variable's dimension) *pins* it: each linearization solves A·δ = b for its step
  (:attr:`Problem.pin_steps`), which the linear system then imposes
  (:meth:`lie_factors.batch.system.LinearSystem.holding`); any other constrained factor
  needs GTSAM's elimination (:attr:`Problem.general_constraints`);
* the elements of each group are an ``(N, m, m)`` array; other variables stay
  in a ``gtsam.Values`` and are retracted by GTSAM.

Variables are numbered in key order among those some factor touches (the
columns of the linear system); a variable in no factor never moves (GTSAM's
damped step for it is 0).
"""

from __future__ import annotations

from types import SimpleNamespace

import gtsam
import numpy as np

from .. import factors as _factors
from ..errors import InputError, first_line, nonfinite_error
from ..expressions.kind import KindFactor
from ..expressions.twins import TABLE, evaluable, twin_row
from .. import interop
from ..posegraph import gauge
from ..robust.losses import from_gtsam
# noise_whitening and whitening are imported from here by the incremental smoother, whitening by the tests
from .groups import FactorGroup, VarBlock, noise_whitening, unique_rows, whitening  # noqa: F401
from .kinds import KindGroup, ValueBlock, block_name


def key_name(key: int) -> str:
    return gtsam.DefaultKeyFormatter(int(key))


def describe_factor(graph, k: int) -> str:
    """`` (Type on x1, l2)`` of factor ``k`` of ``graph`` ('' without a graph or factor)."""
    f = graph.at(k) if graph is not None else None
    return "" if f is None else f" ({type(f).__name__} on {', '.join(key_name(key) for key in f.keys())})"


def _robust_loss(noise_model):
    return from_gtsam(noise_model.robust())


def _read_matrices(values: gtsam.Values, spec, keys: list) -> np.ndarray:
    """(N, m, m) matrices of ``keys`` in ``values``; InputError naming a missing/mistyped key."""
    try:
        return interop.matrices_from_values(values, spec.name, keys)
    except KeyError as exc:
        raise InputError(f"key {key_name(exc.args[0])} is used by a {spec.name} factor "
                         "but is missing from the initial Values") from None
    except TypeError as exc:
        raise InputError(f"key {key_name(exc.args[0])} must hold a gtsam.{spec.name} "
                         f"(it is used by a {spec.name} factor)") from None


def _constrained_rows(nm) -> tuple[np.ndarray, np.ndarray]:
    """(row scale (r,), hard (r,) bool) of a ``noiseModel.Constrained``: GTSAM's whitening leaves its
    rows of σ = 0 as they are, and its Mahalanobis distance weighs them by μ, so ``scale`` is √μ
    there and 1 elsewhere; ``hard`` marks those rows."""
    sigmas = np.asarray(nm.sigmas(), dtype=np.float64)
    hard = sigmas == 0.0
    weights = np.array([nm.squaredMahalanobisDistance(row) for row in np.eye(len(sigmas))])
    return np.where(hard, np.sqrt(weights), 1.0), hard


def matrices_of(values: gtsam.Values, group: str, keys) -> np.ndarray:
    """(N, m, m) element matrices of ``keys`` in ``values``, each a gtsam ``group`` (Pose3, ...)."""
    return _read_matrices(values, _factors.GROUPS[group], [int(k) for k in keys])


def to_gtsam(spec, M: np.ndarray):
    """The GTSAM object of the element matrix ``M``."""
    return interop.to_gtsam(spec.name, M)


class Problem:
    """The graph's variables and factors as arrays, and the current estimate.

    State: ``blocks[name].X`` (group elements) and ``other`` (a gtsam.Values
    with every other variable).  ``var_keys``/``var_dims`` (V,) are the
    variables of the linear system, ``offset[key]`` their scalar offsets.
    """

    def __init__(self, graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values,
                 group_robust: bool = False):
        if not isinstance(graph, gtsam.NonlinearFactorGraph):
            raise TypeError(f"graph must be a gtsam.NonlinearFactorGraph, got {type(graph).__name__}")
        if not isinstance(initial, gtsam.Values):
            raise TypeError(f"initial must be a gtsam.Values, got {type(initial).__name__}")
        self.graph = graph
        self.graph_size = int(graph.size())
        self.blocks: dict[str, VarBlock] = {}
        self.value_blocks: dict[str, ValueBlock] = {}
        self.groups: list[FactorGroup] = []
        self.kinds: list[KindGroup] = []
        self.native: list = []  # (graph index, factor, keys)
        # graph index → batch.robust.RobustLoss of robust factors grouped by their Gaussian part
        # (only with group_robust: the optimizer must then apply the loss).
        self.robust: dict = {}
        self._group_robust = bool(group_robust)
        self._read_factors(graph, initial)
        self._number_variables(initial)

    @classmethod
    def from_pose_graph(cls, pg, X: np.ndarray) -> "Problem":
        """A :class:`lie_factors.posegraph.graph.PoseGraph`'s factors, with no factor object: its between
        factors, then its priors, starting from the elements ``X`` (P, m, m) in ``pg.keys`` order.

        Factor k < E is Between(key1, key2, M_k) with error Log(M⁻¹·X1⁻¹·X2),
        factor E + q the q-th prior; whitening R = chol(Λ)ᵀ (RᵀR = Λ, upper
        triangular, as ``noiseModel.Gaussian.Information``), one per distinct Λ.
        The constant M⁻¹ comes from ``factors.between_setup``, the kernel a factor's
        construction runs (which also checks each M).  Every key of a factor
        must be in ``pg.keys``; a self-loop edge is refused.
        """
        spec = _factors.GROUPS[pg.group]
        self = cls.__new__(cls)
        self.graph = None
        keys = np.asarray(pg.keys, dtype=np.int64)
        E, Q = len(pg.edge_keys), len(pg.prior_keys)
        self.graph_size = E + Q
        self.native, self.robust, self._group_robust = [], {}, False
        self.value_blocks, self.kinds = {}, []
        block = VarBlock(spec)
        self.blocks = {spec.name: block}
        self.groups = []
        edge_keys = np.asarray(pg.edge_keys, dtype=np.int64).reshape(E, 2)
        if E and (edge_keys[:, 0] == edge_keys[:, 1]).any():
            raise InputError("from_pose_graph: an edge connects a key to itself")

        def constants(M, what):
            Minv, codes = block.loops.setup(M)
            bad = np.flatnonzero(codes != _factors.OK)
            if bad.size:
                k = int(bad[0])
                raise InputError(str(_factors.element_error(spec, np.asarray(M[k]), int(codes[k]),
                                                             f"{what} {k}", "from_pose_graph")))
            return Minv

        def whitenings(information):
            """(R of each distinct information matrix, the index of each factor's)."""
            table, index = unique_rows(np.asarray(information, dtype=np.float64).reshape(len(information), -1))
            return whitening(table.reshape(-1, spec.dim, spec.dim)), index

        if E:
            g = FactorGroup("between", spec)
            g.rows = None
            k1, k2 = edge_keys[:, 0].astype(np.uint64), edge_keys[:, 1].astype(np.uint64)
            block.use_keys(k1)
            block.use_keys(k2)
            g.columns = (np.arange(E), k1, k2, constants(pg.measured, "measured"), whitenings(pg.information))
            self.groups.append(g)
        if Q:
            g = FactorGroup("prior", spec)
            g.rows = None
            pk = np.asarray(pg.prior_keys, dtype=np.uint64)
            block.use_keys(pk)
            g.columns = (E + np.arange(Q), pk, None, constants(np.asarray(pg.prior_measured, dtype=np.float64), "prior"),
                         whitenings(pg.prior_information))
            self.groups.append(g)
        block.number_keys()
        used = block._sorted.astype(np.int64)
        pos = np.searchsorted(keys, used)
        if len(used) and (pos.max() >= len(keys) or (keys[np.minimum(pos, len(keys) - 1)] != used).any()):
            missing = used[(pos >= len(keys)) | (keys[np.minimum(pos, len(keys) - 1)] != used)][0]
            raise InputError(f"key {key_name(missing)} is used by a {spec.name} factor "
                             "but has no initial element")
        X = np.asarray(X, dtype=np.float64)
        # every key used, in order: the start itself (never written in place), else its rows
        block.X = X if len(pos) == len(X) and X.flags.c_contiguous and np.array_equal(pos, np.arange(len(X))) \
            else np.ascontiguousarray(X[pos])
        for g in self.groups:
            g.finalize(block)
        self.managed = dict.fromkeys(block.keys, spec.name)
        self._native_keys = []
        n = spec.dim
        P = len(block.keys)
        self.var_keys = block.keys
        self.var_dims = np.full(P, n, dtype=np.int64)
        self.var_index = dict(zip(block.keys, range(P)))
        self.var_offsets = n * np.arange(P, dtype=np.int64)
        self.offset = dict(zip(block.keys, self.var_offsets.tolist()))
        self.total_dim = n * P
        block.var = np.arange(P, dtype=np.int64)
        block.offsets = self.var_offsets
        block.X0 = block.X  # the start, kept: X is replaced, never written in place
        for g in self.groups:
            g.v1, g.o1 = block.var[g.i1], block.offsets[g.i1]
            if g.kind == "between":
                g.v2, g.o2 = block.var[g.i2], block.offsets[g.i2]
        self.other = gtsam.Values()
        self._managed_initial = None  # values() builds the GTSAM objects from the matrices
        self.other_keys = []
        self._native_setup()
        return self

    # ---------------------------------------------------------------- reading
    def _read_factors(self, graph, initial):
        groups: dict = {}
        kinds: dict = {}
        # id(noise model) → (noise model, R or None, robust loss or None). Graphs share
        # noise model objects among many factors (posegraph.build_graph shares equal
        # ones); holding the object keeps its id from being reused while we read.
        whitening: dict = {}
        conversions: dict = {}  # a twin's reader's: id(calibration) → (object, array)
        at = graph.at
        for i in range(graph.size()):
            f = at(i)
            if f is None:
                continue
            cls = type(f)
            entry = kinds.get(cls)
            if entry is None:
                entry = kinds[cls] = self._class_entry(cls, groups)
            kind, rows = entry
            R = None
            row = f
            if kind == "twin":
                read = twin_row(f, conversions)
                if read is not None:
                    row, nm = read
                    R = self._row_whitening(i, nm, whitening, row)
            elif kind is not None:
                R = self._row_whitening(i, f._noise, whitening)
                if kind == "between" and f._key1 == f._key2:
                    R = None  # a factor on one variable twice: GTSAM's linearization handles it
                    self.robust.pop(i, None)
            if R is None:
                if not isinstance(f, gtsam.NonlinearFactor):
                    raise InputError(f"factor {i}: unsupported type {type(f).__name__}")
                keys = [int(k) for k in f.keys()]
                for k in keys:
                    if not initial.exists(k):
                        raise InputError(f"factor {i} ({type(f).__name__}): key {key_name(k)} "
                                         "is missing from the initial Values")
                self.native.append((i, f, keys))
                continue
            if kind in ("expression", "twin"):
                rows.add(i, row, R)
            elif kind == "between":
                rows.append((i, f._key1, f._key2, f._Minv, R))
            else:
                rows.append((i, f._key2, None, f._Minv, R))
        for g in self.groups:
            g.close_rows(self.blocks[g.spec.name])
        for kg in self.kinds:
            kg.close_rows(self)
        for block in (*self.blocks.values(), *self.value_blocks.values()):
            block.number_keys()

    def _class_entry(self, cls, groups: dict) -> tuple:
        """(how factors of class ``cls`` are read, where their rows go): ``"between"`` or
        ``"prior"`` (ours: a FactorGroup's rows), ``"expression"`` (a kind's factor: its
        KindGroup), ``"twin"`` (GTSAM's factor with a twin kind, :mod:`lie_factors.expressions.twins`:
        that kind's KindGroup), or (None, None): native."""
        kind = ("between" if issubclass(cls, _factors.BetweenFactor)
                else "prior" if issubclass(cls, _factors.PriorFactor)
                else "expression" if issubclass(cls, KindFactor) else None)
        if kind == "expression":
            return kind, self._kind_group(cls.kind)
        if kind is None:
            twin = TABLE.get(cls)
            return ("twin", self._kind_group(twin.kind)) if twin is not None else (None, None)
        spec = cls.spec
        self.blocks.setdefault(spec.name, VarBlock(spec))
        g = groups.get((kind, spec.name))
        if g is None:
            g = groups[(kind, spec.name)] = FactorGroup(kind, spec)
            self.groups.append(g)
        return kind, g.rows

    def _kind_group(self, kind) -> KindGroup:
        kg = next((k for k in self.kinds if k.kind is kind), None)
        if kg is None:
            kg = KindGroup(kind)
            self.kinds.append(kg)
        return kg

    def _row_whitening(self, i: int, nm, whitening: dict, twin=None):
        """R of factor ``i``'s noise model ``nm`` (read once per noise model object), its robust
        loss recorded in :attr:`robust`; None where GTSAM must linearize the factor, as for a
        ``twin`` row its kind does not evaluate (:func:`lie_factors.expressions.twins.evaluable`)."""
        w = whitening.get(id(nm))
        if w is None:
            w = whitening[id(nm)] = (nm, *self._whitening_of(nm))
        R = w[1]
        if R is None or (twin is not None and not evaluable(twin, R)):
            return None
        if w[2] is not None:
            self.robust[i] = w[2]
        return R

    def block_of_type(self, t):
        """The block holding variables of the expression type ``t``: the group's VarBlock for a
        registered matrix group, else the type's :class:`~lie_factors.batch.kinds.ValueBlock`."""
        group = t.is_group and t.group is not None
        blocks = self.blocks if group else self.value_blocks
        block = blocks.get(t.name)
        if block is None:  # (made only when missing: a VarBlock sets up its group's loops)
            block = blocks[t.name] = VarBlock(_factors.GROUPS[t.name]) if group else ValueBlock(t)
        return block

    def _whitening_of(self, nm):
        """(R, robust loss) of a lie_factors factor's noise model; R None if GTSAM must linearize."""
        if type(nm) in (gtsam.noiseModel.Gaussian, gtsam.noiseModel.Diagonal,
                        gtsam.noiseModel.Isotropic, gtsam.noiseModel.Unit):
            return nm.R(), None
        R = noise_whitening(nm)
        if R is None and self._group_robust and isinstance(nm, gtsam.noiseModel.Robust):
            # Robust(Block estimator we vectorize, Gaussian): grouped by its Gaussian
            # part; the loss goes to self.robust (see batch.robust).
            loss = _robust_loss(nm)
            if loss is not None:
                R = noise_whitening(nm.noise())
                if R is not None:
                    return R, loss
        return R, None

    def _number_variables(self, initial):
        managed = {}
        for name, block in (*self.blocks.items(), *self.value_blocks.items()):
            for k in block.keys:
                if k in managed:
                    raise InputError(f"key {key_name(k)} is used by both {managed[k]} and "
                                     f"{name} factors")
                managed[k] = name
            if name in self.blocks:
                block.X = _read_matrices(initial, block.spec, block.keys)
            else:
                block.read(initial)
        for g in self.groups:
            g.finalize(self.blocks[g.spec.name])
        self.managed = managed
        native_keys = sorted({k for _, _, ks in self.native for k in ks})
        self._native_keys = native_keys
        zero = initial.zeroVectors() if self.native else None
        active = sorted(set(managed) | set(native_keys))
        dims = []
        for k in active:
            name = managed.get(k)
            dims.append(self._dim_of(name) if name is not None else int(np.asarray(zero.at(k)).shape[0]))
        self.var_keys = active
        self.var_dims = np.array(dims, dtype=np.int64)
        self.var_index = {k: v for v, k in enumerate(active)}
        offs = np.zeros(len(active), dtype=np.int64)
        if len(active) > 1:
            np.cumsum(self.var_dims[:-1], out=offs[1:])
        self.var_offsets = offs
        self.offset = dict(zip(active, offs.tolist()))
        self.total_dim = int(self.var_dims.sum())
        for block in (*self.blocks.values(), *self.value_blocks.values()):
            block.var = np.array([self.var_index[k] for k in block.keys], dtype=np.int64)
            block.offsets = offs[block.var]
            block.X0 = block.X.copy()
        for kg in self.kinds:
            kg.finalize(self)
        for g in self.groups:
            b = self.blocks[g.spec.name]
            g.v1, g.o1 = b.var[g.i1], b.offsets[g.i1]
            if g.kind == "between":
                g.v2, g.o2 = b.var[g.i2], b.offsets[g.i2]
        # Variables not in a group (landmarks, ...), incl. those in no factor.
        unmanaged = [int(k) for k in initial.keys() if int(k) not in managed]
        if unmanaged:
            self.other = gtsam.Values(initial)
            for k in managed:
                self.other.erase(k)
            self._managed_initial = gtsam.Values(initial)
            for k in unmanaged:
                self._managed_initial.erase(k)
        else:  # a pure pose graph: no per-key erasing
            self.other = gtsam.Values()
            self._managed_initial = initial
        self.other_keys = [k for k in native_keys if k not in managed]
        self._native_setup()

    def _dim_of(self, name: str) -> int:
        block = self.blocks.get(name)
        return block.spec.dim if block is not None else self.value_blocks[name].t.dim

    def _native_setup(self):
        self.native_graph = gtsam.NonlinearFactorGraph()
        for _, f, _ in self.native:
            self.native_graph.push_back(f)
        #: native position → row scale of GTSAM's whitened rows giving Mahalanobis weights (√μ where σ = 0)
        self.constrained: dict[int, np.ndarray] = {}
        self.pins: list[tuple[int, int]] = []  # (native position, variable index) of each pin
        self.general_constraints: list[int] = []  # graph indices of the other constrained factors
        self.pin_steps: list[np.ndarray] = []  # each pin's step at the last linearization
        self.constrained_diagonal = None  # GTSAM's hessianDiagonal minus ours (μ) on constrained rows
        if not self.native:
            self.native_arrays = None
            self.native_pairs = np.zeros((0, 2), dtype=np.int64)
            return
        self._classify_constraints()
        sizes, kv, kl, kd, ks, ps, istart = [], [], [], [], [0], [0], [0]
        pairs, rows, relative = [], [], []
        for _, f, keys in self.native:
            rows.append(int(f.dim()))
            relative.append(gauge.is_relative(f))
            loc = 0
            vs = [self.var_index[k] for k in keys]
            for v in vs:
                kv.append(v)
                kl.append(loc)
                d = int(self.var_dims[v])
                kd.append(d)
                loc += d
            sizes.append(loc)
            ks.append(len(kv))
            ps.append(ps[-1] + len(keys) ** 2)
            istart.append(istart[-1] + (loc + 1) ** 2)
            pairs.extend((a, b) for a in vs for b in vs if a > b)
        self.native_pairs = np.array(pairs, dtype=np.int64).reshape(-1, 2)
        self.native_arrays = SimpleNamespace(
            fidx=np.array([i for i, _, _ in self.native], dtype=np.int64),
            size=np.array(sizes, dtype=np.int64),
            key_var=np.array(kv, dtype=np.int64), key_local=np.array(kl, dtype=np.int64),
            key_dim=np.array(kd, dtype=np.int64), key_start=np.array(ks, dtype=np.int64),
            pair_start=np.array(ps[:-1], dtype=np.int64),
            info_start=np.array(istart[:-1], dtype=np.int64), info=np.zeros(istart[-1]),
            sq=np.zeros(len(self.native)), rows=np.array(rows, dtype=np.int64),
            relative=np.array(relative, dtype=bool),
        )

    def _classify_constraints(self) -> None:
        """The native factors with a constrained noise model: pins and general constraints
        (module docstring).  Read once, from the noise models (shared ones read once)."""
        rows_of: dict = {}
        pinned: set = set()
        for j, (i, f, keys) in enumerate(self.native):
            if not isinstance(f, gtsam.NoiseModelFactor):
                continue
            nm = f.noiseModel()
            if not isinstance(nm, gtsam.noiseModel.Constrained):
                continue
            entry = rows_of.get(id(nm))
            if entry is None:
                entry = rows_of[id(nm)] = (nm, *_constrained_rows(nm))
            _, scale, hard = entry
            self.constrained[j] = scale
            v = self.var_index[keys[0]] if len(keys) == 1 else -1
            if v >= 0 and hard.all() and len(hard) == int(self.var_dims[v]) and v not in pinned:
                self.pins.append((j, v))
                pinned.add(v)
            else:
                self.general_constraints.append(i)
        self._pinning = {j for j, _ in self.pins}
        if self.constrained:
            self.constrained_diagonal = np.zeros(self.total_dim)

    def undetermined(self) -> gauge.Undetermined | None:
        """The first variable of the linear system its structure leaves undetermined
        (:func:`lie_factors.posegraph.gauge.undetermined`: too few rows of factors, or a
        component of relative factors only), by its index in :attr:`var_keys`; None if the
        structure decides nothing.  Between factors are relative, lie_factors' or GTSAM's
        (those GTSAM linearizes: robust ones, say, and their twin kinds); priors anchor; a factor
        of another kind leaves its component to the factorization."""
        V = len(self.var_keys)
        rows = np.zeros(V, dtype=np.int64)
        u, v, anchored = [self.native_pairs[:, 0]], [self.native_pairs[:, 1]], []
        for g in self.groups:
            ends = (g.v1, g.v2) if g.kind == "between" else (g.v1,)
            for e in ends:
                rows += g.spec.dim * np.bincount(e, minlength=V)
            if g.kind == "between":
                u.append(g.v1)
                v.append(g.v2)
            else:
                anchored.append(g.v1)
        for kg in self.kinds:  # a kind anchors its component unless it is known to be relative
            for var in kg.var:
                rows += kg.kind.dim * np.bincount(var, minlength=V)
            pairs = kg.pairs()
            u.append(pairs[:, 0])
            v.append(pairs[:, 1])
            if not kg.kind.relative:
                anchored.append(kg.var[0])
        nat = self.native_arrays
        if nat is not None:
            count = np.diff(nat.key_start)  # each native factor's variables
            rows += np.bincount(nat.key_var, np.repeat(nat.rows, count), minlength=V).astype(np.int64)
            anchored.append(nat.key_var[nat.key_start[:-1][~nat.relative & (count > 0)]])
        return gauge.undetermined(self.var_dims, rows, np.concatenate(u), np.concatenate(v),
                                  np.concatenate(anchored) if anchored else np.zeros(0, dtype=np.int64))

    # ---------------------------------------------------------------- state
    def elements(self) -> dict:
        """Block name (a group's, or a value type's) → its values."""
        return {name: b.X for name, b in (*self.blocks.items(), *self.value_blocks.items())}

    def native_values(self, Xs=None, other=None) -> gtsam.Values | None:
        """A gtsam.Values holding the keys the native factors need (None if there are none)."""
        if not self.native:
            return None
        Xs = self.elements() if Xs is None else Xs
        other = self.other if other is None else other
        v = gtsam.Values(other)
        for k in self._native_keys:
            name = self.managed.get(k)
            if name is not None:
                b = self.blocks.get(name)
                if b is not None:
                    v.insert(k, to_gtsam(b.spec, Xs[name][b.index[k]]))
                else:
                    vb = self.value_blocks[name]
                    v.insert(k, vb.gtsam_value(Xs[name][vb.index[k]]))
        return v

    def accept(self, Xs, other) -> None:
        for name, X in Xs.items():
            (self.blocks.get(name) or self.value_blocks[name]).X = X
        self.other = other

    def values(self) -> gtsam.Values:
        """The current estimate as a gtsam.Values (all keys of the initial Values).

        Built in C++ as ``initial.retract(ξ)`` with ξ = Log(X₀⁻¹·X) per
        variable (vectorized on the kernels): faster than constructing
        every pose from Python, and exact to rounding (checked in the tests).
        """
        if self._managed_initial is None:  # from_pose_graph: no initial Values to retract (no kinds)
            out = gtsam.Values()
            for b in self.blocks.values():
                for k, M in zip(b.keys, b.X):
                    out.insert(k, to_gtsam(b.spec, M))
            return out
        vv = gtsam.VectorValues()
        insert = vv.insert
        for b in self.blocks.values():
            xi = np.empty((len(b.keys), b.spec.dim))
            b.loops.relative_log(b.X0, b.X, xi)
            for k, x in zip(b.keys, xi):
                insert(k, x)
        out = self._managed_initial.retract(vv)
        fixed = gtsam.VectorValues()
        for vb in self.value_blocks.values():  # the values themselves: X0 + (X − X0) would round
            for n, (k, x) in enumerate(zip(vb.keys, vb.X)):
                try:
                    out.update(k, vb.gtsam_value(x))
                except RuntimeError:
                    # a fixed-size vector (GTSAM's readers, Values.insertPoint3), which update()
                    # cannot write from Python: from here on the block's values are retracted, which
                    # keeps each one's type
                    for k2, x2, x0 in zip(vb.keys[n:], vb.X[n:], vb.X0[n:]):
                        fixed.insert(k2, np.asarray(x2 - x0, dtype=np.float64).reshape(-1))
                    break
        if fixed.size():
            out = out.retract(fixed)
        out.insert(self.other)
        return out

    # ---------------------------------------------------------------- evaluation
    def error(self, Xs=None, other=None, sq_out: np.ndarray | None = None) -> float:
        """GTSAM's graph error ½·Σ‖whitened residual‖² (native factors: their own error()).

        ``sq_out`` (graph size,): receives every factor's squared whitened
        residual norm (2·error() for native factors).
        """
        Xs = self.elements() if Xs is None else Xs
        total = 0.0
        for g in self.groups:
            sq = np.empty(g.E)
            g.evaluate(Xs[g.spec.name], sq)
            total += 0.5 * float(sq.sum())
            if sq_out is not None:
                sq_out[g.fidx] = sq
        for kg in self.kinds:
            sq = np.empty(kg.E)
            kg.evaluate(Xs, sq)
            total += 0.5 * float(sq.sum())
            if sq_out is not None:
                sq_out[kg.fidx] = sq
        if self.native:
            nv = self.native_values(Xs, other)
            try:
                if sq_out is None:
                    total += float(self.native_graph.error(nv))
                else:
                    for i, f, _ in self.native:
                        e = float(f.error(nv))
                        sq_out[i] = 2.0 * e
                        total += e
            except Exception as exc:
                raise self._native_failure(nv, "evaluated", exc) from None
        return float(total)

    def _native_failure(self, nv, what, exc):
        for i, f, _ in self.native:
            try:
                f.error(nv)
            except Exception as e:
                return InputError(f"factor {i} ({type(f).__name__}) could not be {what}: "
                                  f"{type(e).__name__}: {first_line(e)}")
        return InputError(f"a native factor could not be {what}: {type(exc).__name__}: {first_line(exc)}")

    def linearize(self) -> float:
        """Whitened blocks of every factor at the current estimate; returns the error ½Σ‖b‖².

        Groups: ``A1``, ``A2``, ``b``, ``sq`` arrays.  Native factors:
        ``native_arrays.info`` (augmented information) and ``native_linear``
        (the GaussianFactorGraph, for the GTSAM linear solver).
        """
        total = 0.0
        for g in self.groups:
            g.linearize(self.blocks[g.spec.name].X)
            total += 0.5 * float(g.sq.sum())
        return total + self.linearize_kinds() + self.linearize_native()

    def linearize_kinds(self) -> float:
        """Every kind's factors linearized (their kernels, one call a kind); returns their error."""
        Xs = self.elements()
        total = 0.0
        for kg in self.kinds:
            kg.linearize(Xs)
            total += 0.5 * float(kg.sq.sum())
        return total

    def linearize_native(self) -> float:
        """The native factors' part of :meth:`linearize` (GTSAM linearizes them); returns their
        error ½Σ‖b‖² (0 without native factors).  Starts a new linearization."""
        self.linearization = object()  # identifies this linearization (solvers cache per one)
        total = 0.0
        self.native_linear = None
        if self.native:
            nv = self.native_values()
            try:
                lin = self.native_graph.linearize(nv)
            except Exception as exc:
                raise self._native_failure(nv, "linearized", exc) from None
            nat = self.native_arrays
            info, start, size = nat.info, nat.info_start, nat.size
            constrained = self.constrained
            if constrained:
                self.constrained_diagonal[:] = 0.0
                self.pin_steps = []
            for j in range(len(self.native)):
                lf = lin.at(j)
                if lf is None:
                    raise InputError(f"factor {self.native[j][0]} ({type(self.native[j][1]).__name__}) "
                                     "did not linearize")
                if j in constrained:
                    M = self._constrained_information(j, lf)
                else:
                    if isinstance(lf, gtsam.JacobianFactor) and lf.isConstrained():
                        raise InputError(f"factor {self.native[j][0]} ({type(self.native[j][1]).__name__}) "
                                         "linearizes to a constrained factor, but its noise model is not "
                                         "a noiseModel.Constrained: its hard constraint is not known here")
                    M = np.asarray(lf.augmentedInformation())
                D1 = size[j] + 1
                info[start[j]:start[j] + D1 * D1] = M.ravel()
                nat.sq[j] = M[-1, -1]
            total += 0.5 * float(nat.sq.sum())
            self.native_linear = lin
        return total

    def _constrained_information(self, j: int, lf) -> np.ndarray:
        """[A b]ᵀ·W·[A b] of constrained native factor ``j``'s linearization ``lf``, W the weights of
        its noise model's Mahalanobis distance (μ on the rows of σ = 0); its pin's step A⁻¹·b
        where it pins a variable; GTSAM's ``hessianDiagonal`` (weight 1 on those rows) kept
        beside it."""
        A, b = lf.jacobian()  # GTSAM whitens the rows of σ > 0 and leaves the constrained ones
        A, b = np.asarray(A), np.asarray(b)
        scale = self.constrained[j]
        Ab = np.column_stack([A, b]) * scale[:, None]
        i, f, keys = self.native[j]
        nat = self.native_arrays
        for slot in range(int(nat.key_start[j]), int(nat.key_start[j + 1])):
            v, local, d = int(nat.key_var[slot]), int(nat.key_local[slot]), int(nat.key_dim[slot])
            o = int(self.var_offsets[v])
            self.constrained_diagonal[o:o + d] += (np.sum(A[:, local:local + d] ** 2, axis=0)
                                                   - np.sum(Ab[:, local:local + d] ** 2, axis=0))
        if j in self._pinning:
            try:
                step = np.linalg.solve(A, b)
            except np.linalg.LinAlgError:
                step = np.full(len(b), np.nan)
            if not np.all(np.isfinite(step)):
                raise InputError(f"factor {i} ({type(f).__name__} on {key_name(keys[0])}): its hard constraint "
                                 "does not determine the variable (its Jacobian is singular)")
            self.pin_steps.append(step)
        return Ab.T @ Ab

    def nonfinite(self, when: str, Xs=None, other=None) -> InputError:
        """The refusal of an error that is not a finite number at (Xs, other) (default: the current
        estimate), naming the first factor whose error is not (:func:`errors.nonfinite_error`)."""
        sq = np.zeros(self.graph_size)
        try:
            self.error(Xs, other, sq_out=sq)
        except InputError as exc:
            return exc
        return nonfinite_error(when, 0.5 * sq, lambda k: describe_factor(self.graph, k))

    def linearized_sqnorms(self, out: np.ndarray | None = None) -> np.ndarray:
        """Squared whitened residual norm of every factor at the last linearization, (graph size,).

        Native factors: ‖b‖² of GTSAM's linearization (already robust-weighted
        if their noise model is Robust).  Empty graph slots: 0.
        """
        out = np.zeros(self.graph_size) if out is None else out
        for g in (*self.groups, *self.kinds):
            out[g.fidx] = g.sq
        if self.native_arrays is not None:
            out[self.native_arrays.fidx] = self.native_arrays.sq
        return out

    def retract(self, delta: np.ndarray):
        """(elements, other Values) at ``X·Exp(δ)`` per variable (not applied; see :meth:`accept`)."""
        Xs = {}
        for name, b in self.blocks.items():
            out = np.empty_like(b.X)
            b.loops.retract(b.X, delta, b.offsets, out)
            Xs[name] = out
        for name, vb in self.value_blocks.items():
            Xs[name] = vb.retract(vb.X, delta)
        other = self.other
        if self.other_keys:
            vv = gtsam.VectorValues()
            for k in self.other_keys:
                o = self.offset[k]
                vv.insert(k, delta[o:o + self.var_dims[self.var_index[k]]])
            other = self.other.retract(vv)
        return Xs, other
