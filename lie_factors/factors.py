"""GTSAM Between/Prior factors whose Jacobians come from the closed-form dlog.

Drop-in replacements for GTSAM's own factors, same names and arguments::

    from lie_factors.factors import BetweenFactorPose3, PriorFactorPose3
    graph.add(BetweenFactorPose3(1, 2, measured, noise))

Each constructor returns a :class:`gtsam.CustomFactor` subclass, so the factor
works wherever a native one does (NonlinearFactorGraph, LevenbergMarquardt,
GaussNewton, Dogleg, ISAM2, Marginals).

Errors are GTSAM's definitions: ``Log(measured⁻¹ · X1⁻¹ · X2)`` for Between and
``Log(prior⁻¹ · X)`` for Prior. Jacobians are with respect to GTSAM's right
retraction ``X · Exp(δ)``. With ``dlog(x) = D_exp(x)⁻¹`` the inverse *left*
Jacobian (seed 000, Eq. 40) and ``J_r(x) = D_exp(−x)``:

* ``X2 → X2·Exp(δ)``: ``E → E·Exp(δ)`` so ``e → e + J_r(e)⁻¹ δ``:
  ``H2 = dlog(−e)``.
* ``X1 → X1·Exp(δ)``: ``M⁻¹·Exp(−δ) = Exp(−Ad(M⁻¹) δ)·M⁻¹``, so
  ``E → Exp(−Ad(M⁻¹) δ)·E`` and ``e → e − J_l(e)⁻¹ Ad(M⁻¹) δ``:
  ``H1 = −dlog(e) · Ad(M⁻¹)``, where ``Ad(M⁻¹)`` is constant per factor and
  computed once at construction.
* Prior: ``H = dlog(−e)`` (the X2 case with ``M = prior``, ``X1 = I``).

The numerical work of one evaluation (inverse, compose, log, dlog and the
product with ``Ad(M⁻¹)``) is a single call of :func:`between` / :func:`prior`,
numba kernels over the group modules' cores (the same cores the public
broadcasting functions run); the batch solver loops over the same two kernels.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType

import gtsam
import numpy as np

from . import _dispatch
from ._validate import ORTHONORMAL_TOL
from ._jit import kernel

__all__ = [
    "BetweenFactorRot3",
    "BetweenFactorPose3",
    "BetweenFactorPose2",
    "BetweenFactorSimilarity2",
    "BetweenFactorSimilarity3",
    "PriorFactorRot3",
    "PriorFactorPose3",
    "PriorFactorPose2",
    "PriorFactorSimilarity2",
    "PriorFactorSimilarity3",
    "GROUPS",
    "warm_up",
]


@kernel
def between_error(g, Minv, X1, X2, e):
    """e = Log(M⁻¹·X1⁻¹·X2) on group ``g`` (a :mod:`lie_factors._dispatch` tag)."""
    m = X1.shape[0]
    X1inv = np.empty((m, m))
    rel = np.empty((m, m))
    E = np.empty((m, m))
    _dispatch.inverse(g, X1, X1inv)
    _dispatch.compose(g, X1inv, X2, rel)
    _dispatch.compose(g, Minv, rel, E)
    _dispatch.log(g, E, e)


@kernel
def between(g, Minv, AdMinv, X1, X2, e, H1, H2):
    """Error and Jacobians of a Between factor: H1 = −dlog(e)·Ad(M⁻¹), H2 = dlog(−e)."""
    between_error(g, Minv, X1, X2, e)
    n = e.shape[0]
    D = np.empty((n, n))
    _dispatch.dlog(g, e, D)
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += D[i, k] * AdMinv[k, j]
            H1[i, j] = -acc
    neg = np.empty(n)
    for i in range(n):
        neg[i] = -e[i]
    _dispatch.dlog(g, neg, H2)


@kernel
def prior_error(g, Pinv, X, e):
    """e = Log(P⁻¹·X) on group ``g``."""
    m = X.shape[0]
    E = np.empty((m, m))
    _dispatch.compose(g, Pinv, X, E)
    _dispatch.log(g, E, e)


@kernel
def prior(g, Pinv, X, e, H):
    """Error and Jacobian of a Prior factor: H = dlog(−e)."""
    prior_error(g, Pinv, X, e)
    n = e.shape[0]
    neg = np.empty(n)
    for i in range(n):
        neg[i] = -e[i]
    _dispatch.dlog(g, neg, H)


# Codes of check_element; _ELEMENT_ERRORS turns them into messages.
OK, NOT_FINITE, NOT_ORTHONORMAL, REFLECTION, BAD_LAST_ROW, BAD_SCALE = range(6)


@kernel
def check_element(g, X):
    """Validate one (m, m) element of group ``g``; returns OK or the first failure's code.

    Finite entries; rotation block R (d×d) with max|RᵀR − I| ≤ ORTHONORMAL_TOL
    and det R > 0; then the last row [0 … 0 1] (or [0 … 0 s], s > 0, for
    similarity groups). The same tests as :mod:`lie_factors._validate` runs
    on batches, done on the raw matrix in one call.
    """
    m = X.shape[0]
    for i in range(m):
        for j in range(m):
            if not np.isfinite(X[i, j]):
                return NOT_FINITE
    d = _dispatch.rot_dim(g)
    for i in range(d):
        for j in range(d):
            acc = 0.0
            for k in range(d):
                acc += X[k, i] * X[k, j]
            if i == j:
                acc -= 1.0
            if abs(acc) > ORTHONORMAL_TOL:
                return NOT_ORTHONORMAL
    if d == 2:
        det = X[0, 0] * X[1, 1] - X[0, 1] * X[1, 0]
    else:
        det = (X[0, 0] * (X[1, 1] * X[2, 2] - X[1, 2] * X[2, 1])
               - X[0, 1] * (X[1, 0] * X[2, 2] - X[1, 2] * X[2, 0])
               + X[0, 2] * (X[1, 0] * X[2, 1] - X[1, 1] * X[2, 0]))
    if det < 0.0:
        return REFLECTION
    corner = _dispatch.corner(g)
    if corner == _dispatch.NO_CORNER:
        return OK
    for j in range(m - 1):
        if X[m - 1, j] != 0.0:
            return BAD_LAST_ROW
    if corner == _dispatch.ONE:
        if X[m - 1, m - 1] != 1.0:
            return BAD_LAST_ROW
    elif not X[m - 1, m - 1] > 0.0:
        return BAD_SCALE
    return OK


@kernel
def between_setup(g, M, Minv, AdMinv):
    """Construction of a Between factor: check M, then Minv = M⁻¹, AdMinv = Ad(M⁻¹)."""
    code = check_element(g, M)
    if code == OK:
        _dispatch.inverse(g, M, Minv)
        _dispatch.Ad(g, Minv, AdMinv)
    return code


@kernel
def prior_setup(g, P, Pinv):
    """Construction of a Prior factor: check P, then Pinv = P⁻¹."""
    code = check_element(g, P)
    if code == OK:
        _dispatch.inverse(g, P, Pinv)
    return code


def warm_up(group) -> None:
    """Compile (or load from the on-disk cache) what a factor of ``group`` runs.

    Called before the optimization clock starts, so that reported seconds never
    include compilation. The layouts are those the factors pass: GTSAM hands
    out Fortran-ordered matrices, our own buffers are C-ordered.
    """
    n, m = group.dim, group.mat
    M = np.asfortranarray(np.eye(m))
    Minv, Ad = np.empty((m, m)), np.empty((n, n))
    between_setup(group, M, Minv, Ad)
    prior_setup(group, M, Minv)
    e, H1, H2 = np.empty(n), np.empty((n, n)), np.empty((n, n))
    between(group, Minv, Ad, M, M, e, H1, H2)
    prior(group, Minv, M, e, H1)


@dataclass(frozen=True)
class GroupSpec:
    """How one GTSAM type maps onto a kernel module."""

    name: str  # GTSAM class name, e.g. "Pose3"
    cls: type  # gtsam.Pose3
    group: _dispatch.Group  # the kernels' group tag, e.g. _dispatch.SE3
    at: str  # Values accessor, e.g. "atPose3"

    @property
    def kernels(self) -> ModuleType:
        return self.group.module

    @property
    def dim(self) -> int:
        return self.group.dim

    @property
    def rot_dim(self) -> int:
        return self.group.rot_dim

    def matrix(self, value) -> np.ndarray:
        return np.asarray(value.matrix(), dtype=np.float64)


GROUPS = {
    "Rot3": GroupSpec("Rot3", gtsam.Rot3, _dispatch.SO3, "atRot3"),
    "Pose3": GroupSpec("Pose3", gtsam.Pose3, _dispatch.SE3, "atPose3"),
    "Pose2": GroupSpec("Pose2", gtsam.Pose2, _dispatch.SE2, "atPose2"),
    "Similarity2": GroupSpec("Similarity2", gtsam.Similarity2, _dispatch.SIM2, "atSimilarity2"),
    "Similarity3": GroupSpec("Similarity3", gtsam.Similarity3, _dispatch.SIM3, "atSimilarity3"),
}


def _element_error(spec: GroupSpec, X: np.ndarray, code: int, what: str, factor: str) -> ValueError:
    where = f"{factor}: {what}"
    if code == NOT_FINITE:
        return ValueError(f"{where}: contains NaN or inf")
    if code == NOT_ORTHONORMAL:
        d = spec.rot_dim
        B = X[:d, :d]
        dev = float(np.max(np.abs(B.T @ B - np.eye(d))))
        return ValueError(f"{where}: rotation block is not orthonormal (max|RᵀR - I| = {dev:.3g})")
    if code == REFLECTION:
        return ValueError(f"{where}: rotation block has determinant -1 (a reflection)")
    if code == BAD_SCALE:
        return ValueError(f"{where} has non-positive scale")
    return ValueError(f"{where}: expected last row [0 ... 0 1]")


def _check_type(spec: GroupSpec, value, what: str, factor: str) -> None:
    if not isinstance(value, spec.cls):
        raise TypeError(f"{factor}: {what} must be a gtsam.{spec.name}, got {type(value).__name__}")


def _checked_noise(spec: GroupSpec, noise_model, factor: str):
    if not isinstance(noise_model, gtsam.noiseModel.Base):
        raise TypeError(f"{factor}: noise_model must be a gtsam.noiseModel, got {type(noise_model).__name__}")
    if noise_model.dim() != spec.dim:
        raise ValueError(
            f"{factor}: noise model has dimension {noise_model.dim()}, "
            f"but {spec.name} has dimension {spec.dim}"
        )
    return noise_model


def _checked_key(key, factor: str) -> int:
    if type(key) is int and key >= 0:  # the common case, without the tuple isinstance checks
        return key
    if isinstance(key, (bool, np.bool_)) or not isinstance(key, (int, np.integer)) or key < 0:
        raise TypeError(f"{factor}: keys must be non-negative integers, got {key!r}")
    return int(key)


def _fetch(values, key: int, spec: GroupSpec, factor: str) -> np.ndarray:
    try:
        value = getattr(values, spec.at)(key)
    except RuntimeError as exc:
        raise TypeError(
            f"{factor}: key {gtsam.DefaultKeyFormatter(key)} must hold a gtsam.{spec.name}: {exc}"
        ) from None
    return spec.matrix(value)


class BetweenFactor(gtsam.CustomFactor):
    """Between factor on ``spec``: error Log(measured⁻¹·X1⁻¹·X2), analytic Jacobians.

    Use the named constructors (``BetweenFactorPose3`` ...). Jacobians: see the
    module docstring (H1 = −dlog(e)·Ad(measured⁻¹), H2 = dlog(−e)).
    """

    spec: GroupSpec

    def __init__(self, key1, key2, measured, noise_model):
        name = type(self).__name__
        spec = self.spec
        k1, k2 = _checked_key(key1, name), _checked_key(key2, name)
        _check_type(spec, measured, "measured", name)
        _checked_noise(spec, noise_model, name)
        group = spec.group
        M = measured.matrix()
        Minv = np.empty((group.mat, group.mat))
        AdMinv = np.empty((group.dim, group.dim))
        code = between_setup(group, M, Minv, AdMinv)
        if code != OK:
            raise _element_error(spec, M, code, "measured", name)
        super().__init__(noise_model, [k1, k2], self._evaluate)
        self._measured = measured
        self._key1, self._key2 = k1, k2
        self._Minv = Minv
        self._AdMinv = AdMinv
        self._group = group
        self._name = name

    def measured(self):
        """The measured relative transform, as the GTSAM object given."""
        return self._measured

    def _evaluate(self, this, values, H):
        spec = self.spec
        X1 = _fetch(values, self._key1, spec, self._name)
        X2 = _fetch(values, self._key2, spec, self._name)
        n = spec.group.dim
        e = np.empty(n)
        H1 = np.empty((n, n))
        H2 = np.empty((n, n))
        between(self._group, self._Minv, self._AdMinv, X1, X2, e, H1, H2)
        if H is not None:
            H[0] = H1
            H[1] = H2
        return e


class PriorFactor(gtsam.CustomFactor):
    """Prior factor on ``spec``: error Log(prior⁻¹·X), Jacobian dlog(−e)."""

    spec: GroupSpec

    def __init__(self, key, prior, noise_model):
        name = type(self).__name__
        spec = self.spec
        k = _checked_key(key, name)
        _check_type(spec, prior, "prior", name)
        _checked_noise(spec, noise_model, name)
        group = spec.group
        P = prior.matrix()
        Pinv = np.empty((group.mat, group.mat))
        code = prior_setup(group, P, Pinv)
        if code != OK:
            raise _element_error(spec, P, code, "prior", name)
        super().__init__(noise_model, [k], self._evaluate)
        self._prior = prior
        self._key = k
        self._Pinv = Pinv
        self._group = group
        self._name = name

    def prior(self):
        """The prior value, as the GTSAM object given."""
        return self._prior

    def _evaluate(self, this, values, H):
        spec = self.spec
        X = _fetch(values, self._key, spec, self._name)
        n = spec.group.dim
        e = np.empty(n)
        J = np.empty((n, n))
        prior(self._group, self._Pinv, X, e, J)
        if H is not None:
            H[0] = J
        return e


class BetweenFactorRot3(BetweenFactor):
    """``BetweenFactorRot3(key1, key2, measured: gtsam.Rot3, noise_model)`` (3-dim)."""

    spec = GROUPS["Rot3"]


class BetweenFactorPose3(BetweenFactor):
    """``BetweenFactorPose3(key1, key2, measured: gtsam.Pose3, noise_model)`` (6-dim, [ω, v])."""

    spec = GROUPS["Pose3"]


class BetweenFactorPose2(BetweenFactor):
    """``BetweenFactorPose2(key1, key2, measured: gtsam.Pose2, noise_model)`` (3-dim, [x, y, θ])."""

    spec = GROUPS["Pose2"]


class BetweenFactorSimilarity2(BetweenFactor):
    """``BetweenFactorSimilarity2(key1, key2, measured: gtsam.Similarity2, noise_model)`` (4-dim)."""

    spec = GROUPS["Similarity2"]


class BetweenFactorSimilarity3(BetweenFactor):
    """``BetweenFactorSimilarity3(key1, key2, measured: gtsam.Similarity3, noise_model)``
    (7-dim, [ω, u, λ]).  GTSAM's own has H1 = −Ad((X1⁻¹X2)⁻¹), H2 = I (no Logmap
    derivative); these are exact."""

    spec = GROUPS["Similarity3"]


class PriorFactorRot3(PriorFactor):
    """``PriorFactorRot3(key, prior: gtsam.Rot3, noise_model)``."""

    spec = GROUPS["Rot3"]


class PriorFactorPose3(PriorFactor):
    """``PriorFactorPose3(key, prior: gtsam.Pose3, noise_model)``."""

    spec = GROUPS["Pose3"]


class PriorFactorPose2(PriorFactor):
    """``PriorFactorPose2(key, prior: gtsam.Pose2, noise_model)``."""

    spec = GROUPS["Pose2"]


class PriorFactorSimilarity2(PriorFactor):
    """``PriorFactorSimilarity2(key, prior: gtsam.Similarity2, noise_model)``."""

    spec = GROUPS["Similarity2"]


class PriorFactorSimilarity3(PriorFactor):
    """``PriorFactorSimilarity3(key, prior: gtsam.Similarity3, noise_model)``."""

    spec = GROUPS["Similarity3"]
