"""Write a seeded SE(3) pose graph (g2o, EDGE_SE3:QUAT) of any size: a helix that revisits its places.

    python benchmarks/generate_posegraph.py --poses 1000000 --output /tmp/helix1M.g2o
    python benchmarks/generate_posegraph.py --poses 100000 --closure-every 0 --output /tmp/chain100k.g2o
    python benchmarks/generate_posegraph.py --shape city --poses 4000 --seed 1 --output /tmp/city4k.g2o
    python benchmarks/generate_posegraph.py --shape hills --poses 5000 --seed 1 --output /tmp/hills5k.g2o

The robot climbs a helix of ``--lap`` poses per turn (about 1 m apart), rising
``--rise`` metres per turn, so pose i and pose i − lap are neighbours one turn
apart: every ``--closure-every``-th pose from the second turn on gets a loop
closure to the pose below it (0: a pure odometry chain).  It rolls and pitches
a little along the way, so every rotation axis is exercised.  Measurements
are the true relative poses perturbed on the right, Z = T_ij · Exp(ξ),
ξ ~ N(0, diag(σ²)) in GTSAM's Pose3 tangent order [ω, v] with σ = 0.01 rad /
0.05 m, the information the file states.  The vertices are the noisy odometry
composed from the first pose (the identity), what a robot would log.

``--shape city`` (SE(2), EDGE_SE2) and ``--shape hills`` (SE(3)) are the other
kind of graph: a walk through a grid of streets, ``--block`` metres apart, one
pose a metre, turning at random at the crossings and kept inside a square of
about √N metres, with local loop closures: a pose at the place of an earlier
pose at least ``--min-gap`` poses back is tied to one such pose, chosen at
random, with probability ``--closure-prob`` (closures come where the walk
happens to return, at irregular intervals, as in Manhattan-world graphs such as
city10000).  ``hills`` lifts the same streets onto rolling ground (height,
pitch and roll functions of the place), so a revisit is the same SE(3) pose.
SE(2) noise σ = 0.05 m / 0.01 rad in GTSAM's Pose2 tangent order [v, ω].

Everything in the helix is vectorized (numpy; composition by a doubling scan), so 10⁶ poses
take seconds, and the same ``--seed`` writes the same file byte for byte.
Sizes: N poses, N − 1 odometry edges, about (N − lap)/closure_every closures.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from lie_factors import se2, se3  # noqa: E402

SIGMAS = np.array([0.01, 0.01, 0.01, 0.05, 0.05, 0.05])  # [ω (rad), v (m)]
SIGMAS2 = np.array([0.05, 0.05, 0.01])  # SE(2): [v (m), ω (rad)]


def _rot_zyx(yaw, pitch, roll):
    """R = Rz(yaw) Ry(pitch) Rx(roll) for arrays (K,) → (K, 3, 3)."""
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    R = np.empty(yaw.shape + (3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = -sp, cp * sr, cp * cr
    return R


def helix(n: int, lap: int, rise: float) -> np.ndarray:
    """True poses (n, 4, 4): pose i at angle 2π i/lap on a helix of circumference ≈ lap metres."""
    i = np.arange(n, dtype=np.float64)
    th = 2 * np.pi * i / lap
    r = lap / (2 * np.pi)
    T = np.zeros((n, 4, 4))
    T[:, 0, 3], T[:, 1, 3], T[:, 2, 3] = r * np.cos(th), r * np.sin(th), rise * i / lap
    T[:, :3, :3] = _rot_zyx(th + np.pi / 2, 0.1 * np.sin(3 * th), 0.1 * np.cos(2 * th))
    T[:, 3, 3] = 1.0
    return T


def _inv(T):
    Ti = np.zeros_like(T)
    Rt = np.swapaxes(T[:, :3, :3], 1, 2)
    Ti[:, :3, :3] = Rt
    Ti[:, :3, 3] = -np.einsum("kab,kb->ka", Rt, T[:, :3, 3])
    Ti[:, 3, 3] = 1.0
    return Ti


def compose_scan(Z: np.ndarray) -> np.ndarray:
    """Prefix products P_k = Z_0 ⋯ Z_{k−1} (P_0 = I) of (m, d, d) → (m + 1, d, d), by doubling."""
    P = np.concatenate([np.eye(Z.shape[-1])[None], Z])
    step = 1
    while step < P.shape[0]:
        P[step:] = P[:-step] @ P[step:]
        step *= 2
    return P


def _quat_xyzw(R):
    """Unit quaternions [qx, qy, qz, qw] (K, 4) of rotations (K, 3, 3), qw ≥ 0 (Shepperd's choice of pivot)."""
    K = R.shape[0]
    tr = np.trace(R, axis1=1, axis2=2)
    d = np.stack([R[:, 0, 0], R[:, 1, 1], R[:, 2, 2], tr], axis=1)
    k = np.argmax(d, axis=1)
    q = np.empty((K, 4))
    for piv in range(4):
        m = k == piv
        if not m.any():
            continue
        Rm = R[m]
        if piv == 3:
            s = 2 * np.sqrt(1 + tr[m])
            q[m] = np.stack([(Rm[:, 2, 1] - Rm[:, 1, 2]) / s, (Rm[:, 0, 2] - Rm[:, 2, 0]) / s,
                             (Rm[:, 1, 0] - Rm[:, 0, 1]) / s, 0.25 * s], axis=1)
        else:
            a, b, c = piv, (piv + 1) % 3, (piv + 2) % 3
            s = 2 * np.sqrt(1 + Rm[:, a, a] - Rm[:, b, b] - Rm[:, c, c])
            qq = np.empty((m.sum(), 4))
            qq[:, a] = 0.25 * s
            qq[:, b] = (Rm[:, b, a] + Rm[:, a, b]) / s
            qq[:, c] = (Rm[:, c, a] + Rm[:, a, c]) / s
            qq[:, 3] = (Rm[:, c, b] - Rm[:, b, c]) / s
            q[m] = qq
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    return q


def generate(n: int, lap: int = 1000, rise: float = 0.5, closure_every: int = 10, seed: int = 0):
    """(i, j, Z (E, 4, 4), vertices (n, 4, 4)): odometry edges first, then the loop closures."""
    if n < 2:
        raise ValueError("need at least 2 poses")
    rng = np.random.default_rng(seed)
    T = helix(n, lap, rise)
    Tinv = _inv(T)
    i = np.arange(n - 1)
    j = i + 1
    if closure_every > 0 and n > lap:
        c = np.arange(lap, n, closure_every)
        i = np.concatenate([i, c - lap])
        j = np.concatenate([j, c])
    noise = rng.normal(size=(i.size, 6)) * SIGMAS
    Z = (Tinv[i] @ T[j]) @ se3.exp(noise)
    vertices = compose_scan(Z[: n - 1])
    return i, j, Z, vertices


def street_walk(n: int, block: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Integer places (n, 2) and headings (n,) (quarter turns) of a walk one metre a pose along
    streets ``block`` metres apart inside a square of about √n metres, turning at random at the
    crossings (straight 1/2, left or right 1/4 each) and back from the border."""
    side = max(2 * block, int(round(np.sqrt(n) / block)) * block)
    steps = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]])
    place = np.zeros((n, 2), dtype=np.int64)
    heading = np.zeros(n, dtype=np.int64)
    x, h = np.array([0, 0]), 0
    for k in range(1, n):
        if x[0] % block == 0 and x[1] % block == 0:
            h = (h + rng.choice([0, 0, 1, 3])) % 4
            for turn in (0, 1, 3, 2):  # the first way that stays inside
                nxt = x + steps[(h + turn) % 4]
                if 0 <= nxt[0] <= side and 0 <= nxt[1] <= side:
                    h = (h + turn) % 4
                    break
        x = x + steps[h]
        place[k], heading[k] = x, h
    return place, heading


def local_closures(place: np.ndarray, min_gap: int, prob: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """(i, j): for each pose j at the place of an earlier pose at least ``min_gap`` back, with
    probability ``prob``, one such pose i chosen at random."""
    seen: dict = {}
    ii, jj = [], []
    for j, p in enumerate(map(tuple, place.tolist())):
        earlier = seen.setdefault(p, [])
        far = [i for i in earlier if j - i >= min_gap]
        if far and rng.random() < prob:
            ii.append(far[rng.integers(len(far))])
            jj.append(j)
        earlier.append(j)
    return np.array(ii, dtype=np.int64), np.array(jj, dtype=np.int64)


def city(n: int, block: int = 10, min_gap: int = 50, closure_prob: float = 0.5, seed: int = 0, hills: bool = False):
    """(i, j, Z, vertices) of the street walk: SE(2) (3 × 3 matrices), or with ``hills`` SE(3)
    on rolling ground; odometry edges first, then the local closures."""
    if n < 2:
        raise ValueError("need at least 2 poses")
    rng = np.random.default_rng(seed)
    place, heading = street_walk(n, block, rng)
    ci, cj = local_closures(place, min_gap, closure_prob, rng)
    i = np.concatenate([np.arange(n - 1), ci])
    j = np.concatenate([np.arange(1, n), cj])
    yaw = heading * (np.pi / 2)
    if hills:
        x, y = place[:, 0].astype(np.float64), place[:, 1].astype(np.float64)
        T = np.zeros((n, 4, 4))
        T[:, :3, :3] = _rot_zyx(yaw, 0.05 * np.sin(x / 7.0), 0.05 * np.cos(y / 9.0))
        T[:, 0, 3], T[:, 1, 3] = x, y
        T[:, 2, 3] = 2.0 * np.sin(x / 15.0) * np.cos(y / 20.0)
        T[:, 3, 3] = 1.0
        noise = se3.exp(rng.normal(size=(i.size, 6)) * SIGMAS)
    else:
        T = np.zeros((n, 3, 3))
        T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw)
        T[:, :2, 2] = place
        T[:, 2, 2] = 1.0
        noise = se2.exp(rng.normal(size=(i.size, 3)) * SIGMAS2)
    Z = (np.linalg.inv(T[i]) @ T[j]) @ noise
    return i, j, Z, compose_scan(Z[: n - 1])


def write_g2o_se2(path: str, i, j, Z, vertices) -> None:
    """g2o SE(2): VERTEX_SE2 id x y θ; EDGE_SE2 id1 id2 dx dy dθ + 6 information entries (upper
    triangle over [x y θ])."""
    info = np.diag(1.0 / SIGMAS2 ** 2)
    tail = " " + " ".join(f"{v:g}" for v in info[np.triu_indices(3)]) + "\n"

    def rows(M):
        return np.stack([M[:, 0, 2], M[:, 1, 2], np.arctan2(M[:, 1, 0], M[:, 0, 0])], axis=1).tolist()

    with open(path, "w") as f:
        f.write("".join(f"VERTEX_SE2 {k} " + " ".join(map(repr, r)) + "\n" for k, r in enumerate(rows(vertices))))
        f.write("".join(f"EDGE_SE2 {a} {b} " + " ".join(map(repr, r)) + tail
                        for a, b, r in zip(i.tolist(), j.tolist(), rows(Z))))


def write_g2o(path: str, i, j, Z, vertices) -> None:
    """g2o SE(3): VERTEX_SE3:QUAT id x y z qx qy qz qw; EDGE_SE3:QUAT id1 id2 x y z qx qy qz qw + 21 information
    entries (upper triangle, g2o's order [x y z, rotation])."""
    info = np.diag(1.0 / np.concatenate([SIGMAS[3:], SIGMAS[:3]]) ** 2)
    tail = " " + " ".join(f"{v:g}" for v in info[np.triu_indices(6)]) + "\n"
    with open(path, "w") as f:
        qv = _quat_xyzw(vertices[:, :3, :3])
        rows = np.concatenate([vertices[:, :3, 3], qv], axis=1)
        f.write("".join(f"VERTEX_SE3:QUAT {k} " + " ".join(map(repr, r)) + "\n"
                        for k, r in enumerate(rows.tolist())))
        qz = _quat_xyzw(Z[:, :3, :3])
        rows = np.concatenate([Z[:, :3, 3], qz], axis=1)
        f.write("".join(f"EDGE_SE3:QUAT {a} {b} " + " ".join(map(repr, r)) + tail
                        for a, b, r in zip(i.tolist(), j.tolist(), rows.tolist())))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shape", choices=("helix", "city", "hills"), default="helix",
                    help="helix (SE(3), closures one turn apart), or a street walk with local closures: "
                         "city (SE(2)) or hills (SE(3))")
    ap.add_argument("--poses", type=int, default=100_000)
    ap.add_argument("--block", type=int, default=10, help="city/hills: metres between crossings")
    ap.add_argument("--min-gap", type=int, default=50, help="city/hills: poses back a closure reaches at least")
    ap.add_argument("--closure-prob", type=float, default=0.5,
                    help="city/hills: probability that a pose at an earlier pose's place gets a closure")
    ap.add_argument("--lap", type=int, default=1000, help="poses per turn of the helix")
    ap.add_argument("--rise", type=float, default=0.5, help="metres climbed per turn")
    ap.add_argument("--closure-every", type=int, default=10,
                    help="a loop closure on every k-th pose from the second turn on (0: none)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--output", required=True)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    if a.shape == "helix":
        i, j, Z, V = generate(a.poses, a.lap, a.rise, a.closure_every, a.seed)
    else:
        i, j, Z, V = city(a.poses, a.block, a.min_gap, a.closure_prob, a.seed, hills=a.shape == "hills")
    t1 = time.perf_counter()
    (write_g2o_se2 if a.shape == "city" else write_g2o)(a.output, i, j, Z, V)
    t2 = time.perf_counter()
    print(f"{a.output}: {a.poses} poses, {i.size} edges ({i.size - a.poses + 1} loop closures); "
          f"generated in {t1 - t0:.1f} s, written in {t2 - t1:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
