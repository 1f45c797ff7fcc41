"""Batch Levenberg–Marquardt: every lie_factors factor of a kind in one vectorized pass.

Why: GTSAM's Python ``CustomFactor`` converts the whole ``Values`` into a new
Python object on every callback when it is called from inside a C++ optimizer,
so LM over :mod:`lie_factors.factors` is ~30× slower than native GTSAM.  Driven
from Python there is no such copy.  This module

* groups the graph's lie_factors factors by (kind, group) and keeps their
  constants as arrays (``M⁻¹``, ``Ad(M⁻¹)``, whitening ``R``, key indices);
* keeps the poses as an ``(N, m, m)`` array of matrices per group;
* linearizes each group with one numba loop over the *same* per-factor
  kernels the factors call (``factors.between`` / ``factors.prior``: inverse,
  compose, log, dlog, H1 = −dlog(e)·Ad(M⁻¹), H2 = dlog(−e)), evaluates errors
  with ``factors.between_error`` / ``prior_error`` and retracts ``X·exp(δ)``
  with the groups' ``_exp/_compose`` cores — no formula is written a second
  time here; every loop is a cached top-level kernel that takes the group id
  (:mod:`lie_factors._dispatch`), so only the first run on a machine compiles;
* linearizes every other factor (native GTSAM factors, lie_factors factors
  with robust or constrained noise) through GTSAM (``factor.linearize``);
* creates the GaussianFactorGraph once — one whitened ``JacobianFactor(k1, A1,
  k2, A2, b, unit)`` per factor plus GTSAM's λ-prior per variable — and at
  every linearization / λ writes the new blocks straight into those factors'
  storage from numba (``getA()``/``getb()`` are views of it; checked on real
  data, with a rebuild-per-iteration fallback, ``inplace=False``), so a step
  costs no Python→C++ object construction at all;
* solves each damped step with GTSAM's sparse multifrontal elimination
  (``gfg.optimize(ordering)``; ordering computed once with the params'
  ordering type, COLAMD by default, from the nonlinear graph — as GTSAM's LM
  does);
* runs Levenberg–Marquardt with GTSAM's ``LevenbergMarquardtOptimizer``
  semantics (``tryLambda``/``iterate``/``defaultOptimize``/``checkConvergence``;
  see :class:`BatchLevenbergMarquardt`).

Usage::

    from lie_factors import batch
    result = batch.optimize(graph, initial)          # or params=LevenbergMarquardtParams
    result.values, result.iterations, result.errors, result.seconds, result.converged

For the CLI: :func:`run_batch` has the signature of ``posegraph.optimize``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import gtsam
import numpy as np

from . import _batch_loops
from . import factors as _factors
from ._batch_loops import col_sumsq, linear_error1, linear_error2
from .errors import PoseGraphError
from .results import IterationInfo, OptimizeResult
from ._jacobian_storage import pointers, scatter1, scatter2, write_diagonal

__all__ = ["BatchLevenbergMarquardt", "BatchResult", "optimize", "run_batch", "BatchError"]

#: GTSAM defaults that the Python wrapper does not expose (LevenbergMarquardtParams.h).
MIN_MODEL_FIDELITY = 1e-3
MIN_DIAGONAL = 1e-6
MAX_DIAGONAL = 1e32


class BatchError(ValueError):
    """Bad input to the batch optimizer (unsupported factor, missing key, ...)."""


def _key_name(key: int) -> str:
    return gtsam.DefaultKeyFormatter(int(key))


def _first_line(exc: BaseException, limit: int = 200) -> str:
    """First line of an exception message, truncated (GTSAM messages can embed whole objects)."""
    text = str(exc).strip().splitlines()
    return (text[0] if text else type(exc).__name__)[:limit]


# --------------------------------------------------------------------------- #
# Graph extraction
# --------------------------------------------------------------------------- #

def _whitening(noise_model):
    """Upper-triangular R with ‖R e‖² = Mahalanobis², or None if GTSAM must linearize."""
    if isinstance(noise_model, (gtsam.noiseModel.Robust, gtsam.noiseModel.Constrained)):
        return None
    if not isinstance(noise_model, gtsam.noiseModel.Gaussian):
        return None
    return noise_model.R()  # finite for every non-constrained Gaussian


class _VarBlock:
    """The variables of one group: keys, matrices, offsets into the global δ."""

    def __init__(self, spec):
        self.spec = spec
        self.keys: list[int] = []
        self.index: dict[int, int] = {}
        self.X: np.ndarray | None = None
        self.offsets: np.ndarray | None = None



class _Group:
    """All lie_factors factors of one (kind, group) with Gaussian noise."""

    def __init__(self, kind, spec):
        self.kind, self.spec = kind, spec
        self.rows: list = []  # (local idx1, idx2 | None, constant matrix, AdMinv | None, R, key1, key2)

    def finalize(self, block: _VarBlock):
        n = self.spec.dim
        E = len(self.rows)
        self.E = E
        self.i1 = np.array([r[0] for r in self.rows], dtype=np.int64)
        self.k1 = [int(block.keys[i]) for i in self.i1]
        self.C = np.ascontiguousarray(np.array([r[2] for r in self.rows], dtype=np.float64))
        self.R = np.ascontiguousarray(np.array([r[4] for r in self.rows], dtype=np.float64).reshape(E, n, n))
        if self.kind == "between":
            self.i2 = np.array([r[1] for r in self.rows], dtype=np.int64)
            self.k2 = [int(block.keys[i]) for i in self.i2]
            self.Ad = np.ascontiguousarray(np.array([r[3] for r in self.rows], dtype=np.float64))
            self.A2 = np.empty((E, n, n))
        self.A1 = np.empty((E, n, n))
        self.b = np.empty((E, n))
        # Persistent per-factor views: the arrays are refilled in place at each linearization.
        if self.kind == "between":
            self.views = list(zip(self.k1, self.A1, self.k2, self.A2, self.b))
        else:
            self.views = list(zip(self.k1, self.A1, self.b))
        self.rows = None


def _read_matrices(values: gtsam.Values, spec, keys: list) -> np.ndarray:
    """(N, m, m) matrices of ``keys`` in ``values``; BatchError naming a missing/mistyped key."""
    m = spec.kernels.MAT
    X = np.empty((len(keys), m, m))
    for k in keys:
        if not values.exists(k):
            raise BatchError(f"key {_key_name(k)} is used by a {spec.name} factor "
                             "but is missing from the initial Values")
    if spec.name in ("Pose3", "Pose2"):
        # Bulk extraction in C++ (all values of that type, in key order).
        if spec.name == "Pose3":
            typed = gtsam.utilities.allPose3s(values)
            E = np.asarray(gtsam.utilities.extractPose3(values))
        else:
            typed = gtsam.utilities.allPose2s(values)
            E = np.asarray(gtsam.utilities.extractPose2(values))
        tkeys = np.asarray(typed.keys(), dtype=np.uint64)
        want = np.asarray(keys, dtype=np.uint64)
        pos = np.searchsorted(tkeys, want)
        pos = np.minimum(pos, max(len(tkeys) - 1, 0))
        bad = np.nonzero((len(tkeys) == 0) | (tkeys[pos] != want))[0] if len(want) else []
        if len(bad):
            k = keys[bad[0]]
            raise BatchError(f"key {_key_name(k)} must hold a gtsam.{spec.name} "
                             f"(it is used by a {spec.name} factor)")
        E = E[pos]
        if spec.name == "Pose3":
            X[:] = 0.0
            X[:, :3, :3] = E[:, :9].reshape(-1, 3, 3)
            X[:, :3, 3] = E[:, 9:12]
            X[:, 3, 3] = 1.0
        else:
            c, s_ = np.cos(E[:, 2]), np.sin(E[:, 2])
            X[:] = 0.0
            X[:, 0, 0], X[:, 0, 1], X[:, 1, 0], X[:, 1, 1] = c, -s_, s_, c
            X[:, 0, 2], X[:, 1, 2], X[:, 2, 2] = E[:, 0], E[:, 1], 1.0
        return X
    at = getattr(values, spec.at)
    for j, k in enumerate(keys):
        try:
            X[j] = at(k).matrix()
        except RuntimeError:
            raise BatchError(f"key {_key_name(k)} must hold a gtsam.{spec.name} "
                             f"(it is used by a {spec.name} factor)") from None
    return X


def _to_gtsam(spec, M: np.ndarray):
    name = spec.name
    if name == "Pose3":
        return gtsam.Pose3(M)
    if name == "Rot3":
        return gtsam.Rot3(M)
    if name == "Pose2":
        return gtsam.Pose2(M[0, 2], M[1, 2], math.atan2(M[1, 0], M[0, 0]))
    if name == "Similarity2":
        return gtsam.Similarity2(gtsam.Rot2.atan2(M[1, 0], M[0, 0]), np.array([M[0, 2], M[1, 2]]),
                                 1.0 / M[2, 2])
    if name == "Similarity3":
        return gtsam.Similarity3(M)
    raise AssertionError(name)


# --------------------------------------------------------------------------- #
# Result
# --------------------------------------------------------------------------- #

@dataclass
class BatchResult:
    """What :func:`optimize` returns.

    ``errors[0]`` is the initial error, ``errors[k]`` the error after iteration
    k; ``lambdas[k]`` is λ after iteration k (``lambdas[0]`` the initial λ).
    ``timings`` splits ``seconds`` into linearize / build (GaussianFactorGraph
    construction incl. damping) / eliminate / retract / error / other.
    """

    values: gtsam.Values
    iterations: int
    errors: list[float]
    lambdas: list[float]
    seconds: float
    converged: bool
    inner_iterations: int = 0
    timings: dict = field(default_factory=dict)

    @property
    def initial_error(self) -> float:
        return self.errors[0]

    @property
    def final_error(self) -> float:
        return self.errors[-1]


# --------------------------------------------------------------------------- #
# The optimizer
# --------------------------------------------------------------------------- #

class BatchLevenbergMarquardt:
    """Levenberg–Marquardt over ``graph`` from ``initial``, mirroring GTSAM's optimizer.

    Semantics (GTSAM ``LevenbergMarquardtOptimizer``/``LevenbergMarquardtState``):

    * damping: a prior ``√λ·I`` (or ``√λ·diag(√clamp(diag JᵀJ, 1e-6, 1e32))``
      with ``diagonalDamping``) on every variable (diagonal: every variable
      that appears in a factor), added for each λ tried;
    * a step is tried only if the linearized cost decreases; it is accepted if
      ``fidelity = Δcost / Δlinearized > minModelFidelity (1e-3)``, provided
      ``Δlinearized > ε·linearized error``;
    * accepted: ``λ ← max(lowerBound, λ·max(1/3, 1 − (2·fidelity − 1)³))``,
      factor ← 2·factor (or ``λ ← λ/factor`` with ``useFixedLambdaFactor``);
      rejected: ``λ ← λ·factor``, factor ← 2·factor (unless fixed); give up
      once ``λ ≥ lambdaUpperBound``, or stop trying when
      ``|Δcost| < relativeErrorTol·error``;
    * :meth:`optimize`: nothing if error ≤ errorTol or iterations ≥
      maxIterations, else iterate while iterations < maxIterations, not
      ``gtsam.checkConvergence`` and the error is finite.

    ``min_model_fidelity`` is GTSAM's ``minModelFidelity`` (not exposed by the
    Python wrapper; GTSAM's default).
    """

    def __init__(self, graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values,
                 params: gtsam.LevenbergMarquardtParams | None = None,
                 min_model_fidelity: float = MIN_MODEL_FIDELITY, inplace: bool = True):
        t0 = time.perf_counter()
        self.params = params if params is not None else gtsam.LevenbergMarquardtParams()
        self.graph = graph
        self.min_model_fidelity = float(min_model_fidelity)
        self._read_params()
        self._extract(graph, initial)
        self._timings = dict(setup=0.0, create=0.0, linearize=0.0, build=0.0, eliminate=0.0,
                             retract=0.0, error=0.0, native=0.0)
        self._ordering = None
        self._damping = None
        self._base = None
        self._persistent = None if inplace else False
        self._unit = {}
        self._keep = None
        self._vector_checked = False
        # State (LevenbergMarquardtState)
        self.lambda_ = self.lambda_initial
        self.current_factor = self.lambda_factor
        self._iterations = 0
        self.inner_iterations = 0
        t1 = time.perf_counter()
        self._error = self._total_error(self._blocks_X(), self._native_values(None))
        self._timings["error"] += time.perf_counter() - t1
        self.errors = [self._error]
        self.lambdas = [self.lambda_]
        self._timings["setup"] += time.perf_counter() - t0

    # ---------------------------------------------------------------- params
    def _read_params(self):
        p = self.params
        self.max_iterations = int(p.getMaxIterations())
        self.relative_tol = float(p.getRelativeErrorTol())
        self.absolute_tol = float(p.getAbsoluteErrorTol())
        self.error_tol = float(p.getErrorTol())
        self.lambda_initial = float(p.getlambdaInitial())
        self.lambda_factor = float(p.getlambdaFactor())
        self.lambda_upper = float(p.getlambdaUpperBound())
        self.lambda_lower = float(p.getlambdaLowerBound())
        self.diagonal_damping = bool(p.getDiagonalDamping())
        self.fixed_factor = bool(p.getUseFixedLambdaFactor())
        self.verbosity = str(p.getVerbosity())
        self.verbosity_lm = str(p.getVerbosityLM())
        self._verbose_error = self.verbosity in ("ERROR", "VALUES", "DELTA", "LINEAR")
        self._verbose_termination = self.verbosity not in ("SILENT",)
        self._summary = self.verbosity_lm == "SUMMARY"
        self._trylambda = self.verbosity_lm in ("TRYLAMBDA", "TRYCONFIG", "DAMPED", "TRYDELTA")

    # ------------------------------------------------------------ extraction
    def _extract(self, graph, initial):
        if not isinstance(graph, gtsam.NonlinearFactorGraph):
            raise TypeError(f"graph must be a gtsam.NonlinearFactorGraph, got {type(graph).__name__}")
        if not isinstance(initial, gtsam.Values):
            raise TypeError(f"initial must be a gtsam.Values, got {type(initial).__name__}")
        self.blocks: dict[str, _VarBlock] = {}
        self.groups: list[_Group] = []
        groups: dict = {}
        self.native: list = []  # (index, factor, keys)
        # Hot loop (one pass over the graph): per-class and per-noise-class lookups
        # instead of isinstance chains; R() only for the Gaussian family.
        kinds: dict = {}
        gaussian = (gtsam.noiseModel.Gaussian, gtsam.noiseModel.Diagonal,
                    gtsam.noiseModel.Isotropic, gtsam.noiseModel.Unit)
        at = graph.at
        for i in range(graph.size()):
            f = at(i)
            if f is None:
                continue
            cls = type(f)
            entry = kinds.get(cls)
            if entry is None:
                kind = ("between" if issubclass(cls, _factors.BetweenFactor)
                        else "prior" if issubclass(cls, _factors.PriorFactor) else None)
                if kind is None:
                    entry = kinds[cls] = (None, None, None)
                else:
                    spec = cls.spec
                    block = self.blocks.setdefault(spec.name, _VarBlock(spec))
                    g = groups.get((kind, spec.name))
                    if g is None:
                        g = groups[(kind, spec.name)] = _Group(kind, spec)
                        self.groups.append(g)
                    entry = kinds[cls] = (kind, block.index, g.rows)
            kind, index, rows = entry
            R = None
            if kind is not None:
                nm = f.noiseModel()
                R = nm.R() if type(nm) in gaussian else _whitening(nm)
            if R is None:
                if not isinstance(f, gtsam.NonlinearFactor):
                    raise BatchError(f"factor {i}: unsupported type {type(f).__name__}")
                keys = [int(k) for k in f.keys()]
                for k in keys:
                    if not initial.exists(k):
                        raise BatchError(f"factor {i} ({type(f).__name__}): key {_key_name(k)} "
                                         "is missing from the initial Values")
                self.native.append((i, f, keys))
                continue
            if kind == "between":
                k1, k2 = f._key1, f._key2
                rows.append((index.setdefault(k1, len(index)), index.setdefault(k2, len(index)),
                             f._Minv, f._AdMinv, R, k1, k2))
            else:
                k1 = f._key
                rows.append((index.setdefault(k1, len(index)), None, f._Pinv, None, R, k1, None))
        for block in self.blocks.values():
            block.keys = list(block.index)  # dicts keep insertion order = local index order
        # Variable matrices, type-checked.
        managed = {}
        for name, block in self.blocks.items():
            spec = block.spec
            for k in block.keys:
                if k in managed:
                    raise BatchError(f"key {_key_name(k)} is used by both {managed[k]} and "
                                     f"{spec.name} factors")
                managed[k] = spec.name
            block.X = _read_matrices(initial, spec, block.keys)
        for g in self.groups:
            g.finalize(self.blocks[g.spec.name])
        # Every variable of `initial` gets a slot in δ (GTSAM damps all of them).
        zero = initial.zeroVectors()
        all_keys = sorted(int(k) for k in initial.keys())
        self.dims = {}
        for k in all_keys:
            if k in managed:
                self.dims[k] = self.blocks[managed[k]].spec.dim
            else:
                self.dims[k] = int(np.asarray(zero.at(k)).shape[0])
        self.keys = all_keys
        self.offset = {}
        o = 0
        for k in all_keys:
            self.offset[k] = o
            o += self.dims[k]
        self.total_dim = o
        for block in self.blocks.values():
            block.offsets = np.array([self.offset[k] for k in block.keys], dtype=np.int64)
        for g in self.groups:
            off = self.blocks[g.spec.name].offsets
            g.o1 = off[g.i1]
            if g.kind == "between":
                g.o2 = off[g.i2]
        # Unmanaged variables (only touched by native factors, or by none).
        self.other_keys = [k for k in all_keys if k not in managed]
        self.other = gtsam.Values(initial)
        for k in managed:
            self.other.erase(k)
        self._managed_initial = gtsam.Values(initial)
        for k in self.other_keys:
            self._managed_initial.erase(k)
        for b in self.blocks.values():
            b.X0 = b.X.copy()
        self.managed = managed
        self._native_keys = sorted({k for _, _, ks in self.native for k in ks})
        for name, block in self.blocks.items():
            _batch_loops.bound_to(block.spec)  # compile before timing iterations
        for g in self.groups:
            g.loops = _batch_loops.bound_to(g.spec)

    # ------------------------------------------------------------ state
    def _blocks_X(self):
        return {name: b.X for name, b in self.blocks.items()}

    def _native_values(self, Xs, other=None) -> gtsam.Values | None:
        """A gtsam.Values holding just the keys the native factors need."""
        if not self.native:
            return None
        if Xs is None:
            Xs = self._blocks_X()
        other = self.other if other is None else other
        v = gtsam.Values(other)
        for k in self._native_keys:
            name = self.managed.get(k)
            if name is not None:
                b = self.blocks[name]
                v.insert(k, _to_gtsam(b.spec, Xs[name][b.index[k]]))
        return v

    def _total_error(self, Xs, nvalues) -> float:
        total = 0.0
        for g in self.groups:
            X = Xs[g.spec.name]
            if g.kind == "between":
                total += g.loops[2](X, g.i1, g.i2, g.C, g.R)
            else:
                total += g.loops[3](X, g.i1, g.C, g.R)
        if self.native:
            t = time.perf_counter()
            for i, f, _ in self.native:
                try:
                    total += f.error(nvalues)
                except BatchError:
                    raise
                except Exception as exc:
                    raise BatchError(f"factor {i} ({type(f).__name__}) could not be evaluated: "
                                     f"{type(exc).__name__}: {_first_line(exc)}") from None
            self._timings["native"] += time.perf_counter() - t
        return float(total)

    def error(self) -> float:
        return self._error

    def iterations(self) -> int:
        return self._iterations

    def lambda_value(self) -> float:
        return self.lambda_

    def values(self) -> gtsam.Values:
        """The current estimate as a gtsam.Values (all keys of the initial Values).

        Built in C++ as ``initial.retract(ξ)`` with ξ = Log(X₀⁻¹·X) per
        variable (vectorized on the kernels): ~5× faster than constructing
        every pose from Python, and exact to rounding (checked in the tests).
        """
        vv = gtsam.VectorValues()
        insert = vv.insert
        for name, b in self.blocks.items():
            xi = np.empty((len(b.keys), b.spec.dim))
            _batch_loops.bound_to(b.spec)[5](b.X0, b.X, xi)
            for k, x in zip(b.keys, xi):
                insert(k, x)
        out = self._managed_initial.retract(vv)
        if self.other_keys:
            out.insert(self.other)
        return out

    # ------------------------------------------------------------ linearization
    def _linearize(self):
        """Fill every group's whitened (A1, A2, b); linearize native factors via GTSAM.

        Returns the linearized error at δ = 0 (½‖b‖² summed, GTSAM's
        ``linear.error(VectorValues::Zero)``).
        """
        t = time.perf_counter()
        total = 0.0
        for g in self.groups:
            X = self.blocks[g.spec.name].X
            if g.kind == "between":
                total += g.loops[0](X, g.i1, g.i2, g.C, g.Ad, g.R, g.A1, g.A2, g.b)
            else:
                total += g.loops[1](X, g.i1, g.C, g.R, g.A1, g.b)
        self._timings["linearize"] += time.perf_counter() - t
        self._native_linear = []
        if self.native:
            t = time.perf_counter()
            nv = self._native_values(None)
            zero = None
            for i, f, keys in self.native:
                try:
                    lf = f.linearize(nv)
                except Exception as exc:
                    raise BatchError(f"factor {i} ({type(f).__name__}) could not be linearized: "
                                     f"{type(exc).__name__}: {_first_line(exc)}") from None
                if lf is None:
                    continue
                vv = gtsam.VectorValues()
                for k in keys:
                    vv.insert(k, np.zeros(self.dims[k]))
                total += lf.error(vv)
                self._native_linear.append((lf, keys))
            self._timings["native"] += time.perf_counter() - t
        return float(total)

    def _linear_error(self, delta: np.ndarray) -> float:
        total = 0.0
        for g in self.groups:
            if g.kind == "between":
                total += linear_error2(g.A1, g.A2, g.b, g.o1, g.o2, delta)
            else:
                total += linear_error1(g.A1, g.b, g.o1, delta)
        for lf, keys in self._native_linear:
            vv = gtsam.VectorValues()
            for k in keys:
                o = self.offset[k]
                vv.insert(k, delta[o:o + self.dims[k]])
            total += lf.error(vv)
        return float(total)

    def _sqrt_hessian_diagonal(self) -> np.ndarray:
        """√clamp(diag(JᵀJ)) per coordinate; NaN where a variable is in no factor."""
        diag = np.zeros(self.total_dim)
        present = np.zeros(self.total_dim, dtype=bool)
        for g in self.groups:
            col_sumsq(g.A1, g.o1, diag)
            n = g.spec.dim
            present[(g.o1[:, None] + np.arange(n)).ravel()] = True
            if g.kind == "between":
                col_sumsq(g.A2, g.o2, diag)
                present[(g.o2[:, None] + np.arange(n)).ravel()] = True
        for lf, keys in self._native_linear:
            H = np.asarray(lf.information())
            o = 0
            for k in keys:
                d = self.dims[k]
                s = self.offset[k]
                diag[s:s + d] += np.diag(H)[o:o + d]
                present[s:s + d] = True
                o += d
        out = np.sqrt(np.clip(diag, MIN_DIAGONAL, MAX_DIAGONAL))
        out[~present] = np.nan
        return out

    # ------------------------------------------------------------ linear system
    def _unit_model(self, d):
        m = self._unit.get(d)
        if m is None:
            m = self._unit[d] = gtsam.noiseModel.Unit.Create(d)
        return m

    def _make_persistent(self) -> bool:
        """Create the JacobianFactors once and locate their storage (see `scatter2`)."""
        self._persistent = False
        groups_graph = gtsam.GaussianFactorGraph()
        keep = []
        for g in self.groups:
            n = g.spec.dim
            unit = self._unit_model(n)
            Z, z = np.zeros((n, n)), np.zeros(n)
            if g.kind == "between":
                fs = [gtsam.JacobianFactor(k1, Z, k2, Z, z, unit) for k1, k2 in zip(g.k1, g.k2)]
            else:
                fs = [gtsam.JacobianFactor(k1, Z, z, unit) for k1 in g.k1]
            ptrs = pointers(fs, 2 * n if g.kind == "between" else n)
            if ptrs is None:
                return False
            g.ptrs = ptrs
            for f in fs:
                groups_graph.push_back(f)
            keep.append(fs)
        damping_graph = gtsam.GaussianFactorGraph()
        dfs = []
        zeros = {}
        for k in self.keys:
            d = self.dims[k]
            if d not in zeros:
                zeros[d] = (np.zeros((d, d)), np.zeros(d), self._unit_model(d))
            f = gtsam.JacobianFactor(k, *zeros[d])
            damping_graph.push_back(f)
            dfs.append(f)
        ptrA = np.empty(len(dfs), np.int64)
        ldA = np.empty(len(dfs), np.int64)
        dims_all = np.array([self.dims[k] for k in self.keys], dtype=np.int64)
        for d in np.unique(dims_all):
            idx = np.nonzero(dims_all == d)[0]
            ptrs = pointers([dfs[i] for i in idx], int(d))
            if ptrs is None:
                return False
            ptrA[idx], ldA[idx] = ptrs[0], ptrs[1]
        self._damp_ptrs = (ptrA, ldA, None)
        self._damp_dims = np.array([self.dims[k] for k in self.keys], dtype=np.int64)
        self._damp_offsets = np.array([self.offset[k] for k in self.keys], dtype=np.int64)
        keep.append(dfs)
        self._keep = keep  # the factors own the memory the pointers address
        self._groups_graph, self._damping_graph_p = groups_graph, damping_graph
        full = gtsam.GaussianFactorGraph()
        full.push_back(groups_graph)
        full.push_back(damping_graph)
        self._full_graph = full
        self._persistent = True
        return True

    def _scatter(self) -> None:
        for g in self.groups:
            ptrA, ldA, ptrb = g.ptrs
            if g.kind == "between":
                scatter2(g.A1, g.A2, g.b, ptrA, ldA, ptrb)
            else:
                scatter1(g.A1, g.b, ptrA, ldA, ptrb)

    def _check_inplace(self) -> bool:
        """After a scatter: does GTSAM see the written numbers (first/last factor per group)?"""
        for g, fs in zip(self.groups, self._keep):
            for f in {0, g.E - 1}:
                Ab = np.asarray(fs[f].augmentedJacobian())
                want = (np.hstack([g.A1[f], g.A2[f], g.b[f][:, None]]) if g.kind == "between"
                        else np.hstack([g.A1[f], g.b[f][:, None]]))
                if not np.array_equal(Ab, want):
                    return False
        ptrA, ldA, _ = self._damp_ptrs
        probe = np.arange(1.0, self.total_dim + 1.0)
        write_diagonal(ptrA, ldA, self._damp_dims, self._damp_offsets, probe)
        dfs = self._keep[-1]
        for i in {0, len(dfs) - 1}:
            o, d = self._damp_offsets[i], self._damp_dims[i]
            if not np.array_equal(np.asarray(dfs[i].getA()), np.diag(probe[o:o + d])):
                return False
        return True

    def _prepare_system(self) -> None:
        """After linearizing: the undamped system GTSAM will eliminate, in place if possible."""
        if self._persistent is None:
            t = time.perf_counter()
            if self._make_persistent():
                self._scatter()
                if not self._check_inplace():
                    self._persistent = False
            if not self._persistent:
                self._keep = None
            self._timings["create"] = time.perf_counter() - t
        if self._persistent:
            self._scatter()
            if self._native_linear:
                gfg = gtsam.GaussianFactorGraph()
                gfg.push_back(self._groups_graph)
                for lf, _ in self._native_linear:
                    gfg.push_back(lf)
                gfg.push_back(self._damping_graph_p)
                self._system = gfg
            else:
                self._system = self._full_graph
        else:
            self._build_base()

    def _damped(self, sqrt_lambda: float, sqrt_diag) -> gtsam.GaussianFactorGraph:
        if not self._persistent:
            return self._build(sqrt_lambda, sqrt_diag)
        damp = (np.full(self.total_dim, sqrt_lambda) if sqrt_diag is None
                else sqrt_lambda * sqrt_diag)
        ptrA, ldA, _ = self._damp_ptrs
        write_diagonal(ptrA, ldA, self._damp_dims, self._damp_offsets, damp)
        return self._system

    def _build_base(self) -> None:
        """Undamped GaussianFactorGraph of the current linearization (once per iteration).

        One whitened JacobianFactor per factor (unit noise model), then every
        natively linearized factor.  Reused by every λ tried in the iteration.
        """
        gfg = gtsam.GaussianFactorGraph()
        add = gfg.add
        for g in self.groups:
            unit = self._unit_model(g.spec.dim)
            if g.kind == "between":
                for k1, a1, k2, a2, b in g.views:
                    add(k1, a1, k2, a2, b, unit)
            else:
                for k1, a1, b in g.views:
                    add(k1, a1, b, unit)
        for lf, _ in self._native_linear:
            gfg.push_back(lf)
        self._base = gfg

    def _damping_graph(self):
        """The λ-prior JacobianFactors (A = I, b = 0), created once; re-weighted per λ."""
        if self._damping is None:
            graph = gtsam.GaussianFactorGraph()
            fs = []
            eye = {}
            for k in self.keys:
                d = self.dims[k]
                if d not in eye:
                    eye[d] = (np.eye(d), np.zeros(d), self._unit_model(d))
                f = gtsam.JacobianFactor(k, *eye[d])
                graph.push_back(f)
                fs.append(f)
            self._damping = (graph, fs)
        return self._damping

    def _build(self, sqrt_lambda: float, sqrt_diag: np.ndarray | None) -> gtsam.GaussianFactorGraph:
        """Damped system: the base graph plus GTSAM's priors √λ·I (or √λ·√diag(JᵀJ)).

        The priors are persistent factors A = I whose noise model is set to
        σ = 1/(√λ·s) in place (``setModel``), the same whitened rows GTSAM's
        ``buildDampedSystem`` adds; with diagonal damping, variables in no
        factor get no prior (GTSAM damps only the keys of hessianDiagonal).
        """
        dgraph, dfs = self._damping_graph()
        gfg = gtsam.GaussianFactorGraph()
        gfg.push_back(self._base)
        if sqrt_diag is None:
            sig = {}
            for f, k in zip(dfs, self.keys):
                d = self.dims[k]
                v = sig.get(d)
                if v is None:
                    v = sig[d] = np.full(d, 1.0 / sqrt_lambda)
                f.setModel(False, v)
            gfg.push_back(dgraph)
        else:
            sigmas = 1.0 / (sqrt_lambda * sqrt_diag)
            for f, k in zip(dfs, self.keys):
                o = self.offset[k]
                v = sigmas[o:o + self.dims[k]]
                if np.isnan(v[0]):  # variable in no factor: GTSAM skips it
                    continue
                f.setModel(False, v)
                gfg.push_back(f)
        return gfg

    def _ordering_for(self, gfg):
        if self._ordering is None:
            otype = str(self.params.getOrderingType())
            ordering = None
            if otype in ("COLAMD", "METIS", "NATURAL"):
                try:
                    ordering = gtsam.Ordering.CreateNonlinearFactorGraph(
                        getattr(gtsam.Ordering.OrderingType, otype), self.graph)
                except RuntimeError:
                    ordering = None
            if ordering is None or ordering.size() != len(self.keys):
                # Variables in no factor (still damped): order the damped system instead.
                ordering = gtsam.Ordering.Colamd(gtsam.VariableIndex(gfg))
            self._ordering = ordering
        return self._ordering

    def _delta_vector(self, delta: gtsam.VectorValues) -> np.ndarray:
        vec = np.asarray(delta.vector(), dtype=np.float64)
        if not self._vector_checked:
            # VectorValues.vector() concatenates in key order; check it once on a sample.
            ok = vec.shape[0] == self.total_dim
            step = max(1, len(self.keys) // 16)
            for k in (self.keys[::step] + self.keys[-1:]) if ok else ():
                o = self.offset[k]
                if not np.array_equal(np.asarray(delta.at(k)), vec[o:o + self.dims[k]]):
                    ok = False
                    break
            self._vector_by_key = not ok
            self._vector_checked = True
        if self._vector_by_key:
            vec = np.zeros(self.total_dim)
            for k in self.keys:
                o = self.offset[k]
                vec[o:o + self.dims[k]] = delta.at(k)
        return vec

    def _retract(self, vec: np.ndarray):
        Xs = {}
        for name, b in self.blocks.items():
            out = np.empty_like(b.X)
            b.loops_retract = _batch_loops.bound_to(b.spec)[4]
            b.loops_retract(b.X, vec, b.offsets, out)
            Xs[name] = out
        other = self.other
        if self.other_keys:
            vv = gtsam.VectorValues()
            for k in self.other_keys:
                o = self.offset[k]
                vv.insert(k, vec[o:o + self.dims[k]])
            other = self.other.retract(vv)
        return Xs, other

    # ------------------------------------------------------------ LM
    def _try_lambda(self, linear_error0: float, sqrt_diag) -> bool:
        T = self._timings
        t = time.perf_counter()
        gfg = self._damped(math.sqrt(self.lambda_), sqrt_diag)
        ordering = self._ordering_for(gfg)
        T["build"] += time.perf_counter() - t
        model_fidelity = 0.0
        success = False
        stop = False
        new_error = math.inf
        cost_change = 0.0
        t = time.perf_counter()
        try:
            delta = gfg.optimize(ordering)
            solved = True
        except RuntimeError:  # IndeterminantLinearSystemException
            solved = False
        T["eliminate"] += time.perf_counter() - t
        if solved:
            t = time.perf_counter()
            vec = self._delta_vector(delta)
            new_linear = self._linear_error(vec)
            T["error"] += time.perf_counter() - t
            linear_change = linear_error0 - new_linear
            if self._trylambda:
                print(f"linear delta norm = {np.linalg.norm(vec)}")
                print(f"newlinearizedError = {new_linear:.15g}  linearizedCostChange = {linear_change:.15g}")
            if linear_change >= 0:
                t = time.perf_counter()
                Xs, other = self._retract(vec)
                T["retract"] += time.perf_counter() - t
                t = time.perf_counter()
                nvals = self._native_values(Xs, other)
                new_error = self._total_error(Xs, nvals)
                T["error"] += time.perf_counter() - t
                cost_change = self._error - new_error
                if linear_change > np.finfo(float).eps * linear_error0:
                    model_fidelity = cost_change / linear_change
                    success = model_fidelity > self.min_model_fidelity
                    if self._trylambda:
                        print(f"modelFidelity: {model_fidelity}")
                if abs(cost_change) < self.relative_tol * self._error:
                    stop = True
        if self._summary:
            print(f"{self._iterations:4d} {new_error:12.6e} {cost_change:12.4e} "
                  f"{self.lambda_:10.2e} {int(success):4d}")
        if success:
            for name, X in Xs.items():
                self.blocks[name].X = X
            self.other = other
            self._error = new_error
            if self.fixed_factor:
                self.lambda_ /= self.current_factor
            else:
                self.lambda_ *= max(1.0 / 3.0, 1.0 - (2.0 * model_fidelity - 1.0) ** 3)
                self.current_factor *= 2.0
            self.lambda_ = max(self.lambda_lower, self.lambda_)
            self._iterations += 1
            self.inner_iterations += 1
            return True
        if not stop:
            self.lambda_ *= self.current_factor
            self.inner_iterations += 1
            if not self.fixed_factor:
                self.current_factor *= 2.0
            if self.lambda_ >= self.lambda_upper:
                if self._verbose_termination or self._summary:
                    print("Warning:  Levenberg-Marquardt giving up because "
                          "cannot decrease error with maximum lambda")
                return True
            return False
        if self._trylambda:
            print("Levenberg-Marquardt: stopping as relative cost reduction is small")
        return True

    def iterate(self) -> None:
        """One LM iteration (linearize once, try λ until a step is accepted or LM gives up)."""
        linear_error0 = self._linearize()
        t = time.perf_counter()
        create = self._timings.get("create", 0.0)
        self._prepare_system()
        self._timings["build"] += time.perf_counter() - t - (self._timings.get("create", 0.0) - create)
        if self._summary and self.inner_iterations == 0:
            print(f"Initial error: {self._error}, values: {len(self.keys)}")
        sqrt_diag = self._sqrt_hessian_diagonal() if self.diagonal_damping else None
        while not self._try_lambda(linear_error0, sqrt_diag):
            pass

    def optimize(self, progress: Callable[[int, float, float], None] | None = None) -> BatchResult:
        """GTSAM's ``defaultOptimize``; ``progress(iteration, error, lambda)`` after each iterate."""
        t0 = time.perf_counter()
        new_error = self._error
        converged = False
        if new_error <= self.error_tol:
            if self._verbose_error:
                print(f"Exiting, as error = {new_error} < {self.error_tol}")
            converged = True
        elif self._iterations >= self.max_iterations:
            pass
        else:
            while True:
                current_error = new_error
                self.iterate()
                new_error = self._error
                self.errors.append(new_error)
                self.lambdas.append(self.lambda_)
                if self._verbose_error:
                    print(f"newError: {new_error}")
                if progress is not None:
                    progress(self._iterations, new_error, self.lambda_)
                converged = bool(gtsam.checkConvergence(
                    self.relative_tol, self.absolute_tol, self.error_tol, current_error, new_error))
                if (self._iterations >= self.max_iterations or converged
                        or not math.isfinite(current_error)):
                    break
        t1 = time.perf_counter()
        values = self.values()
        self._timings["values"] = time.perf_counter() - t1
        seconds = time.perf_counter() - t0 + self._timings["setup"]
        timings = dict(self._timings)
        timings["other"] = seconds - sum(v for k, v in timings.items() if k not in ("native",))
        return BatchResult(values, self._iterations, list(self.errors), list(self.lambdas), seconds,
                           converged, self.inner_iterations, timings)


def optimize(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values,
             params: gtsam.LevenbergMarquardtParams | None = None,
             progress: Callable[[int, float, float], None] | None = None) -> BatchResult:
    """Batch Levenberg–Marquardt (see :class:`BatchLevenbergMarquardt`)."""
    t0 = time.perf_counter()
    opt = BatchLevenbergMarquardt(graph, initial, params)
    result = opt.optimize(progress)
    result.seconds = time.perf_counter() - t0
    return result


def run_batch(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, max_iterations: int = 100,
              progress: Callable | None = None,
              params: gtsam.LevenbergMarquardtParams | None = None):
    """``posegraph.optimize``-compatible entry point for ``--backend batch``.

    ``progress`` receives a :class:`lie_factors.results.IterationInfo` after
    each iteration; returns a :class:`lie_factors.results.OptimizeResult`.
    ``max_iterations=0`` runs none.
    """

    if params is None:
        params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    t_start = time.perf_counter()
    history: list = []
    last = [t_start]

    def hook(it, err, lam):
        now = time.perf_counter()
        info = IterationInfo(int(it), float(err), float(lam), now - last[0])
        last[0] = now
        history.append(info)
        if progress is not None:
            progress(info)

    try:
        opt = BatchLevenbergMarquardt(graph, initial, params)
        last[0] = time.perf_counter()
        res = opt.optimize(hook)
    except BatchError as exc:
        raise PoseGraphError(f"batch backend: {exc}") from None
    except RuntimeError as exc:
        raise PoseGraphError(f"optimization failed: {_first_line(exc)}") from None
    return OptimizeResult(res.values, res.iterations, res.initial_error, res.final_error,
                          time.perf_counter() - t_start, res.converged, history)
