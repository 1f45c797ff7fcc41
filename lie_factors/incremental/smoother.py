"""An incremental smoother with ISAM2's interface, on batched linearization and the block factor.

``Smoother`` keeps the linearization point θ, the linearized factors and the
incremental factor of their normal equations
(:class:`~lie_factors.incremental.cholesky.BlockFactor`), and the solution δ
of those equations; the estimate is θ ⊕ δ.  Each update follows ISAM2 (Kaess
et al., "iSAM2", IJRR 2012, Alg. 6):

1. every ``relinearizeSkip``-th update, the variables whose δ moved by
   ``relinearizeThreshold`` or more (max norm) are relinearized: θ ← θ ⊕ δ,
   and every factor on them is linearized again;
2. the new factors are linearized at θ, new variables at the values given;
3. the block factor re-eliminates the columns that changed (the new factors'
   variables last in the order);
4. δ is brought up to date by wildfire back-substitution when an estimate is read.

Factors are read as the batch solver reads them: lie_factors' Between/Prior
factors and GTSAM's own Between/Prior factors on the registry's groups (Pose2,
Pose3, Rot3, Similarity2, Similarity3) with Gaussian noise become arrays, and
every kind's new and relinearized factors are linearized by one compiled call
of :mod:`lie_factors.batch.loops`; any other factor (landmark measurements, a
robust noise model, a user's ``CustomFactor``) is linearized by GTSAM
(:mod:`lie_factors.incremental.gtsam_objects`; the arrays:
:mod:`lie_factors.incremental.factor_arrays`).  :meth:`Smoother.update_arrays`
takes a pose graph's factors as arrays, with no factor object at all.

Every update is validated before anything changes, and is all or nothing: an
unknown or duplicate key, a key of the wrong type, a non-finite measurement,
value or noise model, a new variable no factor constrains, or a system that
leaves a variable undetermined raises, and the smoother is as it was.  The last is
decided on the structure first (:mod:`lie_factors.posegraph.gauge`, kept update by
update: a new variable with fewer rows of factors than its dimension, a component of
relative factors only), then by the pivot rule of :mod:`lie_factors.sparse.pivots`.
"""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np

from .. import factors as _factors
from ..batch.graph import key_name
from ..errors import IndeterminantLinearSystem, InputError
from ..interop import to_gtsam
from ..posegraph import gauge
from ..robust.online import RobustSmoothing, check_loss, robust_update
from ..sparse.pivots import PIVOT_TOLERANCE
from .array_path import try_update, update_read
from .cholesky import BlockFactor
from .dogleg import dogleg_step
from .factor_arrays import Elements, FactorArrays, FactorKind, NewFactors
from .gtsam_objects import VALUE_TYPES, NativeRows, insert_from, read_update, retracted, typed_estimate
from .params import SmootherParams, UpdateResult
from .queries import Queries
from .marginalize import marginalize_leaves, row_subtree_keys
from .relinearization import relinearized_now
from .removal import check_keys, forget, no_value, users
from .reports import adaptive_reorder, error_before, update_result
from .removal import plan as removal_plan
from .removal import structure as removal_structure
from .update_args import PLAIN, UpdateArgs, order_groups, read_args
from .structures import grow
from .undo import Undo

#: What the refusal of an update says first.
UNDETERMINED = "the update leaves a variable undetermined"


class Smoother(Queries, RobustSmoothing):
    """Incremental smoothing and mapping with ``gtsam.ISAM2``'s everyday interface.

    ``params``: a :class:`SmootherParams`, a ``gtsam.ISAM2Params`` (its
    thresholds, skip and relinearization switch), or None (ISAM2's defaults).

    ``update(newFactors, newTheta)``; ``update_arrays(...)`` (a pose graph's
    factors as arrays); ``calculateEstimate()`` (a ``gtsam.Values``),
    ``calculateEstimate(key)`` and ``calculateEstimatePose2/Pose3/Point3/…(key)``;
    ``getLinearizationPoint()``; ``getFactorsUnsafe()``; ``getDelta()``;
    ``marginalCovariance(key)``; ``optimize()`` (relinearize everything and
    iterate to convergence).  ``robust="tls"``: loop closures are tested before they enter
    and again as the map grows (:mod:`lie_factors.robust.online`; ``outliers()``,
    ``settle()``).  Counters: ``relinearizations`` (variables
    relinearized, summed over updates), ``reorderings`` (updates that ordered
    every variable afresh).
    """

    def __init__(self, params=None, robust: str | None = None, **overrides):
        if robust is not None:
            check_loss(robust, "robust")
        self.robust = robust
        self.rejection = None  # the online rejection of loop closures, with ``robust``
        given = params
        if params is None:
            params = SmootherParams(**overrides)
        elif isinstance(params, gtsam.ISAM2Params):
            params = SmootherParams.from_isam2(params)
            for k, v in overrides.items():
                setattr(params, k, v)
            params.__post_init__()
        elif isinstance(params, SmootherParams):
            params = dataclasses.replace(params, **overrides)
        else:
            raise TypeError(f"params must be SmootherParams or gtsam.ISAM2Params, got {type(params).__name__}")
        self.smoother_params = params
        self._given_params = given if isinstance(given, gtsam.ISAM2Params) and not overrides else None
        self.bf = BlockFactor()
        self.keys: list[int] = []  # variable index -> key
        self.var: dict[int, int] = {}  # key -> variable index (the variables not removed)
        self.vgroup: list = []  # variable index -> group name or None
        self.velem = np.zeros(0, dtype=np.int64)  # variable index -> element index in its group
        self.elements: dict[str, Elements] = {}
        self.vcode = np.zeros(0, dtype=np.int64)  # variable index -> index in group_names, or -1
        self.vnative = np.zeros(0, dtype=bool)  # variable index -> a native factor uses it
        self.vfixed = np.zeros(0, dtype=bool)  # variable index -> in a marginal factor: never relinearized
        self.group_names: list[str] = []
        self.kinds: dict[tuple, FactorKind] = {}
        self.kind_list: list[FactorKind] = []
        self.fkind = np.zeros(0, dtype=np.int64)  # factor id -> index in kind_list, or -1 (native), -2 (none)
        self.flocal = np.zeros(0, dtype=np.int64)  # factor id -> index in its kind (or in native)
        self.frelative = np.zeros(0, dtype=bool)  # factor id -> known to be relative (lie_factors.posegraph.gauge)
        self.native: list = []  # (factor, var indices, factor id)
        self.marginal_natives = 0  # how many of them marginalizeLeaves made
        self.native_rows = NativeRows()
        self.native_theta = gtsam.Values()  # θ of every variable a native factor touches
        self.other = gtsam.Values()  # θ of the variables GTSAM holds (no group of ours)
        self.other_types: dict[int, str] = {}  # their keys -> type names (``Values.at<Type>``)
        self.gauge = gauge.Components()  # which variables factors join, and which components are anchored
        self.update_count = 0
        self.relinearizations = 0
        self.reorderings = 0
        self._fresh = True  # δ up to date
        self._full_solve = False  # the next solve back-substitutes exactly (forceFullSolve)
        self._nnz_at_reorder = 0  # the factor's entries after the last adaptive reordering
        self._dogleg_step = None  # with Dogleg parameters: the step δ (the factor's delta is Gauss–Newton's)
        self._dogleg_delta = params.initialDelta  # and the trust region's radius

    def params(self):
        """The parameters (ISAM2's ``params()``): the ``gtsam.ISAM2Params`` the smoother was made
        with, or its :class:`SmootherParams`."""
        return self._given_params if self._given_params is not None else self.smoother_params

    # ------------------------------------------------------------------ reading
    def _setup(self, spec, M: np.ndarray, what: str):
        Minv, codes = self._elements(spec.name).loops.setup(M)
        if (codes != _factors.OK).any():
            k = int(np.flatnonzero(codes != _factors.OK)[0])
            raise InputError(str(_factors.element_error(spec, M[k], int(codes[k]), f"{what} {k}", "update")))
        return Minv

    def _elements(self, name: str) -> Elements:
        el = self.elements.get(name)
        if el is None:
            el = self.elements[name] = Elements(_factors.GROUPS[name])
            el.code = len(self.group_names)
            self.group_names.append(name)
        return el

    # ------------------------------------------------------------------ updates
    def update(self, newFactors=None, newTheta=None, removeFactorIndices=None, constrainedKeys=None,
               noRelinKeys=None, extraReelimKeys=None, force_relinearize=False) -> UpdateResult:
        """ISAM2's ``update``: add factors and variables, take factors out, relinearize what moved
        (every ``relinearizeSkip`` updates, or now with ``force_relinearize``) and re-eliminate
        what changed.  ``removeFactorIndices``: indices of factors to take out (as
        ``getNewFactorsIndices()`` gave them; a variable left in no factor is taken out too);
        ``constrainedKeys``: key → group of the elimination order (smaller first; a dict or a
        ``gtsam.KeyGroupMap``); ``noRelinKeys``: keys held at their linearization point;
        ``extraReelimKeys``: keys re-eliminated whatever their δ.  Or ``update(newFactors,
        newTheta, gtsam.ISAM2UpdateParams)``."""
        args = read_args(removeFactorIndices, constrainedKeys, noRelinKeys, extraReelimKeys, force_relinearize)
        return update_read(self, read_update(newFactors, newTheta, self._setup), args)

    def update_arrays(self, group: str, keys=(), values=None, edge_keys=None, measured=None, information=None,
                      prior_keys=None, prior_measured=None, prior_information=None,
                      robust_factors=None) -> UpdateResult:
        """An update from arrays, with no factor object: new variables ``keys`` (P,) with
        elements ``values`` (P, m, m); between factors ``edge_keys`` (E, 2), ``measured``
        (E, m, m) (Z ≈ X₁⁻¹·X₂), ``information`` (E, n, n); priors ``prior_keys`` (Q,),
        ``prior_measured`` (Q, m, m), ``prior_information`` (Q, n, n).  ``group``: Pose2,
        Pose3, Rot3, Similarity2 or Similarity3; GTSAM's tangent order.  (A replay that
        knows its factors in advance prepares them once: :class:`FactorArrays`,
        :meth:`update_prepared`.)

        With ``robust``, ``robust_factors`` (default: the loop closures) are candidate outliers:
        :func:`lie_factors.robust.online.robust_update`."""
        fa = FactorArrays(group, edge_keys, measured, information, prior_keys, prior_measured, prior_information)
        if self.robust is None and robust_factors is None:
            return self.update_prepared(fa, keys, values, np.arange(fa.E), np.arange(fa.Q))
        return robust_update(self, fa, keys, values, robust_factors)

    def update_prepared(self, fa: "FactorArrays", keys, values, edges=(), priors=(),
                        removeFactorIndices=None) -> UpdateResult:
        """An update adding the new variables ``keys`` (P,) at ``values`` (P, m, m) and the
        factors ``edges``/``priors`` (indices) of the prepared ``fa``, numbered in that order
        from the smoother's factor count; ``removeFactorIndices``: as for :meth:`update`."""
        args = PLAIN
        if removeFactorIndices is not None and len(removeFactorIndices):
            args = read_args(removeFactorIndices)
        else:
            result = try_update(self, fa, keys, values, edges, priors)
            if result is not None:
                return result
        nf = fa.new_factors(keys, values, edges, priors)
        return self._apply(nf, args)

    def estimate_matrices(self, keys) -> np.ndarray:
        """(K, m, m): the estimates of the group variables ``keys`` (all of one group)."""
        self._solve()
        vs = np.array([self._var_of(k) for k in np.asarray(keys).tolist()], dtype=np.int64)
        names = {self.vgroup[v] for v in vs.tolist()}
        if len(names) != 1 or None in names:
            raise InputError("estimate_matrices: the keys must all hold elements of one group")
        el = self.elements[names.pop()]
        out = np.empty((len(vs), el.spec.mat, el.spec.mat))
        el.loops.retract(np.ascontiguousarray(el.X[self.velem[vs]]), self.step, self.bf.tree.voff[vs], out)
        return out

    def estimate_matrix(self, key) -> np.ndarray:
        """The estimate θ ⊕ δ of the group variable ``key`` as its (m, m) matrix."""
        self._solve()
        v = self._var_of(key)
        if self.vgroup[v] is None:
            raise InputError(f"key {key_name(int(key))} is not a group element")
        return self._estimate_matrix(v)

    def _validate(self, nf: NewFactors) -> None:
        var = self.var
        seen = set()
        for k in nf.keys:
            if k in var:
                raise InputError(f"key {key_name(k)} is already a variable of the smoother")
            if k in seen:
                raise InputError(f"key {key_name(k)} is given twice")
            seen.add(k)
        new_group = dict(zip(nf.keys, nf.kinds))
        used = set()
        for (kind, name), entry in nf.arrays.items():
            for k in set(entry["keys"].ravel().tolist()):
                used.add(k)
                if k in new_group:
                    g = new_group[k]
                elif k in var:
                    g = self.vgroup[var[k]]
                else:
                    raise no_value(f"{name} factor", k)
                if g != name:
                    raise InputError(f"key {key_name(k)} holds a {g or 'non-group value'}, "
                                        f"not a {name} (used by a {name} factor)")
        for f, keys in nf.native:
            for k in keys:
                used.add(k)
                if k not in new_group and k not in var:
                    raise no_value(type(f).__name__, k)
        for k in nf.keys:
            if k not in used:
                raise InputError(f"new key {key_name(k)} is in no new factor: it would be unconstrained")

    def _apply(self, nf: NewFactors, args: UpdateArgs = PLAIN) -> UpdateResult:
        self._validate(nf)
        n0 = len(self.keys)
        new = dict(zip(nf.keys, range(n0, n0 + len(nf.keys))))
        removal = removal_plan(self, args.remove, users(self, nf, new))
        extra = check_keys(self, args.extra, new, "extraReelimKeys")
        frozen = check_keys(self, args.no_relin, new, "noRelinKeys")
        groups = order_groups(self, args, len(nf.keys), new)
        commit_structure = self._structure(nf, removal)
        p = self.smoother_params
        relin_vars = relinearized_now(self, args.force_relinearize, frozen)
        before = error_before(self, nf, removal) if p.evaluateNonlinearError else None
        batch = adaptive_reorder(self)
        undo = Undo(self)
        try:
            self._add_variables(nf, undo)
            refreshed = self._relinearize(relin_vars, undo) if len(relin_vars) else []
            new_factors = self._add_factors(nf, undo)
            self.bf.update(new_dims=np.array(nf.dims, dtype=np.int64), new_factors=new_factors,
                           refreshed=refreshed, relinearized=relin_vars, observed=np.array(extra, dtype=np.int64)
                           if batch is None else batch, removed=removal.fids, dead=removal.dead, groups=groups)
        except IndeterminantLinearSystem as exc:
            undo.run()
            raise self._indeterminant(exc, nf.keys) from None
        except BaseException:
            undo.run()
            raise
        commit_structure()
        forget(self, removal.dead)
        self._full_solve = self._full_solve or args.full_solve
        return self._updated(len(relin_vars), nf, removal, extra, relin_vars, before, batch is not None)

    def _structure(self, nf: NewFactors, removal=None):
        """The structural rule on the update (:mod:`lie_factors.posegraph.gauge`), before anything
        changes: a new variable whose new factors have fewer rows than its dimension, or a
        component the update touches whose factors are all relative (no prior: a free gauge),
        raises :class:`IndeterminantLinearSystem`; with a removal, also a variable that keeps
        too few rows, or a component the removal leaves unanchored.  Returns what to call once
        the update has succeeded."""
        n0, P = len(self.keys), len(nf.keys)
        var = self.var
        new = dict(zip(nf.keys, range(n0, n0 + P)))
        u, v, anchored = [], [], []
        touched = list(range(n0, n0 + P))
        rows: dict = {}
        for (kind, name), entry in nf.arrays.items():
            ids = [new[k] if k in new else var[k] for k in entry["keys"].ravel().tolist()]
            touched += ids
            if kind == "between":
                u += ids[0::2]
                v += ids[1::2]
            else:
                anchored += ids
            n = _factors.GROUPS[name].dim
            for w in ids:
                rows[w] = rows.get(w, 0) + n
        for f, keys in nf.native:
            ids = [new[k] if k in new else var[k] for k in keys]
            touched += ids
            u += ids[:1] * (len(ids) - 1)
            v += ids[1:]
            if ids and not gauge.is_relative(f):
                anchored.append(ids[0])
            for w in set(ids):
                rows[w] = rows.get(w, 0) + int(f.dim())
        finding = gauge.short_rows(n0, nf.dims, [rows.get(w, 0) for w in range(n0, n0 + P)])
        if finding is None and removal is not None and not removal.empty:
            comps, finding = removal_structure(self, P, nf.dims, u, v, anchored, rows, removal)
            if finding is None:
                return lambda: setattr(self, "gauge", comps)
        if finding is None:
            plan, finding = self.gauge.join(P, u, v, anchored, touched)
        if finding is not None:
            raise self._refusal(finding, nf.keys)
        return lambda: self.gauge.commit(plan)

    def _name(self, v: int, new_keys: list) -> str:
        """The key of variable ``v`` (``new_keys``: the update's, the variables past the smoother's)."""
        n0 = len(self.keys)
        return key_name(self.keys[v]) if v < n0 else key_name(new_keys[v - n0]) if v - n0 < len(new_keys) else str(v)

    def _refusal(self, finding, new_keys: list) -> IndeterminantLinearSystem:
        """The error of an update whose structure leaves a variable undetermined (``finding``, a
        :class:`lie_factors.posegraph.gauge.Undetermined`)."""
        return finding.error(UNDETERMINED, self._name(finding.variable, new_keys))

    def _indeterminant(self, exc: IndeterminantLinearSystem, new_keys: list) -> IndeterminantLinearSystem:
        """The error of an update that left variable ``exc.variable`` undetermined, by its key
        (``new_keys``: the update's new keys, the variables past the smoother's)."""
        v = exc.variable
        return IndeterminantLinearSystem(
            f"{UNDETERMINED}: a pivot of the column of {self._name(v, new_keys)} is not above "
            f"{PIVOT_TOLERANCE:g} of its diagonal entry: the factors so far do not determine it", v)

    def _updated(self, relinearized: int, nf: NewFactors | None = None, removal=None, extra=(), relin=(),
                 before=None, adaptive: bool = False) -> UpdateResult:
        """The counts after an update that succeeded, and what it reports
        (:func:`~lie_factors.incremental.reports.update_result`)."""
        self.update_count += 1
        self.relinearizations += relinearized
        self.reorderings += int(self.bf.last.batch)
        self._fresh = False
        return update_result(self, relinearized, nf, removal, extra, relin, before, adaptive)

    def _grow_variables(self, n: int) -> None:
        """Room for ``n`` variables in the per-variable arrays."""
        self.velem = grow(self.velem, n)
        self.vcode = grow(self.vcode, n)
        self.vnative = grow(self.vnative, n)
        self.vfixed = grow(self.vfixed, n, False)

    def _kind(self, kind: str, name: str) -> FactorKind:
        """The array factors of (``kind``, group ``name``), made on first use."""
        store = self.kinds.get((kind, name))
        if store is None:
            store = self.kinds[(kind, name)] = FactorKind(kind, _factors.GROUPS[name], self._elements(name))
            store.code = len(self.kind_list)
            self.kind_list.append(store)
        return store

    def _add_variables(self, nf: NewFactors, undo) -> list:
        nv0 = len(self.keys)
        P = len(nf.keys)
        if not P:
            return []
        ids = list(range(nv0, nv0 + P))
        undo.vars(nv0)
        self._grow_variables(nv0 + P)
        self.vcode[nv0:nv0 + P] = -1
        self.vnative[nv0:nv0 + P] = False
        by_group: dict = {}
        for q, (k, name) in enumerate(zip(nf.keys, nf.kinds)):
            self.keys.append(k)
            self.var[k] = nv0 + q
            self.vgroup.append(name)
            if name is not None:
                by_group.setdefault(name, []).append(q)
        for name, qs in by_group.items():
            el = self._elements(name)
            undo.elements(el)
            idx = el.append(np.array([nf.values[q] for q in qs]), np.array([nv0 + q for q in qs], dtype=np.int64))
            self.velem[[nv0 + q for q in qs]] = idx
            self.vcode[[nv0 + q for q in qs]] = el.code
        others = [q for q, name in enumerate(nf.kinds) if name is None]
        native_keys = {k for _, keys in nf.native for k in keys}
        if native_keys:
            undo.vnative()
            self.vnative[[self.var[k] for k in native_keys]] = True
        for q in others:
            k = nf.keys[q]
            self.other_types[k] = nf.types[k]
            self._insert_from(self.other, nf.theta, k)
            undo.inserted(self.other, k)
        for k in native_keys:
            if self.native_theta.exists(k):
                continue
            v = self.var[k]
            name = self.vgroup[v]
            if name is None:
                self._insert_from(self.native_theta, self.other, k)
            else:
                self.native_theta.insert(k, to_gtsam(name, self.elements[name].X[self.velem[v]]))
            undo.inserted(self.native_theta, k)
        return ids

    def _insert_from(self, dest: gtsam.Values, src: gtsam.Values, key: int) -> None:
        """Copy the value of ``key`` (a type GTSAM holds) from ``src``."""
        insert_from(dest, src, key, self.other_types[key])

    def _add_factors(self, nf: NewFactors, undo) -> list:
        """The update's factors stored as arrays or native factors, numbered by their place in
        the update (ISAM2's factor indices: every factor added so far counted, in order)."""
        out = []
        var = self.var
        base = self.bf.nf
        for (kind, name), entry in nf.arrays.items():
            store = self._kind(kind, name)
            undo.kind(store)
            keys = entry["keys"]
            v = np.fromiter((var[k] for k in keys.ravel().tolist()), dtype=np.int64, count=keys.size).reshape(keys.shape)
            e = self.velem[v]
            idx = store.append(v, e, entry["C"], entry["R"], entry["src"])
            fids = base + np.asarray(entry["pos"], dtype=np.int64)
            store.fid[idx] = fids
            self._register(fids, store.code, idx, kind == "between")
            out.append((v, store.jacobians(idx), fids))
        if nf.native:
            undo.native(len(self.native))
            chunks = self.native_rows([f for f, _ in nf.native], self.native_theta)
            fids, first = base + np.asarray(nf.native_pos, dtype=np.int64), len(self.native)
            for q, (f, _) in enumerate(nf.native):
                keys = self.native_rows.keys(f)
                self.native.append((f, np.array([var[k] for k in keys], dtype=np.int64), int(fids[q])))
            self._register(fids, -1, np.arange(first, len(self.native)), [gauge.is_relative(f) for f, _ in nf.native])
            for qs, J in chunks:  # a chunk per kind, whose factors have one variable count
                vs = np.stack([self.native[first + q][1] for q in qs.tolist()])
                out.append((vs, J, fids[qs]))
        if nf.nulls:
            # an empty slot of the graph keeps its index, as in ISAM2's factor graph
            fids = base + np.asarray(nf.nulls, dtype=np.int64)
            self._register(fids, -2, np.zeros(len(fids), dtype=np.int64), True)
            out.append((np.zeros((len(fids), 0), dtype=np.int64), np.zeros((len(fids), 0, 1)), fids))
        return out

    def _register(self, fids: np.ndarray, code: int, local: np.ndarray, relative) -> None:
        """Factor ids ``fids`` are entries ``local`` of kind ``code`` (−1: native factors, −2: an
        empty slot), ``relative`` or not (:func:`lie_factors.posegraph.gauge.is_relative`).
        (Ids past the block factor's count are dropped with it if the update fails.)"""
        n = int(fids.max()) + 1
        self.fkind, self.flocal, self.frelative = (grow(a, n) for a in (self.fkind, self.flocal, self.frelative))
        self.fkind[fids] = code
        self.flocal[fids] = local
        self.frelative[fids] = relative

    def _relinearize(self, relin: np.ndarray, undo) -> list:
        """θ ← θ ⊕ δ on ``relin``, and new Jacobians for every factor on them."""
        bf = self.bf
        codes = self.vcode[relin]
        for name, el in self.elements.items():
            vs = relin[codes == el.code]
            if not len(vs):
                continue
            e = self.velem[vs]
            undo.theta(el, e)
            out = np.empty((len(e), el.spec.mat, el.spec.mat))
            el.loops.retract(np.ascontiguousarray(el.X[e]), self.step, bf.tree.voff[vs], out)
            el.X[e] = out
        # the variables GTSAM holds: retracted one by one, in place (the old values kept for undo)
        for v in relin[codes < 0].tolist():
            k = self.keys[v]
            moved = retracted(self.other, k, self.other_types[k], self._variable_step(v))
            for values in (self.other, self.native_theta):
                if values.exists(k):
                    undo.updated(values, k, getattr(values, f"at{self.other_types[k]}")(k))
                    values.update(k, moved)
        for v in relin[self.vnative[relin] & (codes >= 0)].tolist():
            k = self.keys[v]
            name = self.vgroup[v]
            el = self.elements[name]
            undo.updated(self.native_theta, k, getattr(self.native_theta, f"at{name}")(k))
            self.native_theta.update(k, to_gtsam(name, el.X[self.velem[v]]))
        fids = bf.factors_of(relin)
        fk, fl = self.fkind[fids], self.flocal[fids]
        out = []
        for store in self.kind_list:
            idx = fl[fk == store.code]
            if len(idx):
                out.append((store.fid[idx], store.jacobians(idx)))
        natives = [self.native[local] for local in fl[fk < 0].tolist()]
        if natives:
            for qs, J in self.native_rows([f for f, _, _ in natives], self.native_theta):
                out.append((np.array([natives[q][2] for q in qs.tolist()], dtype=np.int64), J))
        return out

    # ------------------------------------------------------------------ solving and reading
    def _solve(self) -> None:
        """Bring δ up to date: wildfire back-substitution (exact once after ``forceFullSolve``),
        then, with Dogleg parameters, ISAM2's Dogleg step from it (:mod:`lie_factors.incremental.dogleg`)."""
        if self._fresh:
            return
        p = self.smoother_params
        self.bf.solve(0.0 if self._full_solve else p.wildfireThreshold)
        self._full_solve = False
        if p.optimizer != "GaussNewton":
            self._dogleg_step, self._dogleg_delta = dogleg_step(self, self._dogleg_delta)
        self._fresh = True

    @property
    def step(self) -> np.ndarray:
        """The step δ from θ to the estimate, (nscalar,) or longer: the Gauss–Newton step of the
        factor, or ISAM2's Dogleg step."""
        return self.bf.delta if self._dogleg_step is None else self._dogleg_step

    def _variable_step(self, v: int) -> np.ndarray:
        o = int(self.bf.tree.voff[v])
        return self.step[o:o + int(self.bf.tree.dim[v])]

    def marginalizeLeaves(self, leafKeys) -> None:
        """ISAM2's ``marginalizeLeaves``: take the variables ``leafKeys`` out, keeping their
        information as linear factors on what they were eliminated into
        (:mod:`~lie_factors.incremental.marginalize`); the variables of those factors are then
        held at their linearization point.  The keys must be leaves: every variable eliminated
        below one of them is one of them (an ``InputError`` otherwise, nothing changed)."""
        marginalize_leaves(self, leafKeys)

    def row_subtree_keys(self, keys) -> list:
        """The keys of the nodes whose separator holds one of ``keys``: what must be
        re-eliminated with ``keys`` ordered first for them to become leaves
        (:func:`~lie_factors.incremental.marginalize.row_subtree_keys`)."""
        return row_subtree_keys(self, keys)

    def marginalizeLeavesWithIndices(self, leafKeys) -> tuple[list, list]:
        """:meth:`marginalizeLeaves`, returning (the marginal factors' indices, the removed
        factors' indices), as GTSAM's Python wrapper does."""
        return marginalize_leaves(self, leafKeys)

    def optimize(self, max_iterations: int = 100, tolerance: float = 1e-10) -> int:
        """Relinearize every variable and take Gauss–Newton steps until the largest step
        component is below ``tolerance``; returns the iterations taken."""
        bf = self.bf
        for it in range(1, max_iterations + 1):
            bf.replace_all()  # the exact solution of the current system
            self._fresh = False
            saved = self.smoother_params.wildfireThreshold
            self.smoother_params.wildfireThreshold = 0.0
            try:
                self._solve()
            finally:
                self.smoother_params.wildfireThreshold = saved
            step = float(np.max(np.abs(bf.delta[:bf.nscalar]))) if bf.nscalar else 0.0
            relin = np.flatnonzero((bf.vdead[:bf.nv] == 0) & ~self.vfixed[:bf.nv]).astype(np.int64)
            undo = Undo(self)
            try:
                refreshed = self._relinearize(relin, undo)
                bf.update(refreshed=refreshed, relinearized=relin)
            except BaseException:
                undo.run()
                raise
            self.relinearizations += len(relin)
            self.reorderings += int(bf.last.batch)
            self._fresh = False
            if step < tolerance:
                return it
        return max_iterations


for _type in VALUE_TYPES:
    setattr(Smoother, f"calculateEstimate{_type}", typed_estimate(_type))
