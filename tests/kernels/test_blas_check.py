"""numba's BLAS check without scipy.linalg (lie_factors.kernels.blas_check), in fresh interpreters:
a process whose kernels call no BLAS never imports scipy.linalg, numba still finds BLAS, and a
kernel that calls it later imports scipy.linalg then and computes what numpy computes."""

from __future__ import annotations

import subprocess
import sys

_SCRIPT = r"""
import sys
import numpy as np
from lie_factors.sparse.min_degree import minimum_degree

minimum_degree(3, np.array([[0, 1], [1, 2]], dtype=np.int64))  # a kernel that calls no BLAS
import numba.np.arraymath
print(int("scipy.linalg" in sys.modules), int("scipy.linalg.cython_blas" in sys.modules),
      int(numba.np.arraymath._HAVE_BLAS))

import numba

@numba.njit
def products(a):
    return np.dot(a, a), np.linalg.cholesky(np.dot(a, a.T) + np.eye(3))

a = np.arange(9.0).reshape(3, 3) / 7
p, c = products(a)
import scipy.linalg.cython_blas
print(int(np.allclose(p, a @ a) and np.allclose(c, np.linalg.cholesky(a @ a.T + np.eye(3)))),
      int("scipy.linalg" in sys.modules), int(scipy.linalg.cython_blas is sys.modules["scipy.linalg.cython_blas"]))
"""


def test_a_kernel_without_blas_imports_no_scipy_linalg_and_blas_still_works():
    out = subprocess.run([sys.executable, "-c", _SCRIPT], check=True, capture_output=True, text=True).stdout.split()
    assert out == ["0", "0", "1", "1", "1", "1"]


def test_the_smoothers_fronts_load_blas_with_their_module():
    """Their kernels call BLAS inside an update: scipy.linalg comes with the module, not with an
    update."""
    script = "import sys; import lie_factors.incremental.fronts; print(int('scipy.linalg' in sys.modules))"
    out = subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, text=True).stdout
    assert out.split() == ["1"]
