"""The groups lie_factors knows, each declared once: dimensions, element shape, GTSAM type, tangent order.

Everything that needs a fact about a group reads it here: the numba dispatch
(:mod:`lie_factors.kernels.dispatch`, which makes each :class:`GroupInfo` the
group's tag in numba kernels), the public functions
(:mod:`lie_factors.kernels.public`), the factors, the batch reader, the
conversions to and from ``gtsam.Values`` (:mod:`lie_factors.interop`),
the pose-graph type, the crosscheck and the test oracles.  This module imports
neither numba nor GTSAM, so the numba-free paths (``--backend native``, the
input check) can read it.

===============  ===========  ============  ===  =======  =====================================
name             GTSAM        tangent       n    element  element
===============  ===========  ============  ===  =======  =====================================
so3              Rot3         [ω]           3    (3, 3)   R
se3              Pose3        [ω, v]        6    (4, 4)   [[R, t], [0, 1]]
se2              Pose2        [x, y, θ]     3    (3, 3)   [[R, t], [0, 1]]
sim2             Similarity2  [x, y, θ, λ]  4    (3, 3)   [[R, t], [0, 1/s]], s = e^λ
sim3             Similarity3  [ω, u, λ]     7    (4, 4)   [[R, t], [0, 1/s]], s = e^λ
quaternion       (Rot3)       [ω]           3    (4,)     q = [w, x, y, z], ‖q‖ = 1
dual_quaternion  (Pose3)      [ω, v]        6    (8,)     [q_r, q_d], q_d = ½ (0, t) ⊗ q_r
===============  ===========  ============  ===  =======  =====================================

The first five are :data:`GROUPS`, the matrix groups with GTSAM types (what
factors, graphs and files hold); the last two, :data:`QUATERNIONS`, are other
representations of SO(3) and SE(3), with exp, log, compose and inverse only.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "NO_CORNER", "ONE", "POSITIVE", "UNIT", "GroupInfo", "SO3", "SE3", "SE2", "SIM2", "SIM3", "QUATERNION",
    "DUAL_QUATERNION", "GROUPS", "BY_GTSAM",
    "QUATERNIONS", "group",
]

#: ``corner``: what makes an element valid beyond its shape and finite entries.
#: NO_CORNER: the element is a bare rotation; ONE: a rotation block and the last row
#: [0 … 0 1]; POSITIVE: a rotation block and the last row [0 … 0 1/s] with 1/s > 0;
#: UNIT: a unit quaternion (‖q‖ = 1) or unit dual quaternion (also q_r · q_d = 0).
NO_CORNER, ONE, POSITIVE, UNIT = 0, 1, 2, 3


@dataclass(frozen=True, eq=False)
class GroupInfo:
    """The facts of one group; with :mod:`lie_factors.kernels.dispatch` imported, also its
    tag in numba kernels (pass it as ``g`` to a group-generic kernel).

    ``name``: the kernel module's name (``"se3"``, ``lie_factors.se3``);
    ``gtsam``: GTSAM's type name (``"Pose3"``; for the quaternions, the type they
    represent); ``label``: how people write the group (``"SE(3)"``); ``dim``:
    tangent dimension n; ``mat``: matrix size m (for the quaternions, of the
    matrix they represent); ``rot_dim``: size of the rotation block
    R = X[:d, :d]; ``corner``: :data:`NO_CORNER`, :data:`ONE`, :data:`POSITIVE`
    or :data:`UNIT`; ``tangent``: GTSAM's tangent order; ``rotation``: where the
    rotation sits in the tangent, ``x[rotation[0]:rotation[1]]``; ``element``:
    the shape of one element.

    Each group has exactly one instance (compared by identity); it pickles by name.
    """

    name: str
    gtsam: str
    label: str
    dim: int
    mat: int
    rot_dim: int
    corner: int
    tangent: str
    rotation: tuple
    element: tuple

    @property
    def module(self) -> str:
        """Import path of the group's kernel module."""
        return f"lie_factors.{self.name}"

    @property
    def rotation_slice(self) -> slice:
        """Where the rotation (the angle θ, or ω) sits in a tangent vector."""
        return slice(*self.rotation)

    def __reduce__(self):
        # By name: unpickling gives back this very object (numba's cache pickles tags).
        return (group, (self.name,))

    def __repr__(self) -> str:
        return f"<group {self.name}>"


SO3 = GroupInfo(name="so3", gtsam="Rot3", label="SO(3)", dim=3, mat=3, rot_dim=3, corner=NO_CORNER,
                tangent="[ω]", rotation=(0, 3), element=(3, 3))
SE3 = GroupInfo(name="se3", gtsam="Pose3", label="SE(3)", dim=6, mat=4, rot_dim=3, corner=ONE,
                tangent="[ω, v]", rotation=(0, 3), element=(4, 4))
SE2 = GroupInfo(name="se2", gtsam="Pose2", label="SE(2)", dim=3, mat=3, rot_dim=2, corner=ONE,
                tangent="[x, y, θ]", rotation=(2, 3), element=(3, 3))
SIM2 = GroupInfo(name="sim2", gtsam="Similarity2", label="Sim(2)", dim=4, mat=3, rot_dim=2,
                 corner=POSITIVE, tangent="[x, y, θ, λ]", rotation=(2, 3), element=(3, 3))
SIM3 = GroupInfo(name="sim3", gtsam="Similarity3", label="Sim(3)", dim=7, mat=4, rot_dim=3,
                 corner=POSITIVE, tangent="[ω, u, λ]", rotation=(0, 3), element=(4, 4))
QUATERNION = GroupInfo(name="quaternion", gtsam="Rot3", label="unit quaternions", dim=3, mat=3,
                       rot_dim=3, corner=UNIT, tangent="[ω]", rotation=(0, 3), element=(4,))
DUAL_QUATERNION = GroupInfo(name="dual_quaternion", gtsam="Pose3", label="unit dual quaternions", dim=6,
                            mat=4, rot_dim=3, corner=UNIT, tangent="[ω, v]", rotation=(0, 3),
                            element=(8,))

#: The matrix groups, by kernel-module name.
GROUPS: dict[str, GroupInfo] = {g.name: g for g in (SO3, SE3, SE2, SIM2, SIM3)}

#: The matrix groups, by GTSAM type name.
BY_GTSAM: dict[str, GroupInfo] = {g.gtsam: g for g in GROUPS.values()}

#: Unit quaternions and unit dual quaternions, by kernel-module name.
QUATERNIONS: dict[str, GroupInfo] = {g.name: g for g in (QUATERNION, DUAL_QUATERNION)}


def group(name: str) -> GroupInfo:
    """The group called ``name``: a kernel-module name (``"se3"``) or a GTSAM type (``"Pose3"``)."""
    info = GROUPS.get(name) or BY_GTSAM.get(name) or QUATERNIONS.get(name)
    if info is None:
        known = ", ".join(f"{g.name}/{g.gtsam}" for g in GROUPS.values())
        raise KeyError(f"unknown group {name!r} (known: {known}, {', '.join(QUATERNIONS)})")
    return info
