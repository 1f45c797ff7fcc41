"""Trajectories as SLAM benchmarks and evo read them: TUM and KITTI files.

A :class:`Trajectory` is stamped 3-D poses: ``stamps`` (n,) and ``poses`` (n, 4, 4),
each a rigid transform [[R, t], [0, 1]] taking the pose's frame to the world.

- **TUM** (``.tum``): one pose per line, ``stamp tx ty tz qx qy qz qw`` (the
  quaternion's vector part first, its scalar last); ``#`` starts a comment.
- **KITTI** (``.kitti``): one pose per line, the first three rows of its matrix,
  row by row (12 numbers); no stamps: a pose's stamp is its line's index among
  the poses.

2-D poses are written as planar 3-D ones (z = 0, the rotation about z), as evo
expects; a Sim(3) pose as its rotation and the position of its frame's origin.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["Trajectory", "FORMATS", "format_of", "read_trajectory", "write_trajectory_file", "planar_poses",
           "quaternions", "rotations"]

#: The trajectory formats by file extension.
FORMATS = {".tum": "tum", ".kitti": "kitti"}

#: How far from 1 a quaternion's norm, and a rotation from orthonormal, may be in a file:
#: the rounding of the 9 to 12 digits such files print, with room.
UNIT_TOLERANCE = 1e-6


@dataclass
class Trajectory:
    """Stamped 3-D poses: ``stamps`` (n,) float64, increasing or not; ``poses`` (n, 4, 4) float64.

    ``stamped``: whether the stamps came from the data (TUM, pose ids) rather than from the
    order of the lines (KITTI).  ``name``: where it came from, for messages.
    """

    stamps: np.ndarray
    poses: np.ndarray
    stamped: bool = True
    name: str = ""

    def __post_init__(self):
        self.stamps = np.asarray(self.stamps, dtype=np.float64).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=np.float64)
        if self.poses.shape != (len(self.stamps), 4, 4):
            raise InputError(f"{self.name or 'trajectory'}: expected poses of shape ({len(self.stamps)}, 4, 4), "
                             f"got {self.poses.shape}")

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def positions(self) -> np.ndarray:
        """(n, 3) the poses' translations."""
        return self.poses[:, :3, 3]

    def subset(self, index: np.ndarray) -> "Trajectory":
        return Trajectory(self.stamps[index], self.poses[index], self.stamped, self.name)


def format_of(path: str, format: str | None = None) -> str:
    """``tum`` or ``kitti``: ``format`` if given, else from the extension of ``path``."""
    if format is not None:
        if format not in FORMATS.values():
            raise InputError(f"unknown trajectory format {format!r} (choose from {', '.join(FORMATS.values())})")
        return format
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise InputError(f"{path}: cannot tell the trajectory format from the extension {ext or '(none)'!r} "
                         f"(use {', '.join(FORMATS)} or give format=)")
    return FORMATS[ext]


# --------------------------------------------------------------------------- #
# Rotations and quaternions (Hamilton, as GTSAM's and evo's)
# --------------------------------------------------------------------------- #

def rotations(q: np.ndarray) -> np.ndarray:
    """(n, 3, 3) from unit quaternions (n, 4) ordered [qx, qy, qz, qw]."""
    x, y, z, w = (q[:, k] for k in range(4))
    R = np.empty((len(q), 3, 3))
    R[:, 0, 0] = 1 - 2 * (y * y + z * z)
    R[:, 0, 1] = 2 * (x * y - z * w)
    R[:, 0, 2] = 2 * (x * z + y * w)
    R[:, 1, 0] = 2 * (x * y + z * w)
    R[:, 1, 1] = 1 - 2 * (x * x + z * z)
    R[:, 1, 2] = 2 * (y * z - x * w)
    R[:, 2, 0] = 2 * (x * z - y * w)
    R[:, 2, 1] = 2 * (y * z + x * w)
    R[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def quaternions(R: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions [qx, qy, qz, qw], qw ≥ 0, of rotations (n, 3, 3) (Shepperd's method:
    each from the largest of 1 + trace and the diagonal's terms, so no branch loses precision)."""
    n = len(R)
    q = np.empty((n, 4))
    t = np.trace(R, axis1=1, axis2=2)
    d = np.stack([t, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=1)
    k = np.argmax(d, axis=1)
    for case in range(4):
        m = k == case
        if not m.any():
            continue
        r = R[m]
        if case == 0:
            s = 2.0 * np.sqrt(1.0 + t[m])
            q[m] = np.stack([(r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                             (r[:, 1, 0] - r[:, 0, 1]) / s, 0.25 * s], axis=1)
        else:
            i = case - 1
            j, l = (i + 1) % 3, (i + 2) % 3
            s = 2.0 * np.sqrt(1.0 + r[:, i, i] - r[:, j, j] - r[:, l, l])
            v = np.empty((m.sum(), 4))
            v[:, i] = 0.25 * s
            v[:, j] = (r[:, j, i] + r[:, i, j]) / s
            v[:, l] = (r[:, l, i] + r[:, i, l]) / s
            v[:, 3] = (r[:, l, j] - r[:, j, l]) / s
            q[m] = v
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def planar_poses(X: np.ndarray) -> np.ndarray:
    """(n, 4, 4) rigid transforms of (n, m, m) group elements: a Pose2 as a planar 3-D pose, a
    Pose3 as itself, a Similarity3 [[R, t], [0, 1/s]] as R and its origin's position s·t."""
    X = np.asarray(X, dtype=np.float64)
    out = np.broadcast_to(np.eye(4), (len(X), 4, 4)).copy()
    if X.shape[1:] == (3, 3):
        out[:, :2, :2] = X[:, :2, :2]
        out[:, :2, 3] = X[:, :2, 2]
    elif X.shape[1:] == (4, 4):
        out[:, :3, :3] = X[:, :3, :3]
        out[:, :3, 3] = X[:, :3, 3] / X[:, 3, 3][:, None]
    else:
        raise InputError(f"poses: expected (n, 3, 3) or (n, 4, 4) group elements, got {X.shape}")
    return out


# --------------------------------------------------------------------------- #
# Files
# --------------------------------------------------------------------------- #

def _rows(path: str, columns: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(numbers (n, columns), line numbers (n,)) of the data lines of ``path``; one-line errors."""
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, not a trajectory file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot be read ({exc})") from None
    rows, lines = [], []
    for number, line in enumerate(text.splitlines(), 1):
        body = line.split("#", 1)[0].replace(",", " ").split()
        if not body:
            continue
        if len(body) != columns:
            raise InputError(f"{path}:{number}: expected {columns} numbers ({what}), got {len(body)}")
        try:
            values = [float(v) for v in body]
        except ValueError:
            bad = next(v for v in body if not _is_number(v))
            raise InputError(f"{path}:{number}: {bad!r} is not a number") from None
        if not all(np.isfinite(values)):
            raise InputError(f"{path}:{number}: a value is not finite")
        rows.append(values)
        lines.append(number)
    if not rows:
        raise InputError(f"{path}: no pose in the file")
    return np.array(rows, dtype=np.float64), np.array(lines)


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def read_trajectory(path: str, format: str | None = None) -> Trajectory:
    """The trajectory in a TUM or KITTI file (``format``: ``tum``, ``kitti``, or from the extension).

    Each line is checked: its number of columns, its numbers, a unit quaternion (TUM) or an
    orthonormal rotation (KITTI), to :data:`UNIT_TOLERANCE`; a bad one raises
    :class:`~lie_factors.errors.InputError` naming the file and the line.  Quaternions are
    normalized (as evo does).
    """
    kind = format_of(path, format)
    name = os.path.basename(path)
    if kind == "tum":
        rows, lines = _rows(path, 8, "stamp tx ty tz qx qy qz qw")
        q = rows[:, 4:8]
        norm = np.linalg.norm(q, axis=1)
        bad = np.flatnonzero(np.abs(norm - 1.0) > UNIT_TOLERANCE)
        if bad.size:
            raise InputError(f"{path}:{lines[bad[0]]}: the quaternion is not a unit one (norm {norm[bad[0]]:.9g})")
        poses = np.broadcast_to(np.eye(4), (len(rows), 4, 4)).copy()
        poses[:, :3, :3] = rotations(q / norm[:, None])
        poses[:, :3, 3] = rows[:, 1:4]
        return Trajectory(rows[:, 0], poses, True, name)
    rows, lines = _rows(path, 12, "the first three rows of the pose's matrix")
    poses = np.broadcast_to(np.eye(4), (len(rows), 4, 4)).copy()
    poses[:, :3, :] = rows.reshape(-1, 3, 4)
    R = poses[:, :3, :3]
    err = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((err > UNIT_TOLERANCE) | (np.linalg.det(R) <= 0))
    if bad.size:
        raise InputError(f"{path}:{lines[bad[0]]}: the rotation is not orthonormal (|RᵀR − I| = {err[bad[0]]:.3g})")
    return Trajectory(np.arange(len(rows), dtype=np.float64), poses, False, name)


def write_trajectory_file(trajectory: Trajectory, path: str, format: str | None = None) -> None:
    """Write ``trajectory`` as TUM or KITTI (``format``, or from the extension), atomically."""
    from ..util.atomic import replace_atomically

    kind = format_of(path, format)
    P = trajectory.poses
    if kind == "tum":
        q = quaternions(P[:, :3, :3])
        data = np.column_stack([trajectory.stamps, P[:, :3, 3], q])
        header = "# stamp tx ty tz qx qy qz qw\n"
        stamp = "%.17g" if not np.all(trajectory.stamps == np.round(trajectory.stamps)) else "%d"
        fmt = [stamp] + ["%.17g"] * 7
    else:
        data = P[:, :3, :].reshape(-1, 12)
        header = ""
        fmt = ["%.17g"] * 12

    def write(tmp: str) -> None:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(header)
            np.savetxt(fh, data, fmt=fmt, delimiter=" ")

    replace_atomically(path, write)
