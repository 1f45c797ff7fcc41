"""The kernel machinery under the group modules (:mod:`lie_factors.so3` … :mod:`lie_factors.dual_quaternion`).

- :mod:`~lie_factors.kernels.registry`: each group's facts, declared once (no numba, no GTSAM).
- :mod:`~lie_factors.kernels.dispatch`: the facts as tags of group-generic numba kernels.
- :mod:`~lie_factors.kernels.public`: every group's public functions, built once
  (validation, broadcasting, the single-element fast path).
- :mod:`~lie_factors.kernels.validate` (numpy) and :mod:`~lie_factors.kernels.checks`
  (numba): one rule per kind of argument, one message per defect.
- :mod:`~lie_factors.kernels.coeffs`: the rotation coefficients a_θ, b_θ, … with their Taylor bands.
- :mod:`~lie_factors.kernels.jit`: the ``kernel`` decorator, compiled entry points, compile time.
- :mod:`~lie_factors.interop`: element matrices to and from ``gtsam.Values`` (no numba).
"""
