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
robust noise model, a user's ``CustomFactor``) is linearized by GTSAM.
:meth:`Smoother.update_arrays` takes a pose graph's factors as arrays, with no
factor object at all.

Every update is validated before anything changes, and is all or nothing: an
unknown or duplicate key, a key of the wrong type, a non-finite measurement,
value or noise model, a new variable no factor constrains, or a system that
leaves a variable undetermined raises, and the smoother is as it was.
"""

from __future__ import annotations

import os
import re
import tempfile
from dataclasses import dataclass

import gtsam
import numpy as np

from .. import factors as _factors
from ..batch.graph import noise_whitening, key_name, whitening
from ..batch.loops import GroupLoops
from ..interop import to_gtsam
from .cholesky import BlockFactor
from ..errors import IndeterminantLinearSystem


class SmootherError(ValueError):
    """Bad input to :class:`Smoother` (unknown or duplicate key, wrong type, non-finite numbers, …)."""


@dataclass
class SmootherParams:
    """ISAM2's parameters the smoother honours, under GTSAM's names.

    ``relinearizeThreshold``: relinearize a variable whose δ has a component of
    at least this size (``ISAM2Params.relinearizeThreshold``, 0.1); ``relinearizeSkip``:
    check every this many updates (10); ``enableRelinearization``;
    ``wildfireThreshold``: back-substitution stops below nodes that moved less
    (``ISAM2GaussNewtonParams.wildfireThreshold``, 0.001; 0: the exact
    solution); ``relinearizePolicy``: ``"variable"`` (ISAM2's, per variable) or
    ``"global"`` (SLAM++'s: every variable, when the largest δ reaches the threshold).
    """

    relinearizeThreshold: float = 0.1
    relinearizeSkip: int = 10
    enableRelinearization: bool = True
    wildfireThreshold: float = 0.001
    relinearizePolicy: str = "variable"

    def __post_init__(self):
        if not (np.isfinite(self.relinearizeThreshold) and self.relinearizeThreshold >= 0):
            raise SmootherError(f"relinearizeThreshold must be finite and >= 0, got {self.relinearizeThreshold}")
        if int(self.relinearizeSkip) < 1:
            raise SmootherError(f"relinearizeSkip must be >= 1, got {self.relinearizeSkip}")
        if not (np.isfinite(self.wildfireThreshold) and self.wildfireThreshold >= 0):
            raise SmootherError(f"wildfireThreshold must be finite and >= 0, got {self.wildfireThreshold}")
        if self.relinearizePolicy not in ("variable", "global"):
            raise SmootherError(f"relinearizePolicy must be 'variable' or 'global', got {self.relinearizePolicy!r}")
        self.relinearizeSkip = int(self.relinearizeSkip)

    @classmethod
    def from_isam2(cls, params: gtsam.ISAM2Params) -> "SmootherParams":
        """The values of a ``gtsam.ISAM2Params`` (GTSAM's Python API has no getters for the
        thresholds: they are read from its ``print`` output, 6 significant digits)."""
        text = _captured_print(params)

        def number(name, default):
            m = re.search(rf"^{name}:\s*(\S+)", text, re.M)
            return float(m.group(1)) if m else default

        if "ISAM2DoglegParams" in text:
            raise SmootherError("the smoother runs Gauss-Newton steps: ISAM2DoglegParams are not supported")
        return cls(relinearizeThreshold=number("relinearizeThreshold", 0.1),
                   relinearizeSkip=int(params.relinearizeSkip),
                   enableRelinearization=bool(params.enableRelinearization),
                   wildfireThreshold=number("wildfireThreshold", 0.001))


def _captured_print(params) -> str:
    """What ``params.print()`` writes: GTSAM's wrapper sends C++'s ``std::cout`` to Python's
    ``sys.stdout`` (caught here), or else to the process's standard output (caught on its
    descriptor, C's buffer flushed before it is put back)."""
    import contextlib
    import ctypes
    import io
    import sys

    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    libc.fflush(None)
    text = io.StringIO()
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        saved = os.dup(1)
        try:
            os.dup2(tmp.fileno(), 1)
            with contextlib.redirect_stdout(text):
                params.print()
            libc.fflush(None)
        finally:
            os.dup2(saved, 1)
            os.close(saved)
        tmp.seek(0)
        return text.getvalue() + tmp.read().decode(errors="replace")


@dataclass
class UpdateResult:
    """What an update did (ISAM2Result's counts): variables re-eliminated, relinearized,
    cliques (nodes) in the tree, and whether everything was reordered."""

    variablesReeliminated: int
    variablesRelinearized: int
    cliques: int
    reordered: bool

    def getVariablesReeliminated(self) -> int:
        return self.variablesReeliminated

    def getVariablesRelinearized(self) -> int:
        return self.variablesRelinearized

    def getCliques(self) -> int:
        return self.cliques


def _grow(a: np.ndarray, n: int) -> np.ndarray:
    if a.shape[0] >= n:
        return a
    out = np.empty((max(n, 2 * a.shape[0], 16),) + a.shape[1:], dtype=a.dtype)
    out[:a.shape[0]] = a
    return out


class _Elements:
    """The variables of one group: their elements θ (N, m, m) and variable indices."""

    def __init__(self, spec):
        self.spec = spec
        self.loops = GroupLoops(spec, serial=True)
        self.X = np.zeros((0, spec.mat, spec.mat))
        self.var = np.zeros(0, dtype=np.int64)
        self.n = 0

    def append(self, X: np.ndarray, var: np.ndarray) -> np.ndarray:
        k = len(X)
        self.X = _grow(self.X, self.n + k)
        self.var = _grow(self.var, self.n + k)
        idx = np.arange(self.n, self.n + k)
        self.X[idx] = X
        self.var[idx] = var
        self.n += k
        return idx


class _FactorKind:
    """The array factors of one (kind, group): variables, element indices, constants, block-factor ids."""

    def __init__(self, kind: str, spec, elements: _Elements):
        self.kind, self.spec, self.elements = kind, spec, elements
        m, n = spec.mat, spec.dim
        self.v = np.zeros((0, 2 if kind == "between" else 1), dtype=np.int64)
        self.e = np.zeros((0, 2 if kind == "between" else 1), dtype=np.int64)
        self.C = np.zeros((0, m, m))
        self.R = np.zeros((0, n, n))
        self.fid = np.zeros(0, dtype=np.int64)
        self.source: list = []  # the factor objects read (None: from arrays)
        self.n = 0

    def append(self, v, e, C, R, sources) -> np.ndarray:
        k = len(v)
        for name in ("v", "e", "C", "R", "fid"):
            setattr(self, name, _grow(getattr(self, name), self.n + k))
        idx = np.arange(self.n, self.n + k)
        self.v[idx], self.e[idx], self.C[idx], self.R[idx] = v, e, C, R
        self.source.extend(sources)
        self.n += k
        return idx

    def truncate(self, n: int) -> None:
        self.n = n
        del self.source[n:]

    def jacobians(self, idx: np.ndarray) -> np.ndarray:
        """Whitened [A_1 (A_2) | b] of the factors ``idx`` at the current θ: (F, n, D + 1), one compiled call."""
        n = self.spec.dim
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        F = len(idx)
        X = self.elements.X
        b = np.empty((F, n))
        sq = np.empty(F)
        if self.kind == "between":
            A1, A2 = np.empty((F, n, n)), np.empty((F, n, n))
            e = self.e[idx]
            self.elements.loops.between_lin(X, np.ascontiguousarray(e[:, 0]), np.ascontiguousarray(e[:, 1]),
                                            self.C[idx], self.R, idx, A1, A2, b, sq)
            return np.concatenate([A1, A2, b[:, :, None]], axis=2)
        A1 = np.empty((F, n, n))
        self.elements.loops.prior_lin(X, np.ascontiguousarray(self.e[idx, 0]), self.C[idx], self.R, idx, A1, b, sq)
        return np.concatenate([A1, b[:, :, None]], axis=2)


class FactorArrays:
    """A pose graph's between factors and priors, checked and set up once (M⁻¹, the whitening R
    with RᵀR = Λ): :meth:`Smoother.update_prepared` adds any of them by index.

    ``edge_keys`` (E, 2), ``measured`` (E, m, m), ``information`` (E, n, n); ``prior_keys``
    (Q,), ``prior_measured`` (Q, m, m), ``prior_information`` (Q, n, n).  Raises
    :class:`SmootherError` for wrong shapes, non-finite numbers, a self-loop, an element that
    is not in the group, an information matrix that is not positive definite.
    """

    def __init__(self, group: str, edge_keys=None, measured=None, information=None, prior_keys=None,
                 prior_measured=None, prior_information=None):
        spec = _factors.GROUPS.get(group)
        if spec is None:
            raise SmootherError(f"unknown group {group!r} (choose from {', '.join(_factors.GROUPS)})")
        self.group, self.spec = group, spec
        loops = GroupLoops(spec, serial=True)
        m, n = spec.mat, spec.dim
        parts = {}
        for kind, k, M, info, nk in (("between", edge_keys, measured, information, 2),
                                     ("prior", prior_keys, prior_measured, prior_information, 1)):
            k = np.zeros((0, nk), dtype=np.int64) if k is None else np.asarray(k, dtype=np.int64).reshape(-1, nk)
            F = len(k)
            M = np.zeros((0, m, m)) if M is None and F == 0 else np.asarray(M, dtype=np.float64)
            info = np.zeros((0, n, n)) if info is None and F == 0 else np.asarray(info, dtype=np.float64)
            if M.shape != (F, m, m) or info.shape != (F, n, n):
                raise SmootherError(f"{kind} factors: expected measurements ({F}, {m}, {m}) and information "
                                    f"({F}, {n}, {n}), got {M.shape} and {info.shape}")
            if not (np.all(np.isfinite(M)) and np.all(np.isfinite(info))):
                raise SmootherError(f"{kind} factors: a measurement or information matrix is not finite")
            if kind == "between" and np.any(k[:, 0] == k[:, 1]):
                raise SmootherError("between factors: a factor connects a key to itself")
            Minv, codes = loops.setup(M)
            bad = np.flatnonzero(codes != _factors.OK)
            if bad.size:
                q = int(bad[0])
                raise SmootherError(str(_factors.element_error(spec, M[q], int(codes[q]), f"{kind} {q}",
                                                                "update")))
            try:
                R = whitening(info) if F else np.zeros((0, n, n))
            except np.linalg.LinAlgError:
                raise SmootherError(f"{kind} factors: an information matrix is not positive definite") from None
            parts[kind] = (k, Minv, R)
        self.edge_keys, self.Minv, self.R = parts["between"]
        pk, self.Pinv, self.prior_R = parts["prior"]
        self.prior_keys = pk.reshape(-1)
        self.E, self.Q = len(self.edge_keys), len(self.prior_keys)


@dataclass
class _NewFactors:
    """A validated update: new variables (key, group name or None, value) and factors by kind."""

    keys: list
    kinds: list  # group name (array variable) or None (GTSAM's values)
    values: list  # element matrix (m, m) or the gtsam value
    dims: list
    arrays: dict  # (kind, group) -> dict(keys, C, R, src)
    native: list  # (factor, keys)


#: The types a ``gtsam.Values`` can hold, by their ``at<Type>`` accessors (the common ones first).
_COMMON_TYPES = ("Point3", "Point2", "Pose3", "Pose2", "Rot3", "Rot2", "Similarity3", "Similarity2")
_VALUE_TYPES = _COMMON_TYPES + tuple(sorted(
    n[2:] for n in dir(gtsam.Values) if n.startswith("at") and n[2:3].isupper()
    and n[2:] not in _COMMON_TYPES + ("Vector", "Matrix", "Double"))) + ("Vector", "Matrix", "Double")


def _value_type(values: gtsam.Values, key: int) -> str:
    """The type name of the value of ``key`` (the first accessor that reads it)."""
    for t in _VALUE_TYPES:
        try:
            getattr(values, f"at{t}")(key)
        except (RuntimeError, TypeError, ValueError):
            continue
        return t
    raise SmootherError(f"key {key_name(key)}: its value has a type the smoother cannot read")


class Smoother:
    """Incremental smoothing and mapping with ``gtsam.ISAM2``'s everyday interface.

    ``params``: a :class:`SmootherParams`, a ``gtsam.ISAM2Params`` (its
    thresholds, skip and relinearization switch), or None (ISAM2's defaults).

    ``update(newFactors, newTheta)``; ``update_arrays(...)`` (a pose graph's
    factors as arrays); ``calculateEstimate()`` (a ``gtsam.Values``),
    ``calculateEstimate(key)`` and ``calculateEstimatePose2/Pose3/Point3/…(key)``;
    ``getLinearizationPoint()``; ``getFactorsUnsafe()``; ``getDelta()``;
    ``marginalCovariance(key)``; ``optimize()`` (relinearize everything and
    iterate to convergence).  Counters: ``relinearizations`` (variables
    relinearized, summed over updates), ``reorderings`` (updates that ordered
    every variable afresh).
    """

    def __init__(self, params=None, **overrides):
        if params is None:
            params = SmootherParams(**overrides)
        elif isinstance(params, gtsam.ISAM2Params):
            params = SmootherParams.from_isam2(params)
            for k, v in overrides.items():
                setattr(params, k, v)
            params.__post_init__()
        elif not isinstance(params, SmootherParams):
            raise TypeError(f"params must be SmootherParams or gtsam.ISAM2Params, got {type(params).__name__}")
        self.params = params
        self.bf = BlockFactor()
        self.keys: list[int] = []  # variable index -> key
        self.var: dict[int, int] = {}  # key -> variable index
        self.vgroup: list = []  # variable index -> group name or None
        self.velem = np.zeros(0, dtype=np.int64)  # variable index -> element index in its group
        self.elements: dict[str, _Elements] = {}
        self.vcode = np.zeros(0, dtype=np.int64)  # variable index -> index in group_names, or -1
        self.vnative = np.zeros(0, dtype=bool)  # variable index -> a native factor uses it
        self.group_names: list[str] = []
        self.kinds: dict[tuple, _FactorKind] = {}
        self.kind_list: list[_FactorKind] = []
        self.fkind = np.zeros(0, dtype=np.int64)  # factor id -> index in kind_list, or -1 (native)
        self.flocal = np.zeros(0, dtype=np.int64)  # factor id -> index in its kind (or in native)
        self.native: list = []  # (factor, var indices, factor id)
        self.native_theta = gtsam.Values()  # θ of every variable a native factor touches
        self.other = gtsam.Values()  # θ of the variables GTSAM holds (no group of ours)
        self.other_types: dict[int, str] = {}  # their keys -> type names (``Values.at<Type>``)
        self.update_count = 0
        self.relinearizations = 0
        self.reorderings = 0
        self._fresh = True  # δ up to date

    # ------------------------------------------------------------------ reading
    def _classify(self, f):
        """(kind, spec, keys, Minv, R, M) for an array factor, None for a native one."""
        if isinstance(f, _factors.BetweenFactor):
            kind, spec = "between", f.spec
            keys = (f._key1, f._key2)
            nm = f._noise
        elif isinstance(f, _factors.PriorFactor):
            kind, spec = "prior", f.spec
            keys = (f._key2,)
            nm = f._noise
        else:
            nk = len(f.keys()) if isinstance(f, gtsam.NonlinearFactor) else 0
            value = None
            if nk == 2 and hasattr(f, "measured"):
                value, kind = f.measured(), "between"
            elif nk == 1 and hasattr(f, "prior"):
                value, kind = f.prior(), "prior"
            spec = _factors.GROUPS.get(type(value).__name__) if value is not None else None
            if spec is None or type(value) is not spec.cls:
                return None
            keys = tuple(int(k) for k in f.keys())
            nm = f.noiseModel()
            R = noise_whitening(nm)
            if R is None or (kind == "between" and keys[0] == keys[1]):
                return None
            return kind, spec, keys, None, np.asarray(R, dtype=np.float64), spec.matrix(value)
        R = noise_whitening(nm)
        if R is None or (kind == "between" and keys[0] == keys[1]):
            return None
        return kind, spec, keys, f._Minv, np.asarray(R, dtype=np.float64), None

    def _read(self, newFactors, newTheta) -> _NewFactors:
        newFactors = gtsam.NonlinearFactorGraph() if newFactors is None else newFactors
        newTheta = gtsam.Values() if newTheta is None else newTheta
        if not isinstance(newFactors, gtsam.NonlinearFactorGraph):
            raise TypeError(f"newFactors must be a gtsam.NonlinearFactorGraph, got {type(newFactors).__name__}")
        if not isinstance(newTheta, gtsam.Values):
            raise TypeError(f"newTheta must be a gtsam.Values, got {type(newTheta).__name__}")
        arrays: dict = {}
        native = []
        group_of: dict[int, str] = {}
        for i in range(newFactors.size()):
            f = newFactors.at(i)
            if f is None:
                continue
            c = self._classify(f)
            if c is None:
                if not isinstance(f, gtsam.NonlinearFactor):
                    raise SmootherError(f"factor {i}: unsupported type {type(f).__name__}")
                native.append((f, [int(k) for k in f.keys()]))
                continue
            kind, spec, keys, Minv, R, M = c
            if not np.all(np.isfinite(R)):
                raise SmootherError(f"factor {i} ({type(f).__name__}): its noise model is not finite")
            if M is not None and not np.all(np.isfinite(M)):
                raise SmootherError(f"factor {i} ({type(f).__name__}): its measurement is not finite")
            for k in keys:
                g = group_of.setdefault(k, spec.name)
                if g != spec.name:
                    raise SmootherError(f"key {key_name(k)} is used by both {g} and {spec.name} factors")
            entry = arrays.setdefault((kind, spec.name), dict(keys=[], Minv=[], R=[], M=[], src=[]))
            entry["keys"].append(keys)
            entry["Minv"].append(Minv)
            entry["R"].append(R)
            entry["M"].append(M)
            entry["src"].append(f)
        # constants: lie_factors' factors carry them; GTSAM's are set up in one call per kind
        out = {}
        for (kind, name), entry in arrays.items():
            spec = _factors.GROUPS[name]
            F = len(entry["keys"])
            Minv = np.empty((F, spec.mat, spec.mat))
            need = [q for q in range(F) if entry["Minv"][q] is None]
            for q in range(F):
                if entry["Minv"][q] is not None:
                    Minv[q] = entry["Minv"][q]
            if need:
                Minv[need] = self._setup(spec, np.array([entry["M"][q] for q in need]), "measurement")
            keys = np.array(entry["keys"], dtype=np.int64).reshape(F, -1)
            out[(kind, name)] = dict(keys=keys, C=Minv, R=np.array(entry["R"], dtype=np.float64), src=entry["src"])
        new_keys = [int(k) for k in newTheta.keys()]
        kinds, values, dims, types = [], [], [], {}
        zero = None
        for k in new_keys:
            name = group_of.get(k)
            if name is None and k in self.var:
                name = None
            if name is not None:
                spec = _factors.GROUPS[name]
                try:
                    value = getattr(newTheta, spec.at)(k)
                except RuntimeError:
                    raise SmootherError(f"key {key_name(k)} is used by a {name} factor but its new value is "
                                        f"not a gtsam.{name}") from None
                X = spec.matrix(value)
                if not np.all(np.isfinite(X)):
                    raise SmootherError(f"the new value of key {key_name(k)} is not finite")
                kinds.append(name)
                values.append(X)
                dims.append(spec.dim)
            else:
                if zero is None:
                    zero = newTheta.zeroVectors()
                types[k] = _value_type(newTheta, k)
                kinds.append(None)
                values.append(None)
                dims.append(int(np.asarray(zero.at(k)).shape[0]))
        nf = _NewFactors(new_keys, kinds, values, dims, out, native)
        nf.theta = newTheta
        nf.types = types
        return nf

    def _setup(self, spec, M: np.ndarray, what: str):
        Minv, codes = self._elements(spec.name).loops.setup(M)
        bad = np.flatnonzero(codes != _factors.OK)
        if bad.size:
            k = int(bad[0])
            raise SmootherError(str(_factors.element_error(spec, M[k], int(codes[k]), f"{what} {k}", "update")))
        return Minv

    def _elements(self, name: str) -> _Elements:
        el = self.elements.get(name)
        if el is None:
            el = self.elements[name] = _Elements(_factors.GROUPS[name])
            el.code = len(self.group_names)
            self.group_names.append(name)
        return el

    # ------------------------------------------------------------------ updates
    def update(self, newFactors=None, newTheta=None, *args, **kwargs) -> UpdateResult:
        """ISAM2's ``update(newFactors, newTheta)``: add factors and variables, relinearize what
        moved (every ``relinearizeSkip`` updates) and re-eliminate what changed."""
        if args or kwargs:
            raise TypeError("Smoother.update takes newFactors and newTheta only "
                            "(factor removal, constrained and extra keys are not supported)")
        return self._apply(self._read(newFactors, newTheta))

    def update_arrays(self, group: str, keys=(), values=None, edge_keys=None, measured=None, information=None,
                      prior_keys=None, prior_measured=None, prior_information=None) -> UpdateResult:
        """An update from arrays, with no factor object: new variables ``keys`` (P,) with
        elements ``values`` (P, m, m); between factors ``edge_keys`` (E, 2), ``measured``
        (E, m, m) (Z ≈ X₁⁻¹·X₂), ``information`` (E, n, n); priors ``prior_keys`` (Q,),
        ``prior_measured`` (Q, m, m), ``prior_information`` (Q, n, n).  ``group``: Pose2,
        Pose3, Rot3, Similarity2 or Similarity3; GTSAM's tangent order.  (A replay that
        knows its factors in advance prepares them once: :class:`FactorArrays`,
        :meth:`update_prepared`.)"""
        fa = FactorArrays(group, edge_keys, measured, information, prior_keys, prior_measured, prior_information)
        return self.update_prepared(fa, keys, values, np.arange(fa.E), np.arange(fa.Q))

    def update_prepared(self, fa: "FactorArrays", keys, values, edges=(), priors=()) -> UpdateResult:
        """An update adding the new variables ``keys`` (P,) at ``values`` (P, m, m) and the
        factors ``edges``/``priors`` (indices) of the prepared ``fa``."""
        spec = fa.spec
        m, n = spec.mat, spec.dim
        keys = np.asarray(keys, dtype=np.int64).reshape(-1)
        P = len(keys)
        X = np.zeros((0, m, m)) if P == 0 and values is None else np.asarray(values, dtype=np.float64)
        if X.shape != (P, m, m):
            raise SmootherError(f"values: expected shape ({P}, {m}, {m}), got {X.shape}")
        if not np.all(np.isfinite(X)):
            raise SmootherError("values: not finite")
        arrays = {}
        edges = np.asarray(edges, dtype=np.int64).reshape(-1)
        priors = np.asarray(priors, dtype=np.int64).reshape(-1)
        if len(edges):
            arrays[("between", fa.group)] = dict(keys=fa.edge_keys[edges], C=fa.Minv[edges], R=fa.R[edges],
                                                 src=[None] * len(edges))
        if len(priors):
            arrays[("prior", fa.group)] = dict(keys=fa.prior_keys[priors, None], C=fa.Pinv[priors],
                                               R=fa.prior_R[priors], src=[None] * len(priors))
        nf = _NewFactors(keys.tolist(), [fa.group] * P, list(X), [n] * P, arrays, [])
        nf.theta = None
        nf.types = {}
        return self._apply(nf)

    def estimate_matrices(self, keys) -> np.ndarray:
        """(K, m, m): the estimates of the group variables ``keys`` (all of one group)."""
        self._solve()
        vs = np.array([self._var_of(k) for k in np.asarray(keys).tolist()], dtype=np.int64)
        names = {self.vgroup[v] for v in vs.tolist()}
        if len(names) != 1 or None in names:
            raise SmootherError("estimate_matrices: the keys must all hold elements of one group")
        el = self.elements[names.pop()]
        out = np.empty((len(vs), el.spec.mat, el.spec.mat))
        el.loops.retract(np.ascontiguousarray(el.X[self.velem[vs]]), self.bf.delta, self.bf.tree.voff[vs], out)
        return out

    def estimate_matrix(self, key) -> np.ndarray:
        """The estimate θ ⊕ δ of the group variable ``key`` as its (m, m) matrix."""
        self._solve()
        v = self._var_of(key)
        if self.vgroup[v] is None:
            raise SmootherError(f"key {key_name(int(key))} is not a group element")
        return self._estimate_matrix(v)

    def _validate(self, nf: _NewFactors) -> None:
        var = self.var
        seen = set()
        for k in nf.keys:
            if k in var:
                raise SmootherError(f"key {key_name(k)} is already a variable of the smoother")
            if k in seen:
                raise SmootherError(f"key {key_name(k)} is given twice")
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
                    raise SmootherError(f"a {name} factor uses key {key_name(k)}, which has no value "
                                        "(neither new nor in the smoother)")
                if g != name:
                    raise SmootherError(f"key {key_name(k)} holds a {g or 'non-group value'}, "
                                        f"not a {name} (used by a {name} factor)")
        for f, keys in nf.native:
            for k in keys:
                used.add(k)
                if k not in new_group and k not in var:
                    raise SmootherError(f"a {type(f).__name__} uses key {key_name(k)}, which has no value "
                                        "(neither new nor in the smoother)")
        for k in nf.keys:
            if k not in used:
                raise SmootherError(f"new key {key_name(k)} is in no new factor: it would be unconstrained")

    def _apply(self, nf: _NewFactors) -> UpdateResult:
        self._validate(nf)
        p = self.params
        count = self.update_count + 1
        relin_vars = np.zeros(0, dtype=np.int64)
        if p.enableRelinearization and count % p.relinearizeSkip == 0 and self.bf.nv:
            self._solve()
            relin_vars = self._relinearize_set()
        undo = _Undo(self)
        try:
            new_vars = self._add_variables(nf, undo)
            refreshed = self._relinearize(relin_vars, undo) if len(relin_vars) else []
            new_factors = self._add_factors(nf, undo)
            self.bf.update(new_dims=np.array(nf.dims, dtype=np.int64), new_factors=new_factors,
                           refreshed=refreshed, relinearized=relin_vars)
        except IndeterminantLinearSystem as exc:
            undo.run()
            v = exc.variable
            name = key_name(self.keys[v]) if v < len(self.keys) else key_name(nf.keys[v - len(self.keys)]) \
                if v - len(self.keys) < len(nf.keys) else str(v)
            raise IndeterminantLinearSystem(
                f"the update leaves variable {name} undetermined (a pivot of its column is not positive): "
                "the factors so far do not constrain it", v) from None
        except BaseException:
            undo.run()
            raise
        del new_vars
        self.update_count = count
        self.relinearizations += len(relin_vars)
        self.reorderings += int(self.bf.last.batch)
        self._fresh = False
        return UpdateResult(self.bf.last.columns, len(relin_vars), self.bf.nv, self.bf.last.batch)

    def _add_variables(self, nf: _NewFactors, undo) -> list:
        nv0 = len(self.keys)
        P = len(nf.keys)
        if not P:
            return []
        ids = list(range(nv0, nv0 + P))
        undo.vars(nv0)
        self.velem = _grow(self.velem, nv0 + P)
        self.vcode = _grow(self.vcode, nv0 + P)
        self.vnative = _grow(self.vnative, nv0 + P)
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
        """Copy the value of ``key`` (a type GTSAM holds, :meth:`_read` found which) from ``src``."""
        dest.insert(key, getattr(src, f"at{self.other_types[key]}")(key))

    def _add_factors(self, nf: _NewFactors, undo) -> list:
        out = []
        var = self.var
        for (kind, name), entry in nf.arrays.items():
            store = self.kinds.get((kind, name))
            if store is None:
                store = self.kinds[(kind, name)] = _FactorKind(kind, _factors.GROUPS[name], self._elements(name))
                store.code = len(self.kind_list)
                self.kind_list.append(store)
            undo.kind(store)
            keys = entry["keys"]
            v = np.fromiter((var[k] for k in keys.ravel().tolist()), dtype=np.int64, count=keys.size).reshape(keys.shape)
            e = self.velem[v]
            idx = store.append(v, e, entry["C"], entry["R"], entry["src"])
            fids = np.arange(self.bf.nf + sum(len(o[0]) for o in out), self.bf.nf + sum(len(o[0]) for o in out) + len(v))
            store.fid[idx] = fids
            self._register(fids, store.code, idx)
            out.append((v, store.jacobians(idx)))
        if nf.native:
            undo.native(len(self.native))
            base = self.bf.nf + sum(len(o[0]) for o in out)
            for q, (f, keys) in enumerate(nf.native):
                vs = np.array([var[k] for k in keys], dtype=np.int64)
                self.native.append((f, vs, base + q))
                self._register(np.array([base + q]), -1, np.array([len(self.native) - 1]))
                out.append((vs[None, :], self._native_jacobian(f)[None]))
        return out

    def _register(self, fids: np.ndarray, code: int, local: np.ndarray) -> None:
        """Factor ids ``fids`` are entries ``local`` of kind ``code`` (−1: native factors).  (Ids
        past the block factor's count are dropped with it if the update fails.)"""
        n = int(fids.max()) + 1
        self.fkind = _grow(self.fkind, n)
        self.flocal = _grow(self.flocal, n)
        self.fkind[fids] = code
        self.flocal[fids] = local

    def _native_jacobian(self, f) -> np.ndarray:
        """[A | b] of a factor GTSAM linearizes at θ (rows: a JacobianFactor's, or a square root of
        a HessianFactor's augmented information)."""
        try:
            lf = f.linearize(self.native_theta)
        except RuntimeError as exc:
            raise SmootherError(f"{type(f).__name__} could not be linearized: {str(exc).strip()[:200]}") from None
        if isinstance(lf, gtsam.JacobianFactor):
            if lf.isConstrained():
                raise SmootherError(f"{type(f).__name__} has a constrained noise model: not supported")
            A, b = lf.jacobian()
            J = np.concatenate([np.asarray(A), np.asarray(b).reshape(-1, 1)], axis=1)
        else:
            M = np.asarray(lf.augmentedInformation())
            w, Q = np.linalg.eigh(M)
            J = np.sqrt(np.clip(w, 0.0, None))[:, None] * Q.T
            J[:, -1] *= 1.0  # [A b]ᵀ[A b] = M: b is the last column
        if not np.all(np.isfinite(J)):
            raise SmootherError(f"{type(f).__name__} linearized to non-finite numbers")
        return J

    # ------------------------------------------------------------------ relinearization
    def _relinearize_set(self) -> np.ndarray:
        bf = self.bf
        th = self.params.relinearizeThreshold
        moved = bf.largest_steps()
        if self.params.relinearizePolicy == "global":
            return np.arange(bf.nv, dtype=np.int64) if moved.size and moved.max() >= th else moved[:0].astype(np.int64)
        return np.flatnonzero(moved >= th).astype(np.int64)

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
            el.loops.retract(np.ascontiguousarray(el.X[e]), bf.delta, bf.tree.voff[vs], out)
            el.X[e] = out
        # the variables GTSAM holds: retracted one by one, in place (the old values kept for undo)
        for v in relin[codes < 0].tolist():
            k = self.keys[v]
            one = gtsam.Values()
            self._insert_from(one, self.other, k)
            vv = gtsam.VectorValues()
            vv.insert(k, bf.variable_delta(v).copy())
            moved = getattr(one.retract(vv), f"at{self.other_types[k]}")(k)
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
        for local in fl[fk < 0].tolist():
            f, _, fid = self.native[local]
            out.append((np.array([fid]), self._native_jacobian(f)[None]))
        return out

    # ------------------------------------------------------------------ solving and reading
    def _solve(self) -> None:
        if not self._fresh:
            self.bf.solve(self.params.wildfireThreshold)
            self._fresh = True

    def getDelta(self) -> gtsam.VectorValues:
        """δ (the step from θ to the estimate) as a ``gtsam.VectorValues``."""
        self._solve()
        vv = gtsam.VectorValues()
        for v, k in enumerate(self.keys):
            vv.insert(k, self.bf.variable_delta(v).copy())
        return vv

    def _var_of(self, key) -> int:
        v = self.var.get(int(key))
        if v is None:
            raise SmootherError(f"key {key_name(int(key))} is not a variable of the smoother")
        return v

    def _estimate_matrix(self, v: int) -> np.ndarray:
        el = self.elements[self.vgroup[v]]
        out = np.empty((1, el.spec.mat, el.spec.mat))
        e = self.velem[v:v + 1]
        el.loops.retract(np.ascontiguousarray(el.X[e]), self.bf.delta, self.bf.tree.voff[v:v + 1], out)
        return out[0]

    def calculateEstimate(self, key=None):
        """θ ⊕ δ: a ``gtsam.Values`` of every variable, or the value of ``key``."""
        self._solve()
        if key is not None:
            v = self._var_of(key)
            name = self.vgroup[v]
            if name is not None:
                return to_gtsam(name, self._estimate_matrix(v))
            return self._other_estimate(v)
        out = gtsam.Values()
        bf = self.bf
        for name, el in self.elements.items():
            X = np.empty_like(el.X[:el.n])
            el.loops.retract(np.ascontiguousarray(el.X[:el.n]), bf.delta, bf.tree.voff[el.var[:el.n]], X)
            spec = el.spec
            for v, M in zip(el.var[:el.n].tolist(), X):
                out.insert(self.keys[v], to_gtsam(spec.name, M))
        if self.other.size():
            vv = gtsam.VectorValues()
            for v, k in enumerate(self.keys):
                if self.vgroup[v] is None:
                    vv.insert(k, bf.variable_delta(v).copy())
            out.insert(self.other.retract(vv))
        return out

    def _other_estimate(self, v: int):
        k = self.keys[v]
        vv = gtsam.VectorValues()
        vv.insert(k, self.bf.variable_delta(v).copy())
        one = gtsam.Values()
        self._insert_from(one, self.other, k)
        return getattr(one.retract(vv), f"at{self.other_types[k]}")(k)

    def getLinearizationPoint(self) -> gtsam.Values:
        """θ as a ``gtsam.Values`` (a copy)."""
        out = gtsam.Values()
        for name, el in self.elements.items():
            for v, M in zip(el.var[:el.n].tolist(), el.X[:el.n]):
                out.insert(self.keys[v], to_gtsam(el.spec.name, M))
        if self.other.size():
            out.insert(self.other)
        return out

    def getFactorsUnsafe(self) -> gtsam.NonlinearFactorGraph:
        """Every factor added, in the order added (factors given as arrays are made as GTSAM's
        ``BetweenFactor``/``PriorFactor`` with ``noiseModel.Gaussian.Information``)."""
        graph = gtsam.NonlinearFactorGraph()
        for code, local in zip(self.fkind[:self.bf.nf].tolist(), self.flocal[:self.bf.nf].tolist()):
            if code < 0:
                graph.push_back(self.native[local][0])
                continue
            store = self.kind_list[code]
            f = store.source[local]
            if f is None:
                f = self._make_factor(store, local)
            graph.push_back(f)
        return graph

    def _make_factor(self, store: _FactorKind, local: int):
        spec = store.spec
        M = to_gtsam(spec.name, np.linalg.inv(store.C[local]))
        R = store.R[local]
        model = gtsam.noiseModel.Gaussian.Information(R.T @ R)
        keys = [self.keys[v] for v in store.v[local].tolist()]
        cls = getattr(gtsam, f"{'BetweenFactor' if store.kind == 'between' else 'PriorFactor'}{spec.name}")
        return cls(*keys, M, model)

    def marginalCovariance(self, key) -> np.ndarray:
        """The marginal covariance of ``key`` at θ, (d, d): its block of Λ⁻¹, from the path of
        its column to the root of the factor (cheapest for the newest variables)."""
        return self.bf.marginal_covariance(self._var_of(key))

    def error(self, values: gtsam.Values | None = None) -> float:
        """The graph's error ½Σ‖whitened residual‖² at ``values`` (default: the estimate)."""
        values = self.calculateEstimate() if values is None else values
        return float(self.getFactorsUnsafe().error(values))

    def optimize(self, max_iterations: int = 100, tolerance: float = 1e-10) -> int:
        """Relinearize every variable and take Gauss–Newton steps until the largest step
        component is below ``tolerance``; returns the iterations taken."""
        bf = self.bf
        for it in range(1, max_iterations + 1):
            bf.replace_all()  # the exact solution of the current system
            self._fresh = False
            saved = self.params.wildfireThreshold
            self.params.wildfireThreshold = 0.0
            try:
                self._solve()
            finally:
                self.params.wildfireThreshold = saved
            step = float(np.max(np.abs(bf.delta[:bf.nscalar]))) if bf.nscalar else 0.0
            relin = np.arange(bf.nv, dtype=np.int64)
            undo = _Undo(self)
            try:
                refreshed = self._relinearize(relin, undo)
                bf.update(refreshed=refreshed, relinearized=relin)
            except BaseException:
                undo.run()
                raise
            self.relinearizations += bf.nv
            self.reorderings += int(bf.last.batch)
            self._fresh = False
            if step < tolerance:
                return it
        return max_iterations


def _typed_estimate(type_name: str):
    def typed(self, key):
        value = self.calculateEstimate(key)
        if type(value).__name__ == type_name or (isinstance(value, np.ndarray) and (
                type_name in ("Vector", "Matrix") or type_name == f"Point{value.shape[0]}")):
            return value
        raise SmootherError(f"key {key_name(int(key))} holds a {type(value).__name__}, not a {type_name}")

    typed.__name__ = typed.__qualname__ = f"calculateEstimate{type_name}"
    typed.__doc__ = f"The estimate of ``key``, a ``gtsam.{type_name}`` (ISAM2's typed form)."
    return typed


for _type in _VALUE_TYPES:
    setattr(Smoother, f"calculateEstimate{_type}", _typed_estimate(_type))


class _Undo:
    """What an update changed in the smoother's Python state, to put back if it fails
    (the block factor restores itself)."""

    def __init__(self, s: Smoother):
        self.s = s
        self.steps: list = []

    def vars(self, nv0):
        s = self.s
        n_keys = len(s.keys)

        def back():
            for k in s.keys[nv0:]:
                s.var.pop(k, None)
            del s.keys[n_keys:]
            del s.vgroup[n_keys:]
        self.steps.append(back)

    def elements(self, el):
        n = el.n
        self.steps.append(lambda: setattr(el, "n", n))

    def inserted(self, values: gtsam.Values, key: int):
        self.steps.append(lambda: values.erase(key))

    def updated(self, values: gtsam.Values, key: int, old):
        self.steps.append(lambda: values.update(key, old))

    def theta(self, el, e):
        X = el.X[e].copy()

        def back():
            el.X[e] = X
        self.steps.append(back)

    def kind(self, store):
        n = store.n
        self.steps.append(lambda: store.truncate(n))

    def vnative(self):
        s = self.s
        saved = s.vnative.copy()
        self.steps.append(lambda: setattr(s, "vnative", saved))

    def native(self, n):
        s = self.s
        self.steps.append(lambda: s.native.__delitem__(slice(n, None)))

    def run(self):
        for step in reversed(self.steps):
            step()
        self.steps = []
