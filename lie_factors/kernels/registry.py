"""The groups lie_factors knows, each declared once: dimensions, matrix shape, GTSAM type, tangent order.

Everything that needs a fact about a group reads it here: the numba dispatch
(:mod:`lie_factors.kernels.dispatch`), the public functions, the factors, the
batch reader, the conversions to and from ``gtsam.Values``
(:mod:`lie_factors.kernels.elements`), the pose-graph type and the test
oracles.  This module imports neither numba nor GTSAM, so the numba-free paths
(``--backend native``, the input check) can read it.

========  ==========  =========  ======  ========  ==============================================
name      GTSAM       tangent    n (dim) m (mat)   element
========  ==========  =========  ======  ========  ==============================================
so3       Rot3        [ω]        3       3         R
se3       Pose3       [ω, v]     6       4         [[R, t], [0, 1]]
se2       Pose2       [x, y, θ]  3       3         [[R, t], [0, 1]]
sim2      Similarity2 [x, y, θ, λ] 4     3         [[R, t], [0, e^−λ]]
sim3      Similarity3 [ω, u, λ]  7       4         [[R, t], [0, e^−λ]]  (s = e^λ)
========  ==========  =========  ======  ========  ==============================================
"""

from __future__ import annotations

from dataclasses import dataclass

#: ``corner``: what the bottom-right entry of an element is.  NO_CORNER: the element is a
#: bare rotation; ONE: last row [0 … 0 1]; POSITIVE: last row [0 … 0 s] with s > 0.
NO_CORNER, ONE, POSITIVE = 0, 1, 2


@dataclass(frozen=True)
class GroupInfo:
    """The facts of one group.

    ``name``: the kernel module's name (``"se3"``, ``lie_factors.se3``);
    ``gtsam``: GTSAM's type name (``"Pose3"``); ``label``: how people write
    the group (``"SE(3)"``); ``dim``: tangent dimension n; ``mat``: matrix size
    m; ``rot_dim``: size of the rotation block R = X[:d, :d]; ``corner``:
    :data:`NO_CORNER`, :data:`ONE` or :data:`POSITIVE`; ``tangent``: GTSAM's
    tangent order.
    """

    name: str
    gtsam: str
    label: str
    dim: int
    mat: int
    rot_dim: int
    corner: int
    tangent: str

    @property
    def module(self) -> str:
        """Import path of the group's kernel module."""
        return f"lie_factors.{self.name}"


SO3 = GroupInfo("so3", "Rot3", "SO(3)", 3, 3, 3, NO_CORNER, "[ω]")
SE3 = GroupInfo("se3", "Pose3", "SE(3)", 6, 4, 3, ONE, "[ω, v]")
SE2 = GroupInfo("se2", "Pose2", "SE(2)", 3, 3, 2, ONE, "[x, y, θ]")
SIM2 = GroupInfo("sim2", "Similarity2", "Sim(2)", 4, 3, 2, POSITIVE, "[x, y, θ, λ]")
SIM3 = GroupInfo("sim3", "Similarity3", "Sim(3)", 7, 4, 3, POSITIVE, "[ω, u, λ]")

#: Every group, by kernel-module name.
GROUPS: dict[str, GroupInfo] = {g.name: g for g in (SO3, SE3, SE2, SIM2, SIM3)}

#: Every group, by GTSAM type name.
BY_GTSAM: dict[str, GroupInfo] = {g.gtsam: g for g in GROUPS.values()}


def group(name: str) -> GroupInfo:
    """The group called ``name``: a kernel-module name (``"se3"``) or a GTSAM type (``"Pose3"``)."""
    info = GROUPS.get(name) or BY_GTSAM.get(name)
    if info is None:
        known = ", ".join(f"{g.name}/{g.gtsam}" for g in GROUPS.values())
        raise KeyError(f"unknown group {name!r} (known: {known})")
    return info
