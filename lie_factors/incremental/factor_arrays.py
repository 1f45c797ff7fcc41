"""The smoother's variables and factors as arrays: a group's elements, a kind's factors, an update's.

:class:`Elements` holds the variables of one group (their elements θ), and
:class:`FactorKind` the factors of one (kind, group) — their variables,
constants (M⁻¹, the whitening R) and block-factor ids — linearized by one
compiled call of :mod:`lie_factors.batch.loops` per kind.
:class:`FactorArrays` is a replay's factors checked and set up once;
:class:`NewFactors` is one update, read from arrays or from GTSAM's objects
(:mod:`lie_factors.incremental.gtsam_objects`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import factors as _factors
from ..batch.loops import NOT_DEFINITE, NOT_ELEMENT, NOT_FINITE, SELF_LOOP, GroupLoops
from ..errors import InputError
from .structures import grow


class Elements:
    """The variables of one group: their elements θ (N, m, m) and variable indices."""

    def __init__(self, spec):
        self.spec = spec
        self.loops = GroupLoops(spec, serial=True)
        self.X = np.zeros((0, spec.mat, spec.mat))
        self.var = np.zeros(0, dtype=np.int64)
        self.n = 0

    def append(self, X: np.ndarray, var: np.ndarray) -> np.ndarray:
        n0, k = self.n, len(X)
        if n0 + k > self.X.shape[0]:
            self.X = grow(self.X, n0 + k)
            self.var = grow(self.var, n0 + k)
        self.X[n0:n0 + k] = X
        self.var[n0:n0 + k] = var
        self.n = n0 + k
        return np.arange(n0, n0 + k)


class FactorKind:
    """The array factors of one (kind, group): variables, element indices, constants, block-factor ids."""

    def __init__(self, kind: str, spec, elements: Elements):
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
        n0, k = self.n, len(v)
        if n0 + k > self.v.shape[0]:  # the five arrays grow together
            for name in ("v", "e", "C", "R", "fid"):
                setattr(self, name, grow(getattr(self, name), n0 + k))
        self.v[n0:n0 + k], self.e[n0:n0 + k], self.C[n0:n0 + k], self.R[n0:n0 + k] = v, e, C, R
        self.source.extend(sources)
        self.n = n0 + k
        return np.arange(n0, n0 + k)

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
    :class:`~lie_factors.errors.InputError` for wrong shapes, non-finite numbers, a self-loop, an element that
    is not in the group, an information matrix that is not positive definite.
    """

    def __init__(self, group: str, edge_keys=None, measured=None, information=None, prior_keys=None,
                 prior_measured=None, prior_information=None):
        spec = _factors.GROUPS.get(group)
        if spec is None:
            raise InputError(f"unknown group {group!r} (choose from {', '.join(_factors.GROUPS)})")
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
                raise InputError(f"{kind} factors: expected measurements ({F}, {m}, {m}) and information "
                                    f"({F}, {n}, {n}), got {M.shape} and {info.shape}")
            if F == 0:  # (an update often has no prior: no compiled call for nothing)
                parts[kind] = (k, np.zeros((0, m, m)), np.zeros((0, n, n)))
                continue
            # every check and the constants in one compiled call (a smoother update makes one of these)
            status, q, Minv, R, codes = loops.prepare(np.ascontiguousarray(k), np.ascontiguousarray(M),
                                                      np.ascontiguousarray(info))
            if status == NOT_FINITE:
                raise InputError(f"{kind} factors: a measurement or information matrix is not finite")
            if status == SELF_LOOP:
                raise InputError("between factors: a factor connects a key to itself")
            if status == NOT_ELEMENT:
                raise InputError(str(_factors.element_error(spec, M[q], int(codes[q]), f"{kind} {q}",
                                                                "update")))
            if status == NOT_DEFINITE:
                raise InputError(f"{kind} factors: an information matrix is not positive definite")
            parts[kind] = (k, Minv, R)
        self.edge_keys, self.Minv, self.R = parts["between"]
        pk, self.Pinv, self.prior_R = parts["prior"]
        self.prior_keys = pk.reshape(-1)
        self.E, self.Q = len(self.edge_keys), len(self.prior_keys)

    @classmethod
    def of_constants(cls, group: str, edge_keys, Minv, R, prior_keys, Pinv, prior_R) -> "FactorArrays":
        """Factors already checked and set up (M⁻¹ and R given, as an update read from GTSAM's
        factor objects has them): ``edge_keys`` (E, 2), ``Minv`` (E, m, m), ``R`` (E, n, n);
        ``prior_keys`` (Q,), ``Pinv``, ``prior_R``; None for none of a kind."""
        self = cls.__new__(cls)
        self.group = group
        self.spec = spec = _factors.GROUPS[group]
        m, n = spec.mat, spec.dim
        self.edge_keys = np.zeros((0, 2), dtype=np.int64) if edge_keys is None else edge_keys.reshape(-1, 2)
        self.Minv = np.zeros((0, m, m)) if Minv is None else Minv
        self.R = np.zeros((0, n, n)) if R is None else R
        self.prior_keys = np.zeros(0, dtype=np.int64) if prior_keys is None else prior_keys.reshape(-1)
        self.Pinv = np.zeros((0, m, m)) if Pinv is None else Pinv
        self.prior_R = np.zeros((0, n, n)) if prior_R is None else prior_R
        self.E, self.Q = len(self.edge_keys), len(self.prior_keys)
        return self

    def new_factors(self, keys, values, edges, priors) -> "NewFactors":
        """One update of the general path: new variables ``keys`` (P,) at ``values`` (P, m, m)
        and the factors ``edges``/``priors`` (indices), numbered in that order."""
        m, n = self.spec.mat, self.spec.dim
        keys = np.asarray(keys, dtype=np.int64).reshape(-1)
        P = len(keys)
        X = np.zeros((0, m, m)) if P == 0 and values is None else np.asarray(values, dtype=np.float64)
        if X.shape != (P, m, m):
            raise InputError(f"values: expected shape ({P}, {m}, {m}), got {X.shape}")
        if not np.all(np.isfinite(X)):
            raise InputError("values: not finite")
        arrays = {}
        edges = np.asarray(edges, dtype=np.int64).reshape(-1)
        priors = np.asarray(priors, dtype=np.int64).reshape(-1)
        if len(edges):
            arrays[("between", self.group)] = dict(keys=self.edge_keys[edges], C=self.Minv[edges], R=self.R[edges],
                                                   src=[None] * len(edges), pos=np.arange(len(edges)))
        if len(priors):
            arrays[("prior", self.group)] = dict(keys=self.prior_keys[priors, None], C=self.Pinv[priors],
                                                 R=self.prior_R[priors], src=[None] * len(priors),
                                                 pos=len(edges) + np.arange(len(priors)))
        return NewFactors(keys.tolist(), [self.group] * P, list(X), [n] * P, arrays, [])


@dataclass
class NewFactors:
    """An update read: new variables (key, group name or None, value) and factors by kind."""

    keys: list
    kinds: list  # group name (array variable) or None (GTSAM's values)
    values: list  # element matrix (m, m) or the gtsam value
    dims: list
    arrays: dict  # (kind, group) -> dict(keys, C, R, src, pos)
    native: list  # (factor, keys)
    theta: object = None  # the gtsam.Values the variables GTSAM holds come from
    types: dict = field(default_factory=dict)  # their keys -> type names (``Values.at<Type>``)
    native_pos: list = field(default_factory=list)  # each native factor's place in the update
    nulls: list = field(default_factory=list)  # the places of the update's empty slots
    count: int = 0  # the update's factors, empty slots included: its factor indices

    def __post_init__(self):
        if not self.count:
            self.count = sum(len(e["keys"]) for e in self.arrays.values()) + len(self.native) + len(self.nulls)
