"""lie-factors: closed-form Lie-group kernels and GTSAM factors built on them.

Modules (tangent orderings are GTSAM's, see docs/conventions.md):

- :mod:`lie_factors.so3` (Rot3, [ω]), :mod:`lie_factors.se3` (Pose3, [ω, v]),
  :mod:`lie_factors.se2` (Pose2, [x, y, θ]), :mod:`lie_factors.sim2`
  (Similarity2, [x, y, θ, λ]), :mod:`lie_factors.sim3` (Similarity3, [ω, u, λ]):
  hat, vee, exp, log, ad, Ad, dexp, dlog.
- :mod:`lie_factors.quaternion`, :mod:`lie_factors.dual_quaternion`: exp/log.
- :mod:`lie_factors.testing.series`: D_exp from its power series, the test oracle.
"""

__version__ = "0.1.0"
