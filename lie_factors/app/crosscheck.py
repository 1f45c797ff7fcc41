"""Errors of lie_factors and GTSAM kernels against a 50-digit reference, per θ band.

Run as ``lie-factors crosscheck``.

For every function and every band of rotation angles θ, the table gives the
worst error of lie_factors and of GTSAM against a 50-digit reference computed
from the definitions (:mod:`lie_factors.testing.reference`), with the error measure of
docs/conventions.md: max|A − R| / max(1, max|R|).

GTSAM's ExpmapDerivative/LogmapDerivative are right Jacobians, so they are
compared with the reference at −x (J_r(x) = D_exp(−x)); ours is evaluated the
same way (``dexp(-x)``), so both columns answer the same question.
GTSAM's Similarity2 and Similarity3 have no Expmap/Logmap derivatives (their
rows show "—" in the GTSAM column); the Similarity3 rows compare GTSAM's
``Similarity3.Expmap``/``Logmap`` only.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
from dataclasses import dataclass
from typing import Callable

import gtsam
import numpy as np

from .. import interop
from ..kernels import registry
from ..testing import reference as ref

#: Every group of the registry and its kernel module.
KERNELS = {name: importlib.import_module(info.module) for name, info in registry.GROUPS.items()}
GROUPS = tuple(KERNELS)
#: GTSAM types without Expmap/Logmap derivatives (no GTSAM column for dexp/dlog).
NO_GTSAM_DERIVATIVE = tuple(f"{info.gtsam} ({name})" for name, info in registry.GROUPS.items()
                            if not hasattr(getattr(gtsam, info.gtsam), "ExpmapDerivative"))

#: (label, lowest θ, highest θ); degenerate bands are single points.
BANDS = [
    ("0", 0.0, 0.0),
    ("1e-200", 1e-200, 1e-200),
    ("1e-15..1e-8", 1e-15, 1e-8),
    ("1e-8..1e-4", 1e-8, 1e-4),
    ("1e-4..0.1", 1e-4, 0.1),
    ("0.1..1", 0.1, 1.0),
    ("1..π-1e-4", 1.0, math.pi - 1e-4),
    ("π-1e-4..π-1e-12", math.pi - 1e-4, math.pi - 1e-12),
]
#: Beyond π the log is another branch; the derivatives are still defined up to 2π.
DERIVATIVE_BANDS = [("π..2π-1e-3", math.pi, 2 * math.pi - 1e-3)]


@dataclass
class Row:
    function: str
    band: str
    ours: float
    gtsam: float | None


def _angles(lo: float, hi: float, k: int, rng) -> list[float]:
    if lo == hi:
        return [lo]
    if lo > 0 and hi / lo > 10:
        return list(np.exp(rng.uniform(np.log(lo), np.log(hi), size=k)))
    return list(rng.uniform(lo, hi, size=k))


def rotation_slice(group: str) -> slice:
    """Where the rotation angle sits in the group's tangent vector."""
    return registry.group(group).rotation_slice


def _tangent(group: str, theta: float, rng) -> np.ndarray:
    """A tangent vector of rotation angle θ, with translation (and scale) of size 1e-3 … 1e2."""
    if group == "so3":
        d = rng.normal(size=3)
        return theta * d / np.linalg.norm(d)
    scale = 10 ** rng.uniform(-3, 2)
    if group in ("se3", "sim3"):
        d = rng.normal(size=3)
        v = rng.normal(size=3)
        x = np.concatenate([theta * d / np.linalg.norm(d), scale * v / np.linalg.norm(v)])
        if group == "se3":
            return x
        # λ log-uniform in ±[1e-9, 2]: GTSAM's Expmap/Logmap lose digits for λ ~ 1e-5 … 1e-3
        return np.append(x, rng.choice([-1.0, 1.0]) * 10 ** rng.uniform(-9, math.log10(2)))
    sign = rng.choice([-1.0, 1.0])
    t = rng.normal(size=2)
    t = scale * t / np.linalg.norm(t)
    if group == "se2":
        return np.array([t[0], t[1], sign * theta])
    return np.array([t[0], t[1], sign * theta, rng.uniform(-2, 2)])


def _gtsam_functions() -> dict[tuple[str, str], Callable]:
    """GTSAM's version of each (group, function), expressed in our conventions."""
    f: dict[tuple[str, str], Callable] = {}
    for group, info in registry.GROUPS.items():
        cls = getattr(gtsam, info.gtsam)
        f[(group, "exp")] = lambda x, cls=cls: np.asarray(cls.Expmap(x).matrix())
        f[(group, "log")] = lambda X, cls=cls, group=group: np.asarray(cls.Logmap(interop.to_gtsam(group, X)))
        if hasattr(cls, "ExpmapDerivative"):
            # GTSAM's derivatives are right Jacobians: ExpmapDerivative(x) = D_exp(-x)
            f[(group, "dexp")] = lambda x, cls=cls: np.asarray(cls.ExpmapDerivative(x))
            f[(group, "dlog")] = lambda x, cls=cls: np.asarray(cls.LogmapDerivative(x))
    return f


def run(samples: int = 3, seed: int = 0, groups=GROUPS) -> list[Row]:
    """Measure every (group, function, band); ``samples`` random points per band."""
    rng = np.random.default_rng(seed)
    theirs = _gtsam_functions()
    rows: list[Row] = []
    for group in groups:
        K = KERNELS[group]
        for fname in ("exp", "log", "dexp", "dlog"):
            bands = BANDS + DERIVATIVE_BANDS if fname in ("dexp", "dlog") else BANDS
            for label, lo, hi in bands:
                ours_worst, their_worst = 0.0, None
                for theta in _angles(lo, hi, samples, rng):
                    x = _tangent(group, theta, rng)
                    xm = ref.mpf_vec(x)
                    if fname == "exp":
                        R = ref.exp(group, xm)
                        arg, ours = x, K.exp(x)
                    elif fname == "log":
                        X = ref.to_numpy(ref.exp(group, xm))
                        R = ref.mp.matrix(ref.log_near(group, X, xm))
                        arg, ours = X, K.log(X)
                    else:
                        # right Jacobians, GTSAM's convention: J_r(x) = D_exp(-x)
                        neg = ref.mpf_vec(-x)
                        R = ref.dexp(group, neg) if fname == "dexp" else ref.dlog(group, neg)
                        arg, ours = x, getattr(K, fname)(-x)
                    ours_worst = max(ours_worst, ref.rel_err(ours, R))
                    g = theirs.get((group, fname))
                    if g is not None:
                        try:
                            e = ref.rel_err(g(arg), R)
                        except Exception:  # GTSAM raising is its worst possible error
                            e = math.inf
                        their_worst = e if their_worst is None else max(their_worst, e)
                rows.append(Row(f"{group}.{fname}", label, ours_worst, their_worst))
    return rows


def format_table(rows: list[Row]) -> str:
    lines = [
        "| function | θ band | lie_factors error | GTSAM error |",
        "|---|---|---|---|",
    ]
    for r in rows:
        g = "—" if r.gtsam is None else f"{r.gtsam:.1e}"
        lines.append(f"| {r.function} | {r.band} | {r.ours:.1e} | {g} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="lie-factors crosscheck",
        description="Errors of lie_factors and GTSAM against a 50-digit mpmath reference, per θ band.",
    )
    parser.add_argument("--samples", type=int, default=3, help="random points per band (default 3)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print the rows as one JSON line at the end")
    args = parser.parse_args(argv)
    if args.samples < 1:
        parser.error("--samples must be at least 1")
    rows = run(args.samples, args.seed)
    print(format_table(rows))
    worst = max(r.ours for r in rows)
    print(f"\nworst lie_factors error: {worst:.1e} (target 1e-14)")
    print(f"GTSAM has no Expmap/Logmap derivative for {' or '.join(NO_GTSAM_DERIVATIVE)}: '—' in those rows.")
    if args.json:
        print(json.dumps([r.__dict__ for r in rows]))
    return 0 if worst <= 1e-14 else 1


if __name__ == "__main__":
    raise SystemExit(main())
