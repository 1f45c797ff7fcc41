"""Robust losses with GTSAM's ``noiseModel.mEstimator`` semantics, as numba kernels over factors.

GTSAM's ``noiseModel.Robust(mEstimator, Gaussian)`` works on the *whitened*
residual of a factor, ``u = R·e`` (``R`` the Gaussian's square-root
information, ``e`` the unwhitened error), through its distance ``d = ‖u‖``:

* error: ``NoiseModelFactor::error = Robust::loss(‖u‖²) = ρ(d)`` (not ½‖u‖²);
* linearization (``Robust::WhitenSystem`` with the default ``Block`` reweight
  scheme): the Gaussian whitens ``A`` and ``b = −e`` first, then
  ``mEstimator::reweight`` multiplies every Jacobian block and ``b`` by
  ``√w(d)``, ``w`` the estimator's ``weight``.

So a robust factor is an ordinary whitened factor whose rows are scaled by
``√w(d)`` at each linearization, and whose error is ``ρ(d)``.  The per-factor
kernels :func:`weight` / :func:`loss` take a loss id (``kinds``) and the
estimator's parameter; :func:`weights_and_losses` runs them over every factor
of a graph at once.  Loss id ``GAUSSIAN`` (0) is the plain quadratic
(``w = 1``, ``ρ = ½d²``), so a mixed graph is one array of ids.

The formulas are GTSAM 4.3's ``LossFunctions.cpp``, written in the same
operation order (tests compare against ``gtsam.noiseModel.mEstimator`` at
distances straddling every threshold):

=============  =====================================  ============================================
name           weight w(d)                            loss ρ(d)
=============  =====================================  ============================================
huber (k)      1 if d ≤ k else k/d                    d²/2 if d ≤ k else k(d − k/2)
cauchy (k)     k²/(k² + d²)                           ½k²·log1p(d²/k²)
tukey (c)      (1 − d²/c²)² if d ≤ c else 0           c²(1 − (1 − d²/c²)³)/6 if d ≤ c else c²/6
gm (c)         c⁴/(c² + d²)²                          ½c²d²/(c² + d²)
dcs (c)        1 if d² ≤ c else (2c/(c + d²))²        d²/2 if d² ≤ c else c(3/2 − 2/(1 + d²/c))
welsch (c)     exp(−d²/c²)                            −½c²·expm1(−d²/c²)
fair (c)       1/(1 + |d|/c)                          c²(|d|/c − log1p(|d|/c))
=============  =====================================  ============================================

(``gm`` is Geman–McClure; DCS's ``c`` is in squared-distance units, as in GTSAM.)
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from ..kernels.jit import kernel

__all__ = [
    "Loss", "GAUSSIAN", "HUBER", "CAUCHY", "TUKEY", "GEMAN_MCCLURE", "DCS", "WELSCH", "FAIR",
    "LOSSES", "RobustLoss", "parse_loss", "from_gtsam", "weight", "loss",
    "weights_and_losses",
]

class Loss(IntEnum):
    """The losses (names are strings at the API: ``huber``, ``cauchy``, …)."""

    GAUSSIAN = 0
    HUBER = 1
    CAUCHY = 2
    TUKEY = 3
    GEMAN_MCCLURE = 4
    DCS = 5
    WELSCH = 6
    FAIR = 7


# The kernels compare plain integers (numba freezes them as constants).
GAUSSIAN, HUBER, CAUCHY, TUKEY, GEMAN_MCCLURE, DCS, WELSCH, FAIR = (int(m) for m in Loss)

#: name → (id, gtsam mEstimator class name, default parameter).  Defaults: the
#: 95 %-efficiency tuning constants for unit-variance residuals (Huber 1.345,
#: Cauchy 2.3849, Tukey 4.6851, Welsch 2.9846, Fair 1.3998); Geman–McClure c = 1
#: and DCS Φ = 1 (Agarwal et al. 2013).  The CLI accepts ``name:k`` to override.
LOSSES: dict[str, tuple[int, str, float]] = {
    "huber": (HUBER, "Huber", 1.345),
    "cauchy": (CAUCHY, "Cauchy", 2.3849),
    "tukey": (TUKEY, "Tukey", 4.6851),
    "gm": (GEMAN_MCCLURE, "GemanMcClure", 1.0),
    "dcs": (DCS, "DCS", 1.0),
    "welsch": (WELSCH, "Welsch", 2.9846),
    "fair": (FAIR, "Fair", 1.3998),
}
_BY_CLASS = {cls: (name, lid) for name, (lid, cls, _) in LOSSES.items()}


# --------------------------------------------------------------------------- #
# Kernels (GTSAM LossFunctions.cpp, same operation order)
# --------------------------------------------------------------------------- #

@kernel
def weight(kind, k, d):
    """w(d) of loss ``kind`` with parameter ``k`` at distance ``d = ‖R e‖ ≥ 0``."""
    if kind == HUBER:
        a = abs(d)
        return 1.0 if a <= k else k / a
    if kind == CAUCHY:
        k2 = k * k
        return k2 / (k2 + d * d)
    if kind == TUKEY:
        if abs(d) <= k:
            t = 1.0 - d * d / (k * k)
            return t * t
        return 0.0
    if kind == GEMAN_MCCLURE:
        c2 = k * k
        c4 = c2 * c2
        s = c2 + d * d
        return c4 / (s * s)
    if kind == DCS:
        e2 = d * d
        if e2 > k:
            w = 2.0 * k / (k + e2)
            return w * w
        return 1.0
    if kind == WELSCH:
        return math.exp(-(d * d) / (k * k))
    if kind == FAIR:
        return 1.0 / (1.0 + abs(d) / k)
    return 1.0


@kernel
def loss(kind, k, d):
    """ρ(d) of loss ``kind`` with parameter ``k`` (``GAUSSIAN``: ½d²)."""
    if kind == HUBER:
        a = abs(d)
        if a <= k:
            return d * d / 2
        return k * (a - (k / 2))
    if kind == CAUCHY:
        k2 = k * k
        return k2 * math.log1p(d * d / k2) * 0.5
    if kind == TUKEY:
        c2 = k * k
        if abs(d) <= k:
            t = 1.0 - d * d / c2
            return c2 * (1 - t * t * t) / 6.0
        return c2 / 6.0
    if kind == GEMAN_MCCLURE:
        c2 = k * k
        e2 = d * d
        return 0.5 * (c2 * e2) / (c2 + e2)
    if kind == DCS:
        # GTSAM 4.3: the integral of w(d)·d (older GTSAMs had Agarwal's Eq. 9,
        # which is not), so ρ is continuous with ρ' = w·d.
        e2 = d * d
        if e2 <= k:
            return e2 / 2
        return k * (1.5 - 2.0 / (1.0 + e2 / k))
    if kind == WELSCH:
        c2 = k * k
        return c2 * 0.5 * -math.expm1(-(d * d) / c2)
    if kind == FAIR:
        u = abs(d) / k
        return k * k * (u - math.log1p(u))
    return 0.5 * d * d


@kernel
def weights_and_losses(kinds, ks, sqnorms, w_out, loss_out):
    """Per factor f: ``w_out[f] = w(√sqnorms[f])``, ``loss_out[f] = ρ(√sqnorms[f])``; returns Σ ρ.

    ``sqnorms`` (F,) are the squared whitened residual norms ‖R e‖²; ``kinds``
    (F,) int64 loss ids, ``ks`` (F,) their parameters.
    """
    total = 0.0
    for f in range(sqnorms.shape[0]):
        d = math.sqrt(sqnorms[f])
        w_out[f] = weight(kinds[f], ks[f], d)
        r = loss(kinds[f], ks[f], d)
        loss_out[f] = r
        total += r
    return total


@kernel
def _eval_many(kind, k, d, w_out, loss_out):
    for i in range(d.shape[0]):
        w_out[i] = weight(kind, k, d[i])
        loss_out[i] = loss(kind, k, d[i])


# --------------------------------------------------------------------------- #
# Python-side description of one loss
# --------------------------------------------------------------------------- #

@dataclass(frozen=True)
class RobustLoss:
    """One GTSAM mEstimator: ``name`` (a key of :data:`LOSSES`) and its parameter ``k``."""

    name: str
    k: float

    def __post_init__(self):
        if self.name not in LOSSES:
            raise ValueError(f"unknown robust loss {self.name!r} (choose from {', '.join(LOSSES)})")
        if not (math.isfinite(self.k) and self.k > 0):
            raise ValueError(f"robust loss {self.name}: parameter must be a positive number, got {self.k!r}")

    @property
    def kind(self) -> Loss:
        return Loss(LOSSES[self.name][0])

    def weight(self, d) -> np.ndarray:
        """w(d) for an array of distances (shape preserved)."""
        return self.evaluate(d)[0]

    def loss(self, d) -> np.ndarray:
        """ρ(d) for an array of distances (shape preserved)."""
        return self.evaluate(d)[1]

    def evaluate(self, d) -> tuple[np.ndarray, np.ndarray]:
        d = np.asarray(d, dtype=np.float64)
        flat = np.ascontiguousarray(d.reshape(-1))
        w = np.empty_like(flat)
        r = np.empty_like(flat)
        _eval_many(int(self.kind), float(self.k), flat, w, r)
        return w.reshape(d.shape), r.reshape(d.shape)

    def to_gtsam(self):
        """The equivalent ``gtsam.noiseModel.mEstimator`` object (Block reweighting)."""
        import gtsam

        return getattr(gtsam.noiseModel.mEstimator, LOSSES[self.name][1]).Create(float(self.k))

    def __str__(self) -> str:
        return f"{self.name}:{self.k:g}"


def parse_loss(text: str) -> RobustLoss:
    """``"huber"`` or ``"huber:1.5"`` → :class:`RobustLoss`; ValueError naming the problem."""
    name, sep, param = text.partition(":")
    name = name.strip().lower()
    if name not in LOSSES:
        raise ValueError(f"unknown robust loss {name!r} (choose from {', '.join(LOSSES)})")
    if not sep:
        return RobustLoss(name, LOSSES[name][2])
    try:
        k = float(param)
    except ValueError:
        raise ValueError(f"robust loss {name}: parameter must be a number, got {param!r}") from None
    if not (math.isfinite(k) and k > 0):
        raise ValueError(f"robust loss {name}: parameter must be positive, got {param!r}")
    return RobustLoss(name, k)


_FLOAT = re.compile(r"[-+]?\d\.\d+e[-+]\d+")


def from_gtsam(mestimator) -> RobustLoss | None:
    """The :class:`RobustLoss` equal to a ``gtsam.noiseModel.mEstimator`` object, or None.

    None for estimators we do not vectorize (other classes, ``Scalar``
    reweighting).  The Python wrapper has no accessor for the parameter, so it
    is read from GTSAM's own serialization (printed with 17 significant digits,
    so exact) and then checked: our ``weight``/``loss`` must reproduce the
    object's at distances around the parameter, else None.
    """
    entry = _BY_CLASS.get(type(mestimator).__name__)
    if entry is None:
        return None
    name, _ = entry
    try:
        text = mestimator.serialize()
    except Exception:  # pragma: no cover - every mEstimator in gtsam 4.3 serializes
        return None
    key = (name, text)
    if key not in _FROM_GTSAM:
        _FROM_GTSAM[key] = _parse_checked(name, text, mestimator)
    return _FROM_GTSAM[key]


_FROM_GTSAM: dict = {}  # (name, serialization) → RobustLoss | None: graphs share few estimators


def _parse_checked(name: str, text: str, mestimator) -> RobustLoss | None:
    m = _FLOAT.search(text)
    if m is None:
        return None
    # The token before the parameter is the ReweightScheme (0 Scalar, 1 Block).
    head = text[: m.start()].split()
    if not head or head[-1] != "1":
        return None
    k = float(m.group(0))
    if not (math.isfinite(k) and k > 0):
        return None
    ours = RobustLoss(name, k)
    probe = np.array([0.0, 0.5 * k, 0.999 * k, k, 1.001 * k, 2.0 * k, 10.0 * k,
                      math.sqrt(k), 1.5 * math.sqrt(k)])
    w, r = ours.evaluate(probe)
    for x, wi, ri in zip(probe, w, r):
        if not (np.isclose(wi, mestimator.weight(float(x)), rtol=1e-12, atol=0)
                and np.isclose(ri, mestimator.loss(float(x)), rtol=1e-12, atol=1e-300)):
            return None
    return ours
