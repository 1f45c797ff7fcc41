"""Absolute and relative trajectory error, as evo computes them (``evo_ape``, ``evo_rpe``).

**Association.** By stamp: each stamp of the shorter trajectory is paired with the
nearest stamp of the longer one, if within :data:`MAX_STAMP_DIFFERENCE` (evo's
rule; pose ids pair exactly).  A trajectory without stamps (KITTI) pairs by
index with one of the same length.

**Alignment** (``align``): ``se3`` finds the rotation R and translation t, ``sim3``
also the scale s, that minimize Σᵢ ‖pᵢ − (s·R·qᵢ + t)‖² over the associated
positions p (reference) and q (estimate), in closed form (Umeyama, "Least-squares
estimation of transformation parameters between two point patterns", IEEE PAMI
1991, Eqs. 38–42): with the centroids μ_p, μ_q, the variance σ_q² of q and the
cross-covariance Σ = (1/n)·Σᵢ (pᵢ − μ_p)(qᵢ − μ_q)ᵀ = U·D·Vᵀ (SVD),
S = diag(1, 1, det(U)·det(V)), R = U·S·Vᵀ, s = tr(D·S)/σ_q² (1 without scale),
t = μ_p − s·R·μ_q.  Every estimated pose X becomes [[R, t], [0, 1]]·X with its
translation first scaled by s.  ``none`` leaves the estimate as it is.

**ATE**: eᵢ = ‖pᵢ − p̂ᵢ‖, the position error of each associated pose after
alignment.  **RPE** over ``delta`` poses: for the pairs (i, j) = (0, δ), (δ, 2δ), …
of the associated poses, Eᵢⱼ = (Qᵢ⁻¹·Qⱼ)⁻¹·(P̂ᵢ⁻¹·P̂ⱼ) (Q the reference, P̂ the
aligned estimate) and eᵢⱼ = ‖translation of Eᵢⱼ‖.  Each reports RMSE, mean,
median, standard deviation (population), minimum and maximum of e.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .trajectory import Trajectory

__all__ = ["MAX_STAMP_DIFFERENCE", "ALIGNMENTS", "Statistics", "Evaluation", "associate", "umeyama", "aligned",
           "ate_errors", "rpe_errors", "evaluate_trajectories"]

#: Largest difference of two stamps paired by association (evo's default, seconds).
MAX_STAMP_DIFFERENCE = 0.01

#: The alignments ``align`` names.
ALIGNMENTS = ("se3", "sim3", "none")


@dataclass(frozen=True)
class Statistics:
    """Statistics of a set of errors (metres): ``rmse``, ``mean``, ``median``, ``std``
    (population), ``min``, ``max``, and ``count``, how many errors."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    count: int

    @classmethod
    def of(cls, errors: np.ndarray) -> "Statistics":
        e = np.asarray(errors, dtype=np.float64)
        return cls(float(np.sqrt(np.mean(e * e))), float(np.mean(e)), float(np.median(e)), float(np.std(e)),
                   float(np.min(e)), float(np.max(e)), int(e.size))

    def to_dict(self) -> dict:
        return {"rmse": self.rmse, "mean": self.mean, "median": self.median, "std": self.std,
                "min": self.min, "max": self.max, "count": self.count}


@dataclass(frozen=True)
class Evaluation:
    """``ate`` and ``rpe`` (:class:`Statistics`), the ``alignment`` used and what it found
    (``rotation`` (3, 3), ``translation`` (3,), ``scale``), the ``delta`` of the RPE, and the
    per-pose ATE ``errors`` (n,) with the ``stamps`` (n,) they belong to."""

    ate: Statistics
    rpe: Statistics
    alignment: str
    rotation: np.ndarray
    translation: np.ndarray
    scale: float
    delta: int
    stamps: np.ndarray
    errors: np.ndarray
    aligned: Trajectory
    reference: Trajectory

    def to_dict(self) -> dict:
        """``{"ate": {...}, "rpe": {...}, "align": ..., "delta": ..., "scale": ..., "poses": ...}``."""
        return {"ate": self.ate.to_dict(), "rpe": self.rpe.to_dict(), "align": self.alignment,
                "delta": self.delta, "scale": self.scale, "poses": int(len(self.stamps))}

    def __repr__(self) -> str:
        return (f"<Evaluation: {len(self.stamps)} poses, ATE RMSE {self.ate.rmse:.6g} m, RPE RMSE "
                f"{self.rpe.rmse:.6g} m over {self.delta}, align {self.alignment}>")


def associate(estimate: Trajectory, reference: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """(indices into ``estimate``, indices into ``reference``) of the associated poses, in the
    shorter trajectory's order."""
    if not (estimate.stamped and reference.stamped):
        if len(estimate) != len(reference):
            raise InputError(f"{estimate.name or 'the estimate'} and {reference.name or 'the reference'}: "
                             f"without stamps they pair by index and need as many poses "
                             f"({len(estimate)} and {len(reference)})")
        k = np.arange(len(estimate))
        return k, k
    short, long_ = (estimate, reference) if len(estimate) <= len(reference) else (reference, estimate)
    order = np.argsort(long_.stamps, kind="stable")
    sorted_stamps = long_.stamps[order]
    pos = np.clip(np.searchsorted(sorted_stamps, short.stamps), 1, max(len(sorted_stamps) - 1, 1))
    left = np.clip(pos - 1, 0, len(sorted_stamps) - 1)
    right = np.clip(pos, 0, len(sorted_stamps) - 1)
    d_left = np.abs(sorted_stamps[left] - short.stamps)
    d_right = np.abs(sorted_stamps[right] - short.stamps)
    # the nearest stamp; on a tie the first in the longer trajectory's order (as evo's argmin)
    pick_left = (d_left < d_right) | ((d_left == d_right) & (order[left] <= order[right]))
    nearest = np.where(pick_left, left, right)
    diff = np.where(pick_left, d_left, d_right)
    keep = diff <= MAX_STAMP_DIFFERENCE
    i_short, i_long = np.flatnonzero(keep), order[nearest[keep]]
    if not i_short.size:
        raise InputError(f"{estimate.name or 'the estimate'} and {reference.name or 'the reference'} have no "
                         f"stamps in common (within {MAX_STAMP_DIFFERENCE} s)")
    return (i_short, i_long) if short is estimate else (i_long, i_short)


def umeyama(q: np.ndarray, p: np.ndarray, scale: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """(R, t, s) minimizing Σ ‖pᵢ − (s·R·qᵢ + t)‖² (module docstring); ``q``, ``p`` (n, 3)."""
    n = len(q)
    if n < 3 and scale:
        raise InputError(f"a similarity alignment needs at least 3 associated poses, got {n}")
    mu_q, mu_p = q.mean(axis=0), p.mean(axis=0)
    qc, pc = q - mu_q, p - mu_p
    sigma = pc.T @ qc / n
    U, D, Vt = np.linalg.svd(sigma)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / (np.sum(qc * qc) / n)) if scale else 1.0
    t = mu_p - s * R @ mu_q
    return R, t, s


def aligned(estimate: Trajectory, R: np.ndarray, t: np.ndarray, s: float) -> Trajectory:
    """``estimate`` with every pose's translation scaled by ``s`` and then [[R, t], [0, 1]] applied."""
    P = estimate.poses.copy()
    P[:, :3, 3] *= s
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return Trajectory(estimate.stamps, T @ P, estimate.stamped, estimate.name)


def ate_errors(estimate: Trajectory, reference: Trajectory) -> np.ndarray:
    """(n,) the position error of each pose (associated, aligned)."""
    return np.linalg.norm(reference.positions - estimate.positions, axis=1)


def _relative(P: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(k, 4, 4) Pᵢ⁻¹·Pⱼ of rigid transforms."""
    Ri, ti = P[i, :3, :3], P[i, :3, 3]
    out = np.broadcast_to(np.eye(4), (len(i), 4, 4)).copy()
    RiT = np.swapaxes(Ri, 1, 2)
    out[:, :3, :3] = RiT @ P[j, :3, :3]
    out[:, :3, 3] = np.einsum("kab,kb->ka", RiT, P[j, :3, 3] - ti)
    return out


def rpe_errors(estimate: Trajectory, reference: Trajectory, delta: int) -> np.ndarray:
    """(k,) the translation error of the relative pose over ``delta`` poses, for the pairs
    (0, δ), (δ, 2δ), … of the associated poses."""
    ids = np.arange(0, len(estimate), delta)
    i, j = ids[:-1], ids[1:]
    if not i.size:
        raise InputError(f"RPE over {delta} poses needs more than {delta} associated poses, got {len(estimate)}")
    E = np.linalg.inv(_relative(reference.poses, i, j)) @ _relative(estimate.poses, i, j)
    return np.linalg.norm(E[:, :3, 3], axis=1)


def evaluate_trajectories(estimate: Trajectory, reference: Trajectory, align: str = "se3",
                          delta: int = 1) -> Evaluation:
    """ATE and RPE of ``estimate`` against ``reference`` (module docstring)."""
    if align not in ALIGNMENTS:
        raise InputError(f"align: unknown alignment {align!r} (choose from {', '.join(ALIGNMENTS)})")
    if isinstance(delta, bool) or not isinstance(delta, (int, np.integer)) or delta < 1:
        raise InputError(f"delta: expected an integer ≥ 1, got {delta!r}")
    ie, ir = associate(estimate, reference)
    est, ref = estimate.subset(ie), reference.subset(ir)
    if align == "none":
        R, t, s = np.eye(3), np.zeros(3), 1.0
    else:
        R, t, s = umeyama(est.positions, ref.positions, scale=align == "sim3")
    moved = aligned(est, R, t, s)
    errors = ate_errors(moved, ref)
    return Evaluation(Statistics.of(errors), Statistics.of(rpe_errors(moved, ref, int(delta))), align, R, t, s,
                      int(delta), ref.stamps, errors, moved, ref)
