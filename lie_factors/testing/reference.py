"""High-precision references built from the definitions, never from closed forms.

Used by the tests and by ``lie-factors crosscheck`` as the oracle the closed
forms are measured against.

Everything here is written independently of the code under test (it reads only
the groups' names and dimensions from :mod:`lie_factors.kernels.registry`):
``hat`` follows GTSAM's tangent orders, ``ad`` is the matrix of
``y -> vee([hat x, hat y])`` obtained by bracketing basis vectors, ``exp`` is the
matrix exponential of ``hat(x)`` and ``dexp`` is the power series
sum_i ad^i/(i+1)! (Eade, "Derivative of the Exponential Map", Eq. 35), all at
``DPS`` significant digits with mpmath.
"""

from __future__ import annotations

import mpmath as mp
import numpy as np

from ..kernels import registry

DPS = 50
mp.mp.dps = DPS

# --- hat/vee per group (the tangent orders of docs/conventions.md) ---------------------------


def _skew(w):
    return [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]


def hat_so3(x):
    return mp.matrix(_skew(x))


def hat_se3(x):
    w, v = x[:3], x[3:]
    S = _skew(w)
    return mp.matrix([S[0] + [v[0]], S[1] + [v[1]], S[2] + [v[2]], [0, 0, 0, 0]])


def hat_se2(x):
    return mp.matrix([[0, -x[2], x[0]], [x[2], 0, x[1]], [0, 0, 0]])


def hat_sim2(x):
    return mp.matrix([[0, -x[2], x[0]], [x[2], 0, x[1]], [0, 0, -x[3]]])


def hat_sim3(x):
    w, u, lam = x[:3], x[3:6], x[6]
    S = _skew(w)
    return mp.matrix([S[0] + [u[0]], S[1] + [u[1]], S[2] + [u[2]], [0, 0, 0, -lam]])


def vee_so3(M):
    return [M[2, 1], M[0, 2], M[1, 0]]


def vee_se3(M):
    return [M[2, 1], M[0, 2], M[1, 0], M[0, 3], M[1, 3], M[2, 3]]


def vee_se2(M):
    return [M[0, 2], M[1, 2], M[1, 0]]


def vee_sim2(M):
    return [M[0, 2], M[1, 2], M[1, 0], -M[2, 2]]


def vee_sim3(M):
    return [M[2, 1], M[0, 2], M[1, 0], M[0, 3], M[1, 3], M[2, 3], -M[3, 3]]


#: name → (tangent dimension n from the registry, hat, vee) of every matrix group.
GROUPS = {name: (registry.group(name).dim, globals()[f"hat_{name}"], globals()[f"vee_{name}"])
          for name in registry.GROUPS}


def mpf_vec(x):
    """Exact conversion of a float64 vector to mpf (no rounding)."""
    return [mp.mpf(float(v)) for v in np.asarray(x, dtype=float).ravel()]


def to_numpy(M) -> np.ndarray:
    return np.array(M.tolist(), dtype=float)


def ad(group: str, x):
    """ad_x as the matrix of y -> vee(hat(x) hat(y) - hat(y) hat(x))."""
    n, hat, vee = GROUPS[group]
    X = hat(x)
    A = mp.matrix(n, n)
    for j in range(n):
        e = [0] * n
        e[j] = 1
        Y = hat(e)
        col = vee(X * Y - Y * X)
        for i in range(n):
            A[i, j] = col[i]
    return A


def exp(group: str, x):
    """exp(hat(x)) by mpmath's matrix exponential."""
    return mp.expm(GROUPS[group][1](x))


def dexp(group: str, x):
    """sum_i ad_x^i/(i+1)!, summed until terms fall below 10^-DPS of the sum (1-norms).

    Plain lists of mpf and the nonzero entries of ad_x only: the same sum as with
    mp.matrix products, ~2× faster (the test sweeps call this a few hundred times).
    """
    A = ad(group, x)
    n = A.rows
    cols = [[(k, A[k, j]) for k in range(n) if A[k, j] != 0] for j in range(n)]
    total = [[mp.mpf(int(i == j)) for j in range(n)] for i in range(n)]
    term = [row[:] for row in total]
    tol = mp.mpf(10) ** (-DPS)

    def norm1(M):
        return max(mp.fsum(abs(M[r][c]) for r in range(n)) for c in range(n))

    i = 0
    while True:
        i += 1
        d = i + 1
        term = [[mp.fsum(row[k] * a for k, a in cols[j]) / d for j in range(n)] for row in term]
        for r in range(n):
            for c in range(n):
                total[r][c] += term[r][c]
        if i > 3 and norm1(term) <= tol * max(norm1(total), 1):
            break
        if i > 2000:
            raise RuntimeError("dexp series did not converge")
    return mp.matrix(total)


def dlog(group: str, x):
    return mp.inverse(dexp(group, x))


def log(group: str, X):
    """vee(logm(X)) by mpmath's principal matrix logarithm (X: float or mp matrix).

    Valid away from rotation angle pi, where the principal logarithm is unique.
    """
    M = X if isinstance(X, mp.matrix) else mp.matrix(np.asarray(X, dtype=float).tolist())
    return GROUPS[group][2](mp.logm(M))


def log_near(group: str, X, x0, tol_digits: int = DPS - 5):
    """The logarithm of X closest to x0: Newton on exp(hat x) = X at DPS digits.

    mp.logm can return a complex, non-principal branch for rotation angles near
    pi; starting from a nearby tangent x0 (e.g. the vector that generated X)
    and solving the definition directly avoids that. Each step uses
    X·exp(x)⁻¹ ≈ exp(D_exp(x) δ), i.e. δ = D_exp(x)⁻¹ vee(X·exp(x)⁻¹ − I).
    """
    n, hat, vee = GROUPS[group]
    Xm = X if isinstance(X, mp.matrix) else mp.matrix(np.asarray(X, dtype=float).tolist())
    x = [mp.mpf(v) if not isinstance(v, mp.mpf) else v for v in x0]
    tol = mp.mpf(10) ** (-tol_digits)
    for _ in range(100):
        E = mp.expm(hat(x))
        r = vee(Xm * mp.inverse(E) - mp.eye(Xm.rows))
        d = dlog(group, x) * mp.matrix(r)
        x = [x[i] + d[i] for i in range(n)]
        if mp.norm(d) <= tol * max(1, mp.norm(mp.matrix(x))):
            return x
    raise RuntimeError("log_near: Newton did not converge")


# --- unit quaternions [w, x, y, z] ------------------------------------------------------


def quat_mul(p, q):
    """Hamilton product of two quaternions given as [w, x, y, z] lists."""
    w1, x1, y1, z1 = p
    w2, x2, y2, z2 = q
    return [w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2]


def quat_exp(w):
    """exp of the pure quaternion (0, ω/2) by its power series (half-angle convention)."""
    p = [mp.mpf(0)] + [mp.mpf(v) / 2 for v in w]
    total = [mp.mpf(1), mp.mpf(0), mp.mpf(0), mp.mpf(0)]
    term = list(total)
    for k in range(1, 400):
        term = [t / k for t in quat_mul(term, p)]
        total = [a + b for a, b in zip(total, term)]
        if max(abs(t) for t in term) < mp.mpf(10) ** (-DPS - 5) and k > 3:
            break
    return total


def quat_to_rotation(q):
    """The rotation matrix v ↦ q v q* of a unit quaternion [w, x, y, z]."""
    w, x, y, z = q
    return mp.matrix([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def rel_err(ours, ref) -> float:
    """docs/conventions.md accuracy: max|A - R| / max(1, max|R|), computed in mpmath.

    ``ref`` is an mpmath matrix or a (nested) list of mpf; ``ours`` anything
    numpy can convert, with the same number of entries.
    """
    if isinstance(ref, mp.matrix):
        flat_r = [ref[i, j] for i in range(ref.rows) for j in range(ref.cols)]
    else:
        flat_r = list(np.asarray(ref, dtype=object).ravel())
    flat_o = np.asarray(ours, dtype=float).ravel().tolist()
    if len(flat_o) != len(flat_r):
        raise ValueError(f"size mismatch: {len(flat_o)} vs {len(flat_r)}")
    num = max(abs(mp.mpf(o) - mp.mpf(r)) for o, r in zip(flat_o, flat_r))
    den = max(mp.mpf(1), max(abs(mp.mpf(r)) for r in flat_r))
    return float(num / den)
