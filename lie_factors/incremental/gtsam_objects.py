"""The smoother's GTSAM-object path: factor graphs and Values read into arrays, and GTSAM's objects made back.

:func:`read_update` reads an ISAM2 update (a ``gtsam.NonlinearFactorGraph`` and
a ``gtsam.Values``) as the batch solver reads a graph: lie_factors'
Between/Prior factors and GTSAM's own on the registry's groups with a
Gaussian noise model become arrays (:class:`~lie_factors.incremental.factor_arrays.NewFactors`);
any other factor stays an object, linearized by GTSAM (:func:`native_jacobian`), or, a factor
kind's or GTSAM's with a twin kind, by the kind's kernel, a kind at a time (:class:`NativeRows`).
:func:`make_factor` makes GTSAM's factor of an array factor back, and
:func:`typed_estimate` ISAM2's typed ``calculateEstimate<Type>`` accessors.
"""

from __future__ import annotations

from typing import Callable

import gtsam
import numpy as np

from .. import factors as _factors
from ..batch.graph import key_name, noise_whitening
from ..errors import InputError
from ..expressions.kind import KindFactor
from ..expressions.plan import KindRows
from ..expressions.twins import evaluable, twin_row
from ..interop import to_gtsam
from .factor_arrays import FactorKind, NewFactors

#: The types a ``gtsam.Values`` can hold, by their ``at<Type>`` accessors (the common ones first).
COMMON_TYPES = ("Point3", "Point2", "Pose3", "Pose2", "Rot3", "Rot2", "Similarity3", "Similarity2")
VALUE_TYPES = COMMON_TYPES + tuple(sorted(
    n[2:] for n in dir(gtsam.Values) if n.startswith("at") and n[2:3].isupper()
    and n[2:] not in COMMON_TYPES + ("Vector", "Matrix", "Double"))) + ("Vector", "Matrix", "Double")


def value_type(values: gtsam.Values, key: int) -> str:
    """The type name of the value of ``key`` (the first accessor that reads it)."""
    for t in VALUE_TYPES:
        try:
            getattr(values, f"at{t}")(key)
        except (RuntimeError, TypeError, ValueError):
            continue
        return t
    raise InputError(f"key {key_name(key)}: its value has a type the smoother cannot read")


#: The types whose retraction GTSAM defines as the sum x + δ (its vector-space traits), done here
#: without a ``gtsam.Values`` round trip.
VECTOR_SPACE_TYPES = ("Point2", "Point3", "Vector")


def retracted(values: gtsam.Values, key: int, type_name: str, step: np.ndarray):
    """The value of ``key`` in ``values``, a ``type_name`` (:func:`value_type`), moved by ``step``
    as ``gtsam.Values.retract`` moves it: x + δ for a vector space, else GTSAM's retraction."""
    value = getattr(values, f"at{type_name}")(key)
    if type_name in VECTOR_SPACE_TYPES:
        return value + step
    one = gtsam.Values()
    one.insert(key, value)
    vv = gtsam.VectorValues()
    vv.insert(key, np.array(step, dtype=np.float64))
    return getattr(one.retract(vv), f"at{type_name}")(key)


def insert_from(dest: gtsam.Values, src: gtsam.Values, key: int, type_name: str) -> None:
    """Copy the value of ``key``, a ``type_name`` (:func:`value_type`), from ``src`` to ``dest``."""
    dest.insert(key, getattr(src, f"at{type_name}")(key))


def classify(f):
    """(kind, spec, keys, Minv, R, M) for a factor read as arrays, None for one GTSAM keeps."""
    if isinstance(f, _factors.BetweenFactor):
        kind, spec = "between", f.spec
        keys = (f._key1, f._key2)
        nm = f._noise
    elif isinstance(f, _factors.PriorFactor):
        kind, spec = "prior", f.spec
        keys = (f._key2,)
        nm = f._noise
    else:
        nk = len(f.keys()) if isinstance(f, gtsam.NonlinearFactor) else 0
        value = None
        if nk == 2 and hasattr(f, "measured"):
            value, kind = f.measured(), "between"
        elif nk == 1 and hasattr(f, "prior"):
            value, kind = f.prior(), "prior"
        spec = _factors.GROUPS.get(type(value).__name__) if value is not None else None
        if spec is None or type(value) is not spec.cls:
            return None
        keys = tuple(int(k) for k in f.keys())
        nm = f.noiseModel()
        R = noise_whitening(nm)
        if R is None or (kind == "between" and keys[0] == keys[1]):
            return None
        return kind, spec, keys, None, np.asarray(R, dtype=np.float64), spec.matrix(value)
    R = noise_whitening(nm)
    if R is None or (kind == "between" and keys[0] == keys[1]):
        return None
    return kind, spec, keys, f._Minv, np.asarray(R, dtype=np.float64), None


def _read_factors(newFactors: gtsam.NonlinearFactorGraph) -> tuple[dict, list, dict, list, list]:
    """(arrays, native, group_of, native_pos, nulls): the factors read as arrays by (kind,
    group), as lists with their places in the graph; the others with their keys, and their
    places; the group of every key an array factor uses; the places of empty slots."""
    arrays: dict = {}
    native, native_pos, nulls = [], [], []
    group_of: dict[int, str] = {}
    for i in range(newFactors.size()):
        f = newFactors.at(i)
        if f is None:
            nulls.append(i)
            continue
        c = classify(f)
        if c is None:
            if not isinstance(f, gtsam.NonlinearFactor):
                raise InputError(f"factor {i}: unsupported type {type(f).__name__}")
            native.append((f, [int(k) for k in f.keys()]))
            native_pos.append(i)
            continue
        kind, spec, keys, Minv, R, M = c
        for k in keys:
            g = group_of.setdefault(k, spec.name)
            if g != spec.name:
                raise InputError(f"key {key_name(k)} is used by both {g} and {spec.name} factors")
        entry = arrays.setdefault((kind, spec.name), dict(keys=[], Minv=[], R=[], M=[], src=[], pos=[]))
        entry["pos"].append(i)
        entry["keys"].append(keys)
        entry["Minv"].append(Minv)
        entry["R"].append(R)
        entry["M"].append(M)
        entry["src"].append(f)
    return arrays, native, group_of, native_pos, nulls


def _constants(arrays: dict, setup: Callable) -> dict:
    """Each kind's factors as arrays: keys, M⁻¹ (lie_factors' factors carry theirs; GTSAM's are
    set up by ``setup(spec, M, what)``, one call per kind), R, and the factor objects."""
    out = {}
    for (kind, name), entry in arrays.items():
        spec = _factors.GROUPS[name]
        F = len(entry["keys"])
        R = np.array(entry["R"], dtype=np.float64)
        _finite(R, range(F), entry, "noise model")
        need = [q for q in range(F) if entry["Minv"][q] is None]
        if len(need) == F:  # GTSAM's factors only: M⁻¹ in one call
            M = np.array(entry["M"])
            _finite(M, need, entry, "measurement")
            Minv = setup(spec, M, "measurement")
        else:
            Minv = np.empty((F, spec.mat, spec.mat))
            for q in range(F):
                if entry["Minv"][q] is not None:
                    Minv[q] = entry["Minv"][q]
            if need:
                M = np.array([entry["M"][q] for q in need])
                _finite(M, need, entry, "measurement")
                Minv[need] = setup(spec, M, "measurement")
        keys = np.array(entry["keys"], dtype=np.int64).reshape(F, -1)
        out[(kind, name)] = dict(keys=keys, C=Minv, R=R, src=entry["src"], pos=entry["pos"])
    return out


def _finite(A: np.ndarray, which, entry: dict, what: str) -> None:
    """``A`` (one row per factor ``which`` of a kind's ``entry``) is finite, else the error
    names the first factor that is not, by its place in the graph."""
    total = float(A.sum())
    if total - total == 0.0 or np.isfinite(A).all():  # (a NaN or an infinity makes the sum's difference NaN)
        return
    q = list(which)[int(np.flatnonzero(~np.isfinite(A).reshape(len(A), -1).all(axis=1))[0])]
    raise InputError(f"factor {entry['pos'][q]} ({type(entry['src'][q]).__name__}): its {what} is not finite")


def read_update(newFactors, newTheta, setup: Callable) -> NewFactors:
    """ISAM2's ``update(newFactors, newTheta)`` read: factors as arrays where they can be, the
    new variables of a group read as element matrices (their group: that of the array factors
    that use them), every other value kept as GTSAM's (its type found).  ``setup(spec, M,
    what)``: M⁻¹ of measurements ``M``."""
    newFactors = gtsam.NonlinearFactorGraph() if newFactors is None else newFactors
    newTheta = gtsam.Values() if newTheta is None else newTheta
    if not isinstance(newFactors, gtsam.NonlinearFactorGraph):
        raise TypeError(f"newFactors must be a gtsam.NonlinearFactorGraph, got {type(newFactors).__name__}")
    if not isinstance(newTheta, gtsam.Values):
        raise TypeError(f"newTheta must be a gtsam.Values, got {type(newTheta).__name__}")
    arrays, native, group_of, native_pos, nulls = _read_factors(newFactors)
    out = _constants(arrays, setup)
    new_keys = [int(k) for k in newTheta.keys()]
    kinds, values, dims, types = [], [], [], {}
    zero = None
    for k in new_keys:
        name = group_of.get(k)
        if name is not None:
            spec = _factors.GROUPS[name]
            try:
                value = getattr(newTheta, spec.at)(k)
            except RuntimeError:
                raise InputError(f"key {key_name(k)} is used by a {name} factor but its new value is "
                                    f"not a gtsam.{name}") from None
            X = spec.matrix(value)
            if not np.all(np.isfinite(X)):
                raise InputError(f"the new value of key {key_name(k)} is not finite")
            kinds.append(name)
            values.append(X)
            dims.append(spec.dim)
        else:
            if zero is None:
                zero = newTheta.zeroVectors()
            types[k] = value_type(newTheta, k)
            kinds.append(None)
            values.append(None)
            dims.append(int(np.asarray(zero.at(k)).shape[0]))
    return NewFactors(new_keys, kinds, values, dims, out, native, newTheta, types, native_pos, nulls,
                      int(newFactors.size()))


def native_jacobian(f, theta: gtsam.Values) -> np.ndarray:
    """[A | b] of a factor GTSAM linearizes at ``theta`` (rows: a JacobianFactor's, or a square
    root of a HessianFactor's augmented information)."""
    try:
        lf = f.linearize(theta)
    except RuntimeError as exc:
        raise InputError(f"{type(f).__name__} could not be linearized: {str(exc).strip()[:200]}") from None
    if isinstance(lf, gtsam.JacobianFactor):
        if lf.isConstrained():
            raise InputError(f"{type(f).__name__} has a constrained noise model: not supported")
        A, b = lf.jacobian()
        J = np.concatenate([np.asarray(A), np.asarray(b).reshape(-1, 1)], axis=1)
    else:
        M = np.asarray(lf.augmentedInformation())
        w, Q = np.linalg.eigh(M)
        J = np.sqrt(np.clip(w, 0.0, None))[:, None] * Q.T
        J[:, -1] *= 1.0  # [A b]ᵀ[A b] = M: b is the last column
    if not np.all(np.isfinite(J)):
        raise InputError(f"{type(f).__name__} linearized to non-finite numbers")
    return J


class NativeRows:
    """[A | b] of each factor GTSAM would linearize, at ``theta``: a factor kind's, or GTSAM's
    factor with a twin kind (:mod:`lie_factors.expressions.twins`), with a Gaussian noise model
    by the kind's kernel, every factor of a kind in one call
    (:class:`lie_factors.expressions.plan.KindRows`); any other by GTSAM
    (:func:`native_jacobian`).  What each factor is evaluated as is read once per factor object
    (a twin's row: pybind11's accessors and GTSAM's comparison, microseconds a factor), into a
    slot of its kind's rows."""

    def __init__(self):
        self._rows: dict = {}  # id(factor) → (factor, its kind's KindRows or None, its slot)
        self._kinds: dict = {}  # id(kind) → its KindRows
        self._conversions: dict = {}  # the twin readers' converted calibrations
        self._whitening: dict = {}  # id(noise model) → (noise model, R or None): factors share them

    def __call__(self, factors: list, theta: gtsam.Values) -> list:
        """[(positions (F,), [A | b] (F, r, c)), ...]: the rows of ``factors`` (their positions
        in the list), a chunk per kind and one per factor GTSAM linearizes; the column blocks
        of A in the order of :meth:`keys`."""
        out: list = []
        by_kind: dict = {}
        for q, f in enumerate(factors):
            entry = self._entry(f)
            if entry[1] is None:
                out.append((np.array([q], dtype=np.int64), native_jacobian(f, theta)[None]))
            else:
                positions, slots = by_kind.setdefault(entry[1], ([], []))
                positions.append(q)
                slots.append(entry[2])
        for rows, (positions, slots) in by_kind.items():
            out.append((np.array(positions, dtype=np.int64), rows.rows(np.array(slots, dtype=np.int64), theta)))
        return out

    def keys(self, f) -> list:
        """The keys of ``f`` in the order of its rows' column blocks: its kind's variable order
        (a twin's may differ from GTSAM's, as GeneralSFMFactor2's), else ``f.keys()``."""
        entry = self._entry(f)
        return [int(k) for k in (f.keys() if entry[1] is None else entry[1].keys[entry[2]].tolist())]

    def _entry(self, f) -> tuple:
        entry = self._rows.get(id(f))
        if entry is None or entry[0] is not f:  # (the entry holds f: its id is not reused)
            entry = self._rows[id(f)] = (f, *self._slot(f))
        return entry

    def _slot(self, f) -> tuple:
        """(the KindRows evaluating ``f``, its slot there), or (None, None) where GTSAM must."""
        if isinstance(f, KindFactor):
            row, nm = f, f.noiseModel()
        else:
            read = twin_row(f, self._conversions)
            if read is None:
                return None, None
            row, nm = read
        w = self._whitening.get(id(nm))
        if w is None or w[0] is not nm:
            R = noise_whitening(nm)
            w = self._whitening[id(nm)] = (nm, None if R is None else np.ascontiguousarray(R, dtype=np.float64))
        if w[1] is None or not evaluable(row, w[1]):
            return None, None
        rows = self._kinds.get(id(row.kind))
        if rows is None:  # (the KindRows holds the kind: its id stays its own)
            rows = self._kinds[id(row.kind)] = KindRows(row.kind)
        return rows, rows.add(row, w[1])


def make_factor(store: FactorKind, local: int, keys: list):
    """GTSAM's ``BetweenFactor``/``PriorFactor`` (``noiseModel.Gaussian.Information``) of entry
    ``local`` of ``store``; ``keys``: the smoother's keys by variable index."""
    spec = store.spec
    M = to_gtsam(spec.name, np.linalg.inv(store.C[local]))
    R = store.R[local]
    model = gtsam.noiseModel.Gaussian.Information(R.T @ R)
    factor_keys = [keys[v] for v in store.v[local].tolist()]
    cls = getattr(gtsam, f"{'BetweenFactor' if store.kind == 'between' else 'PriorFactor'}{spec.name}")
    return cls(*factor_keys, M, model)


def typed_estimate(type_name: str):
    """ISAM2's ``calculateEstimate<type_name>(key)``: the estimate of ``key``, refused when it is
    not a ``type_name``."""
    def typed(self, key):
        value = self.calculateEstimate(key)
        if type(value).__name__ == type_name or (isinstance(value, np.ndarray) and (
                type_name in ("Vector", "Matrix") or type_name == f"Point{value.shape[0]}")):
            return value
        raise InputError(f"key {key_name(int(key))} holds a {type(value).__name__}, not a {type_name}")

    typed.__name__ = typed.__qualname__ = f"calculateEstimate{type_name}"
    typed.__doc__ = f"The estimate of ``key``, a ``gtsam.{type_name}`` (ISAM2's typed form)."
    return typed
