"""Factor kinds (:mod:`lie_factors.expressions`) in the batch solver: every factor of a kind as
arrays, evaluated and linearized by one call of the kind's kernel.

A kind's variables live where their type does: group elements of a registered group in the
:class:`~lie_factors.batch.groups.VarBlock` that Between/Prior factors of the group use, and
every other type (Rot2, points, vectors, calibrations, cameras) in a :class:`ValueBlock` of its
own (values (N, …) and each variable's offset in δ; retract X·Exp(δ) for Rot2, p + δ for the
rest, a camera's pose P·Exp(δ[:6]) and calibration K + δ[6:]: GTSAM's).  A :class:`KindGroup`
holds the kind's factors: per variable slot the index of each factor's variable in its block,
the constants stacked (F, …), the whitening matrices (one per distinct noise model) and the
outputs of the last linearization.
"""

from __future__ import annotations

import gtsam
import numpy as np

from .. import factors as _factors
from ..errors import InputError
from ..expressions.kind import check_statuses
from ..expressions.types import CALIBRATIONS, CAMERAS, accessor, as_array
from ..util.arrays import sorted_unique
from .loops import GroupLoops


class ValueBlock:
    """The variables of one non-matrix-group type ``t`` (Rot2, Point2/3, VectorN, the
    calibrations, the cameras): ``keys`` (sorted), ``X`` (N, …) their values, ``offsets`` (N,)
    in δ."""

    def __init__(self, t):
        self.t = t
        self.keys: list[int] = []
        self.index: dict = {}
        self.X: np.ndarray | None = None
        self.X0: np.ndarray | None = None
        self.offsets: np.ndarray | None = None
        self.var: np.ndarray | None = None
        self._key_arrays: list = []

    def use_keys(self, keys: np.ndarray) -> None:
        self._key_arrays.append(np.asarray(keys, dtype=np.uint64))

    def number_keys(self) -> None:
        ks = sorted_unique(np.concatenate(self._key_arrays)) if self._key_arrays else np.zeros(0, np.uint64)
        self._sorted = ks
        self.keys = ks.tolist()
        self.index = dict(zip(self.keys, range(len(self.keys))))

    def local(self, keys: np.ndarray) -> np.ndarray:
        return np.searchsorted(self._sorted, np.asarray(keys, dtype=np.uint64)).astype(np.int64)

    def read(self, values: gtsam.Values) -> None:
        """The start: each key's value in ``values`` (InputError naming a missing or mistyped key)."""
        t = self.t
        get = getattr(values, accessor(t))
        X = np.empty((len(self.keys),) + t.shape)
        for i, k in enumerate(self.keys):
            if not values.exists(k):
                raise InputError(f"key {gtsam.DefaultKeyFormatter(k)} is used by a factor on a {t} "
                                 "but is missing from the initial Values")
            try:
                X[i] = as_array(t, get(k), f"key {gtsam.DefaultKeyFormatter(k)}")
            except RuntimeError:
                raise InputError(f"key {gtsam.DefaultKeyFormatter(k)} must hold a {t} "
                                 "(it is used by a factor on one)") from None
        self.X = X
        self.X0 = X

    def retract(self, X: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """X·Exp(δ) (Rot2) or X + δ on the first d entries (vectors; a Cal3Bundler's principal
        point stays), each variable's δ at its offset; a camera (P, K): (P·Exp(δ[:6]), K + δ[6:])
        (GTSAM's ``PinholeCamera::retract``)."""
        d = self.t.dim
        step = delta[self.offsets[:, None] + np.arange(d)] if len(self.offsets) else np.zeros((0, d))
        if self.t.kind == "camera":
            return self._retract_cameras(X, delta, step)
        if self.t.name != "Rot2":
            if X.shape[1] == d:
                return X + step
            out = X.copy()
            out[:, :d] += step
            return out
        c, s = np.cos(step[:, 0]), np.sin(step[:, 0])
        out = np.empty_like(X)
        out[:, 0, 0] = X[:, 0, 0] * c - X[:, 1, 0] * s
        out[:, 1, 0] = X[:, 1, 0] * c + X[:, 0, 0] * s
        out[:, 0, 1] = -out[:, 1, 0]
        out[:, 1, 1] = out[:, 0, 0]
        return out

    def _retract_cameras(self, X: np.ndarray, delta: np.ndarray, step: np.ndarray) -> np.ndarray:
        out = X.copy()
        poses = np.ascontiguousarray(X[:, :16]).reshape(-1, 4, 4)
        moved = np.empty_like(poses)
        GroupLoops(_factors.GROUPS["Pose3"]).retract(poses, delta, self.offsets, moved)
        out[:, :16] = moved.reshape(-1, 16)
        out[:, 16:16 + self.t.dim - 6] += step[:, 6:]  # a Cal3Bundler's principal point stays
        return out

    def gtsam_value(self, x: np.ndarray):
        """The GTSAM object (or array) a ``gtsam.Values`` holds for the value ``x``."""
        name = self.t.name
        if name in CAMERAS:
            calibration = CAMERAS[name]
            return getattr(gtsam, name)(gtsam.Pose3(x[:16].reshape(4, 4)),
                                        getattr(gtsam, calibration)(*(float(v) for v in x[16:])))
        if name == "Rot2":
            return gtsam.Rot2.atan2(x[1, 0], x[0, 0])
        if name in CALIBRATIONS:  # GTSAM's constructors take the stored entries in order
            return getattr(gtsam, name)(*(float(v) for v in x))
        return np.array(x)


class KindGroup:
    """The factors of one kind in a graph (module docstring).  Rows are read first
    (:meth:`add`), then :meth:`finalize` makes the arrays once the variables are numbered."""

    def __init__(self, kind):
        self.kind = kind
        self.rows: list = []  # (graph index, factor, R)
        self.E = 0

    def add(self, i: int, f, R: np.ndarray) -> None:
        self.rows.append((i, f, R))

    def blocks_of(self, problem) -> list:
        """The block holding each variable slot's values (a VarBlock or a ValueBlock)."""
        return [problem.block_of_type(t) for t in self.kind.variables]

    def close_rows(self, problem) -> None:
        """Hand each slot's keys to its block for numbering."""
        kind = self.kind
        F = len(self.rows)
        self.fidx = np.array([r[0] for r in self.rows], dtype=np.int64)
        self.factors = [r[1] for r in self.rows]
        self.keys = np.array([f._keys_ for f in self.factors], dtype=np.uint64).reshape(F, len(kind.variables))
        for j, block in enumerate(self.blocks_of(problem)):
            block.use_keys(self.keys[:, j])
        self.C = [np.ascontiguousarray(np.array([f._constants[c] for f in self.factors], dtype=np.float64)
                                       .reshape((F,) + t.shape)) for c, t in enumerate(kind.constants)]
        entry: dict = {}
        self.ridx = np.array([entry.setdefault(id(r[2]), len(entry)) for r in self.rows], dtype=np.int64)
        table = list({id(r[2]): r[2] for r in self.rows}.values())
        m = kind.dim
        self.R = np.ascontiguousarray(np.array(table, dtype=np.float64).reshape(-1, m, m))
        self.rows = None
        self.E = F

    def finalize(self, problem) -> None:
        """Each slot's local indices and variable numbers (after the blocks are numbered)."""
        self.blocks = self.blocks_of(problem)
        self.index = [b.local(self.keys[:, j]) for j, b in enumerate(self.blocks)]
        self.var = [b.var[i] for b, i in zip(self.blocks, self.index)]
        self.sq = np.zeros(self.E)
        self._sq = np.zeros(self.E)  # an evaluation's, apart from the last linearization's
        m = self.kind.dim
        self.e = np.zeros((self.E, m))
        self.A = np.zeros((self.E, m, self.kind.columns))
        self.b = np.zeros((self.E, m))
        self.status = np.zeros(self.E, dtype=np.int64)

    def pairs(self) -> np.ndarray:
        """(P, 2) the variable pairs the factors join (for the sparsity pattern)."""
        out = [np.stack([self.var[p], self.var[q]], axis=1) for p in range(len(self.var))
               for q in range(p + 1, len(self.var))]
        return np.concatenate(out) if out else np.zeros((0, 2), dtype=np.int64)

    def _arguments(self, Xs: dict, sq: np.ndarray, jacobians: bool) -> list:
        args = list(self.kind.tags)
        for block, i in zip(self.blocks, self.index):
            args += [Xs[block_name(block)], i]
        args += self.C
        args += [self.R, self.ridx, self.e, self.A, self.b, sq, self.status, 0, self.E, jacobians]
        return args

    def linearize(self, Xs: dict) -> None:
        """Every factor's residual, whitened Jacobians ``A`` (E, m, Σd), ``b`` and ``sq``; a
        factor undefined there raises its error (:meth:`KindFactor.evaluated`)."""
        if self.E:
            self.kind.evaluate(*self._arguments(Xs, self.sq, True))
            check_statuses(self.factors, self.status)

    def evaluate(self, Xs: dict, sq: np.ndarray) -> None:
        """Every factor's squared whitened residual norm into ``sq`` (E,)."""
        if self.E:
            self.kind.evaluate(*self._arguments(Xs, self._sq, False))
            check_statuses(self.factors, self.status)
            sq[:] = self._sq


def block_name(block) -> str:
    """The key of ``block`` in a problem's element dictionaries (its type's name)."""
    return block.spec.name if hasattr(block, "spec") else block.t.name
