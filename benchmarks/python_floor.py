"""What any solver written in Python pays to take GTSAM's objects in and give a ``gtsam.Values`` out.

Before it computes anything, a Python library handed a ``gtsam.NonlinearFactorGraph`` and a
``gtsam.Values`` reads each factor's data through GTSAM's accessors (pybind11 calls of 0.1–0.4 µs
each: ``keys()``, the measurement or prior, ``noiseModel().R()``, ``calibration()`` where the
factor has one) and each value as an array; what it returns as GTSAM's ``Values`` it builds a
variable at a time (each GTSAM object made, then inserted).  These functions do exactly that and
nothing else; the benchmarks time them beside GTSAM's own solver on the same calls
(``small_problems.py``, ``smoother_clients.py``): the floor under ``lf.optimize`` and
``lf.Smoother``.

A value's type is found once per key, untimed (:func:`value_types`).
"""

from __future__ import annotations

import gtsam
import numpy as np

#: factor class → the accessors of its data (besides keys and noise model) it has
_ACCESSORS: dict = {}


def as_array(x):
    """A GTSAM value or measurement as the array(s) a kernel would take."""
    if hasattr(x, "matrix"):
        return x.matrix()
    if hasattr(x, "pose") and hasattr(x, "calibration"):  # a camera
        return x.pose().matrix(), as_array(x.calibration())
    if hasattr(x, "k1") and hasattr(x, "px"):  # Cal3Bundler: its constructor's arguments
        return np.array([x.fx(), x.k1(), x.k2(), x.px(), x.py()])
    if hasattr(x, "bearing"):  # a BearingRange
        return as_array(x.bearing()), x.range()
    if hasattr(x, "point3"):  # a Unit3
        return x.point3()
    if hasattr(x, "vector"):
        return x.vector()
    return np.asarray(x)


def value_types(values: gtsam.Values) -> dict:
    """key → the name of its value's GTSAM type (untimed set-up)."""
    from lie_factors.incremental.gtsam_objects import value_type

    return {int(k): value_type(values, int(k)) for k in values.keys()}


def read_factors(graph: gtsam.NonlinearFactorGraph) -> None:
    """Each factor's keys, noise model's R and data, read through GTSAM's accessors."""
    for i in range(graph.size()):
        f = graph.at(i)
        if f is None:
            continue
        f.keys()
        nm = f.noiseModel()
        if hasattr(nm, "R"):
            nm.R()
        accessors = _ACCESSORS.get(type(f))
        if accessors is None:
            accessors = _ACCESSORS[type(f)] = [a for a in ("measured", "prior", "calibration") if hasattr(f, a)]
        for accessor in accessors:
            as_array(getattr(f, accessor)())


def read_values(values: gtsam.Values, types: dict, into: dict) -> None:
    """Each value of ``values`` as an array, into ``into``: key → (type name, array)."""
    for k in values.keys():
        t = types[int(k)]
        into[int(k)] = (t, as_array(getattr(values, f"at{t}")(k)))


def gtsam_object(type_name: str, a):
    """GTSAM's object of type ``type_name`` from its array ``a`` (a vector type: the array)."""
    if type_name in ("Point2", "Point3", "Vector"):
        return a
    if type_name == "Pose2":
        return gtsam.Pose2(gtsam.Rot2.atan2(a[1, 0], a[0, 0]), a[:2, 2])
    if type_name == "Rot2":
        return gtsam.Rot2.atan2(a[1, 0], a[0, 0])
    if type_name.startswith("PinholeCamera"):
        return getattr(gtsam, type_name)(gtsam.Pose3(a[0]), getattr(gtsam, type_name[len("PinholeCamera"):])(*a[1]))
    if type_name.startswith("Cal3"):
        return getattr(gtsam, type_name)(*a)
    return getattr(gtsam, type_name)(a)


def build_values(known: dict) -> gtsam.Values:
    """A ``gtsam.Values`` of every variable in ``known`` (key → (type name, array))."""
    out = gtsam.Values()
    for k, (t, a) in known.items():
        out.insert(k, gtsam_object(t, a))
    return out
