"""The single-element fast path of the public functions (every group of the registry).

One float64 ndarray of exactly the argument's shape is validated and computed in
one numba call; everything else takes the general (batched) path. Both run the
same cores, so a single element must equal the batch path's result bit for bit,
and every bad input must still raise the general path's ValueError (the bad
inputs themselves: tests/kernels/test_groups.py).
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from lie_factors.errors import InputError
from lie_factors.kernels import checks as _check, public as _public, registry, validate as _validate
from lie_factors import se3, so3
from lie_factors import dual_quaternion as DQ
from lie_factors import quaternion as Q

GROUPS = {name: importlib.import_module(info.module) for name, info in registry.GROUPS.items()}
TANGENT_FUNCTIONS = ("hat", "exp", "ad", "dexp", "dlog")
ELEMENT_FUNCTIONS = ("log", "Ad", "inverse")  # validate group membership


def _tangents(name, n, seed=0):
    K = GROUPS[name]
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, K.DIM))
    r = registry.group(name).rotation_slice
    w = rng.normal(size=(n, r.stop - r.start))
    x[:, r] = w * (rng.uniform(0.0, 3.0, size=n) / np.linalg.norm(w, axis=1))[:, None]
    return x


def _elements(name, n, seed=0):
    return GROUPS[name].exp(_tangents(name, n, seed))


def _calls(name, seed=0):
    """(function name, args) for one element of each public kernel."""
    K = GROUPS[name]
    x = _tangents(name, 2, seed)
    X = K.exp(x)
    calls = [(f, (x[0],)) for f in TANGENT_FUNCTIONS]
    calls += [(f, (X[0],)) for f in ELEMENT_FUNCTIONS]
    calls += [("vee", (K.hat(x[0]),)), ("compose", (X[0], X[1]))]
    return calls


def _batch(K, fname, args):
    """The general path on a batch of one: the reference the fast path must match bit for bit."""
    return getattr(K, fname)(*(a[None] for a in args))[0]


def _forbid_general_path(monkeypatch):
    """Make the general (batched) path fail, so a call that returns took the fast path."""

    def fail(*args, **kwargs):
        raise AssertionError("took the general path")

    monkeypatch.setattr(_public, "apply", fail)
    monkeypatch.setattr(_public, "apply2", fail)


@pytest.mark.parametrize("name", GROUPS)
def test_single_equals_batch_bit_for_bit(name):
    K = GROUPS[name]
    for seed in range(5):
        for fname, args in _calls(name, seed):
            ours = getattr(K, fname)(*args)
            ref = _batch(K, fname, args)
            assert ours.shape == ref.shape and ours.dtype == np.float64
            assert np.array_equal(ours, ref), (fname, args)
            assert ours.flags.c_contiguous and ours.flags.writeable and ours.flags.owndata


@pytest.mark.parametrize("name", GROUPS)
def test_fast_path_taken_for_any_memory_order(name, monkeypatch):
    # C order, Fortran order (GTSAM's .matrix()), a strided view and a read-only view all
    # take the fast path (one compiled signature serves every memory order).
    K = GROUPS[name]
    calls = _calls(name, seed=3)
    _forbid_general_path(monkeypatch)
    for fname, args in calls:
        f = getattr(K, fname)
        expected = f(*args)
        variants = {
            "fortran": [np.asfortranarray(a) for a in args],
            "strided": [np.repeat(a, 2, axis=-1)[..., ::2] for a in args],
            "readonly": [a.copy() for a in args],
        }
        for a in variants["readonly"]:
            a.flags.writeable = False
        for label, vs in variants.items():
            assert all(v.dtype == np.float64 and v.shape == a.shape for v, a in zip(vs, args))
            assert np.array_equal(f(*vs), expected), (fname, label)


def _outcome(f, args):
    try:
        return f(*args).tobytes()
    except ValueError as exc:
        return str(exc)


@pytest.mark.parametrize("name", GROUPS)
def test_general_path_inputs_agree(name):
    # Lists, integer and float32 arrays, 0-d batches and subclasses take the general path
    # and give the same numbers as the fast path on the float64 conversion.
    K = GROUPS[name]
    for fname, args in _calls(name, seed=4):
        f = getattr(K, fname)
        expected = f(*args)
        assert np.array_equal(f(*(a.tolist() for a in args)), expected), fname
        as32 = [a.astype(np.float32) for a in args]  # rotations in float32 are not orthonormal to 1e-9
        assert _outcome(f, as32) == _outcome(f, [a.astype(np.float64) for a in as32]), fname
        big_endian = [a.astype(">f8") for a in args]
        assert np.array_equal(f(*big_endian), expected), fname
    ints = np.zeros(K.DIM, dtype=np.int64)
    ints[0] = 1
    assert np.array_equal(K.exp(ints), K.exp(ints.astype(np.float64)))
    assert np.array_equal(K.dexp(ints), K.dexp(ints.astype(np.float64)))
    identity = np.eye(K.MAT, dtype=np.int64)
    assert np.array_equal(K.log(identity), np.zeros(K.DIM))


@pytest.mark.parametrize("name", GROUPS)
def test_orthonormality_threshold_straddled(name):
    # The fast check may refuse a block the general check accepts (within 1e-15 of the
    # tolerance): that element then takes the general path. It must never accept one the
    # general check rejects. Sweep max|RᵀR − I| across ORTHONORMAL_TOL in ~1e-16 steps.
    K = GROUPS[name]
    d = registry.group(name).rot_dim
    X0 = _elements(name, 1, seed=10)[0]
    tol = _validate.ORTHONORMAL_TOL
    corner = registry.group(name).corner
    seen = {"fast": 0, "general only": 0, "rejected": 0}
    for k in range(-40, 41):
        delta = 0.5 * tol * (1.0 + k * 2e-7)
        X = X0.copy()
        X[:d, 0] *= 1.0 + delta  # column 0 of the block: |c0|² − 1 ≈ 2δ
        try:
            _public.elements(X[None], registry.group(name), "X")  # the general path's own check
            general_ok = True
        except ValueError:
            general_ok = False
        fast_ok = bool(_check.element_ok(np.ascontiguousarray(X), d, corner))
        assert not (fast_ok and not general_ok), k
        seen["fast" if fast_ok else "general only" if general_ok else "rejected"] += 1
        if general_ok:
            assert np.array_equal(K.log(X), K.log(X[None])[0])
        else:
            with pytest.raises(InputError, match="orthonormal"):
                K.log(X)
    assert seen["fast"] and seen["general only"] and seen["rejected"], seen


def test_compose_mixed_inputs_take_the_general_path():
    X = se3.exp(np.array([0.1, 0.2, 0.3, 1.0, 2.0, 3.0]))
    Y = se3.exp(np.array([-0.3, 0.1, 0.2, 0.0, 1.0, -1.0]))
    ref = se3.compose(X, Y)
    assert np.array_equal(se3.compose(X.tolist(), Y), ref)
    assert np.array_equal(se3.compose(X, Y.tolist()), ref)
    assert se3.compose(X, np.stack([Y, Y])).shape == (2, 4, 4)


class _Sub(np.ndarray):
    pass


def test_subclass_takes_the_general_path():
    R = so3.exp(np.array([0.1, -0.2, 0.3]))
    out = so3.log(R.view(_Sub))
    assert type(out) is np.ndarray and np.array_equal(out, so3.log(R[None])[0])


# ------------------------------------------------------------ quaternion / dual quaternion exp, log


@pytest.mark.parametrize("M, n", [(Q, 3), (DQ, 6)], ids=["quaternion", "dual_quaternion"])
def test_quaternion_exp_log_single_equals_batch(M, n, monkeypatch):
    rng = np.random.default_rng(11)
    xs = rng.normal(size=(6, n))
    xs[:, :3] *= (rng.uniform(0.0, 3.0, size=6) / np.linalg.norm(xs[:, :3], axis=1))[:, None]
    qs = M.exp(xs)
    refs = [(M.exp(x[None])[0], M.log(q[None])[0]) for x, q in zip(xs, qs)]
    _forbid_general_path(monkeypatch)
    for (x, q), (e_ref, l_ref) in zip(zip(xs, qs), refs):
        assert np.array_equal(M.exp(x), e_ref) and np.array_equal(M.log(q), l_ref)
        assert np.array_equal(M.log(np.repeat(q, 2)[::2]), l_ref)


@pytest.mark.parametrize("M", [Q, DQ], ids=["quaternion", "dual_quaternion"])
def test_quaternion_unit_threshold_straddled(M):
    # |‖q‖ − 1| swept across UNIT_TOL in ~1e-16 steps: the fast path never accepts what the
    # general check rejects, and every accepted q gives the batch path's bits.
    q0 = M.exp(np.array([0.3, -0.2, 0.1, 1.0, 2.0, 3.0][: 3 if M is Q else 6]))
    outcomes = set()
    for k in range(-40, 41):
        q = q0.copy()
        q[:4] *= 1.0 + M.UNIT_TOL * (1.0 + k * 1e-7)
        try:
            ref = M.log(q[None])[0]
        except ValueError:
            with pytest.raises(InputError, match="unit"):
                M.log(q)
            outcomes.add("rejected")
            continue
        assert np.array_equal(M.log(q), ref)
        outcomes.add("accepted")
    assert outcomes == {"accepted", "rejected"}
