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

from . import _dispatch, _validate, se2, se3, sim2, sim3, so3
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
]


@kernel
def between_error(g, Minv, X1, X2, e):
    """e = Log(M⁻¹·X1⁻¹·X2) on group ``g`` (ids of :mod:`lie_factors._dispatch`)."""
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


@dataclass(frozen=True)
class GroupSpec:
    """How one GTSAM type maps onto a kernel module."""

    name: str  # GTSAM class name, e.g. "Pose3"
    cls: type  # gtsam.Pose3
    kernels: ModuleType  # lie_factors.se3
    at: str  # Values accessor, e.g. "atPose3"
    rot_dim: int  # size of the rotation block of the matrix

    @property
    def gid(self) -> int:
        return self.kernels.GID

    @property
    def dim(self) -> int:
        return self.kernels.DIM

    def matrix(self, value) -> np.ndarray:
        return np.asarray(value.matrix(), dtype=np.float64)


GROUPS = {
    "Rot3": GroupSpec("Rot3", gtsam.Rot3, so3, "atRot3", 3),
    "Pose3": GroupSpec("Pose3", gtsam.Pose3, se3, "atPose3", 3),
    "Pose2": GroupSpec("Pose2", gtsam.Pose2, se2, "atPose2", 2),
    "Similarity2": GroupSpec("Similarity2", gtsam.Similarity2, sim2, "atSimilarity2", 2),
    "Similarity3": GroupSpec("Similarity3", gtsam.Similarity3, sim3, "atSimilarity3", 3),
}


def _checked_element(spec: GroupSpec, value, what: str, factor: str) -> np.ndarray:
    """The matrix of a measurement/prior, rejecting wrong types, NaN and non-rotations."""
    if not isinstance(value, spec.cls):
        raise TypeError(f"{factor}: {what} must be a gtsam.{spec.name}, got {type(value).__name__}")
    X = spec.matrix(value)
    m = spec.kernels.MAT
    _validate.square(X, m, f"{factor}: {what}")
    _validate.rotation_block(X, f"{factor}: {what}", spec.rot_dim)
    if spec.name.startswith("Similarity") and not X[m - 1, m - 1] > 0:
        raise ValueError(f"{factor}: {what} has non-positive scale")
    return X


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
        M = _checked_element(spec, measured, "measured", name)
        _checked_noise(spec, noise_model, name)
        super().__init__(noise_model, [k1, k2], self._evaluate)
        self._measured = measured
        self._key1, self._key2 = k1, k2
        G = spec.kernels
        self._Minv = G.inverse(M)
        self._AdMinv = np.ascontiguousarray(G.Ad(self._Minv))
        self._gid = spec.gid
        self._name = name

    def measured(self):
        """The measured relative transform, as the GTSAM object given."""
        return self._measured

    def _evaluate(self, this, values, H):
        spec = self.spec
        X1 = _fetch(values, self._key1, spec, self._name)
        X2 = _fetch(values, self._key2, spec, self._name)
        n = spec.kernels.DIM
        e = np.empty(n)
        H1 = np.empty((n, n))
        H2 = np.empty((n, n))
        between(self._gid, self._Minv, self._AdMinv, X1, X2, e, H1, H2)
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
        P = _checked_element(spec, prior, "prior", name)
        _checked_noise(spec, noise_model, name)
        super().__init__(noise_model, [k], self._evaluate)
        self._prior = prior
        self._key = k
        self._Pinv = spec.kernels.inverse(P)
        self._gid = spec.gid
        self._name = name

    def prior(self):
        """The prior value, as the GTSAM object given."""
        return self._prior

    def _evaluate(self, this, values, H):
        spec = self.spec
        X = _fetch(values, self._key, spec, self._name)
        n = spec.kernels.DIM
        e = np.empty(n)
        J = np.empty((n, n))
        prior(self._gid, self._Pinv, X, e, J)
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
