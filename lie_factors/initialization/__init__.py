"""Initial values for a pose graph: one policy (:func:`initialize`), GTSAM's initializers on arrays.

Where Levenberg–Marquardt starts decides where it stops: on torus3D the
composed odometry of the file leads GTSAM's LM to a local minimum (error
29954 after 69 iterations) while GTSAM's chordal relaxation leads it to
12117.6 in 3.  Methods (:data:`METHODS`):

``chordal``
    GTSAM's ``InitializePose3.initialize`` (Martinec–Pajdla chordal relaxation
    of the rotations, then one Gauss–Newton step on the full poses).  A 2-D
    graph goes through it as a planar Pose3 graph (GTSAM has no chordal
    initializer for Pose2; :mod:`~lie_factors.initialization.planar`).
``lago``
    GTSAM's ``lago.initialize`` (Carlone et al., linear approximation of the
    Pose2 orientations).  2-D only; every information matrix must be diagonal.
``spanning-tree``
    measurements composed along a breadth-first spanning tree from the first
    prior (:mod:`~lie_factors.initialization.spanning_tree`).
``file``
    the poses given (a g2o file's vertices, usually composed odometry).
``auto``
    3-D: chordal; 2-D: lago, then chordal; then file, then spanning-tree — the
    first that runs.  Similarity3 graphs (Sim(3) g2o files): file, then
    spanning-tree (GTSAM's chordal and LAGO initializers are for
    Pose3/Pose2).  Given the known inliers (odometry and the priors, for
    robust and GNC runs), from those edges alone first: composed along them
    when they are a tree (the chordal/LAGO answer on a chain), else the
    relaxations on them; then file, then spanning-tree over every edge.
    Each method that cannot run is reported with a one-line reason in
    :attr:`Initialization.skipped`.

``chordal`` and ``lago`` have two implementations giving the same poses to
~1e-10 (``engine``): ours on the arrays of the pose graph
(:mod:`~lie_factors.initialization.chordal`: numpy, the group kernels (numba)
and CHOLMOD; :mod:`~lie_factors.initialization.lago`: numpy and CHOLMOD), the
default and the batch backend's, and GTSAM's own on the GTSAM graph built
from it (:mod:`~lie_factors.initialization.with_gtsam`: no numba), which the
``--backend native`` path uses, as does every path where cvxopt is missing.
Anchor and priors as GTSAM treats them: :mod:`~lie_factors.initialization.anchor`.
"""

from ..errors import InitializationError
from .anchor import ANCHOR_KEY
from .policy import ENGINES, METHODS, Initialization, auto_order, initialize

__all__ = ["ANCHOR_KEY", "ENGINES", "METHODS", "Initialization", "InitializationError", "auto_order",
           "initialize"]
