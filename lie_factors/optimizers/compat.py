"""GTSAM's functions that look for GTSAM's own factor classes, made to accept ours.

Several GTSAM functions pick factors out of a graph by their C++ class
(``dynamic_pointer_cast<BetweenFactor<Pose3>>``) and pass over anything else
without a word.  Our factors are ``CustomFactor``\\ s, so on a graph of ours:

* ``gtsam.writeG2o`` and ``gtsam.save2D`` write the vertices and no edge at all;
* ``gtsam.InitializePose3.initialize`` and ``gtsam.lago.initialize`` return
  an empty ``Values`` for a graph of ours, and fail on GTSAM's edges with our
  prior (GTSAM's examples with the prior swapped): "Indeterminate linear
  system" and ``IndexError: map::at``;
* ``gtsam.fastSyncPose3`` and its siblings raise "FastSync requires at least one
  between measurement";
* ``gtsam.ShonanAveraging2``/``3``, constructed from a list of Between factors,
  refuse ours (a list of GTSAM's classes is what the wrapper converts).

The same-named functions and classes here take the same arguments.  They hand
GTSAM a copy of the graph (or list) in which each of our factors is replaced by
GTSAM's own class with the same keys, the same measured value and the *same
noise model object* (:func:`to_gtsam_graph`); GTSAM's own factors, and any other
factor, are passed as they are.  GTSAM then does all the work, so the results
are GTSAM's on that graph, bit for bit, and so are the exceptions.

:func:`writeG2o` in addition never drops anything silently: a factor or a
value GTSAM's writer would pass over raises :class:`G2oWriteError`, and
nothing is written (see its docstring for what GTSAM writes).

GTSAM's readers (``readG2o``, ``load2D``, ``load3D``, ``parse2DFactors``,
``parse3DFactors``) here return our factors, so a script that reads a file and
optimizes it runs our factors after the import change.

:data:`GTSAM_NAMES` lists every name of ``gtsam`` this module replaces.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from types import SimpleNamespace

from gtsam import gtsam  # the compiled extension: GTSAM's own classes, whatever is assigned into the package

from ..errors import InputError
from ..kernels.registry import BY_GTSAM

_OURS = "lie_factors.factors"
_READY = "lie_factors.expressions.ready"
_tables: dict = {}
_ready_table: list = []


def _table(direction: str) -> dict:
    """GTSAM's class for each of ours (``"to"``), or ours for each of GTSAM's (``"from"``).

    Built on first use: importing lie_factors.factors imports numba, which
    compat itself does not need for graphs of GTSAM's own factors.
    """
    if not _tables:
        from .. import factors

        _tables["to"] = {getattr(factors, name): getattr(gtsam, name) for name in factors.__all__
                         if name.startswith(("BetweenFactor", "PriorFactor"))}
        _tables["from"] = {native: ours for ours, native in _tables["to"].items()}
    return _tables[direction]


def _ours_exist() -> bool:
    # No factor of ours can exist before lie_factors.factors is imported.
    return _OURS in sys.modules


def to_gtsam(factor):
    """GTSAM's own factor for one of lie_factors.factors' or one of the ready factors equal to
    GTSAM's (:mod:`lie_factors.expressions.ready`: bearing-range, range, GPS); any other factor
    is returned as is.

    Same keys, same measured (or prior) value, and the same noise model object
    (a robust model stays robust), so GTSAM's factor has the same error.
    """
    if _ours_exist() and type(factor) in _table("to"):
        return factor.as_gtsam()
    if _ready_exist() and type(factor) in _ready_types():
        return factor.as_gtsam()
    return factor


def _ready_exist() -> bool:
    # No ready factor can exist before lie_factors.expressions.ready is imported.
    return _READY in sys.modules


def _ready_types() -> frozenset:
    """The ready factors with GTSAM's own class of the same name, which ``as_gtsam()`` builds."""
    if not _ready_table:
        from ..expressions import ready

        _ready_table.append(frozenset(cls for cls in vars(ready).values()
                                      if isinstance(cls, type) and "as_gtsam" in vars(cls)))
    return _ready_table[0]


def from_gtsam(factor):
    """lie_factors.factors' factor for one of GTSAM's Between/Prior factors on
    Rot3/Pose2/Pose3/Similarity2/Similarity3 (any other factor is returned as is).

    Same keys, same measured (or prior) value, same noise model object.
    """
    cls = _table("from").get(type(factor))
    if cls is None:
        return factor
    keys = list(factor.keys())
    if len(keys) == 2:
        return cls(keys[0], keys[1], factor.measured(), factor.noiseModel())
    return cls(keys[0], factor.prior(), factor.noiseModel())


def _mapped(graph, convert, table: dict):
    """``graph`` with ``convert`` applied to each factor whose class is in ``table``.

    The graph itself if there is none (no copy); else a new graph, factor
    order kept, removed (null) slots left out.  Anything that is not a
    NonlinearFactorGraph is returned as is, for GTSAM to reject with its own
    exception.
    """
    if not isinstance(graph, gtsam.NonlinearFactorGraph):
        return graph
    n = graph.size()
    factors = [graph.at(k) for k in range(n)]
    if not any(type(f) in table for f in factors):
        return graph
    out = gtsam.NonlinearFactorGraph()
    for f in factors:
        if f is not None:
            out.add(convert(f))
    return out


def to_gtsam_graph(graph: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
    """``graph`` with each of our factors replaced by GTSAM's own class (:func:`to_gtsam`).

    Returns ``graph`` itself when it holds none of ours.
    """
    if not (_ours_exist() or _ready_exist()) or not isinstance(graph, gtsam.NonlinearFactorGraph):
        return graph
    table = set(_table("to")) if _ours_exist() else set()
    return _mapped(graph, to_gtsam, table | (_ready_types() if _ready_exist() else set()))


def from_gtsam_graph(graph: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
    """``graph`` with each of GTSAM's Between/Prior factors replaced by ours (:func:`from_gtsam`)."""
    return _mapped(graph, from_gtsam, _table("from"))


# --------------------------------------------------------------------------- #
# g2o files
# --------------------------------------------------------------------------- #

class G2oWriteError(InputError):
    """:func:`writeG2o` cannot write a factor or a value, or a robust noise model.

    An :class:`~lie_factors.errors.InputError`, so a ``ValueError``: the class GTSAM's own
    writer raises for a noise model it cannot write.
    """


def _writes_edge(factor, cache: dict) -> bool:
    """Whether GTSAM's own writeG2o writes an edge for ``factor``'s class.

    Asked of GTSAM itself, once per class and call: the factor alone is
    written to a scratch file with no values, and anything but a header
    (PARAMS_*) line is its edge.  This follows the installed GTSAM (4.3.0
    writes BetweenFactorPose2/Pose3 and BearingRangeFactor3D; 4.2 only the
    first two) instead of a list that could fall behind it.
    """
    cls = type(factor)
    if cls not in cache:
        one = gtsam.NonlinearFactorGraph()
        one.add(factor)
        fd, path = tempfile.mkstemp(suffix=".g2o")
        os.close(fd)
        try:
            gtsam.writeG2o(one, gtsam.Values(), path)
            with open(path) as fh:
                cache[cls] = any(line.strip() and not line.startswith("PARAMS") for line in fh)
        except ValueError:
            # GTSAM refuses this very factor (noise models are checked before,
            # so something else about it): the class is one it writes, and the
            # real write raises the same error.
            cache[cls] = True
        finally:
            os.unlink(path)
    return cache[cls]


def _describe(factor, k: int) -> str:
    keys = ", ".join(gtsam.DefaultKeyFormatter(key) for key in factor.keys())
    return f"factor {k} ({type(factor).__name__} on {keys})"


def _check_noise(factor, k: int) -> None:
    model = factor.noiseModel() if hasattr(factor, "noiseModel") else None
    if model is not None and not isinstance(model, gtsam.noiseModel.Gaussian):
        kind = type(model).__name__
        raise G2oWriteError(
            f"writeG2o: {_describe(factor, k)} has a {kind} noise model; a g2o edge holds an "
            "information matrix only, so its kernel would be lost (write the graph read "
            "without a kernel, or one with the robust models' noise())")


def _is_pose(values: gtsam.Values, key: int) -> bool:
    for at in (values.atPose2, values.atPose3):
        try:
            at(key)
            return True
        except RuntimeError:
            pass
    return False


def _check_written(path: str, graph: gtsam.NonlinearFactorGraph, estimate: gtsam.Values) -> None:
    """Every factor and every value of ``graph``/``estimate`` has its line in the file at ``path``."""
    vertices = edges = 0
    with open(path) as fh:
        for line in fh:
            if line.startswith("VERTEX"):
                vertices += 1
            elif line.strip() and not line.startswith("PARAMS"):
                edges += 1
    missing = estimate.size() - vertices
    if missing:
        # Which ones, as far as Python can tell: Values.atPoint3 also reads a
        # 3-vector inserted as a plain numpy array (a Vector, which GTSAM's
        # writer passes over), so name every value that is not a pose.
        others = [gtsam.DefaultKeyFormatter(k) for k in estimate.keys() if not _is_pose(estimate, k)]
        raise G2oWriteError(
            f"writeG2o: {missing} of the {estimate.size()} values have no g2o vertex type and would "
            "be left out of the file (GTSAM writes Pose2, Pose3, Point2 and Point3 values; a numpy "
            "array given to Values.insert is a Vector, Values.insertPoint3 makes a Point3); the "
            f"values that are not poses: {', '.join(others[:10])}{' ...' if len(others) > 10 else ''}")
    factors = sum(graph.at(k) is not None for k in range(graph.size()))
    if edges != factors:  # every class was checked to write its edge: this is GTSAM's doing
        raise G2oWriteError(f"writeG2o: GTSAM wrote {edges} edges for {factors} factors")


def writeG2o(graph: gtsam.NonlinearFactorGraph, estimate: gtsam.Values, filename: str) -> None:
    """Write ``graph`` and ``estimate`` to a g2o file, as ``gtsam.writeG2o`` does, with our factors.

    Our factors are written as GTSAM's own classes with the same measured
    value and noise model (:func:`to_gtsam`), so the file is the one GTSAM
    writes for its own factors.  Nothing is dropped silently: GTSAM's writer
    passes over every factor it has no g2o edge for (priors, factors on other
    types, a user's CustomFactor, ...) and every value that is not a Pose2,
    Pose3, Point2 or Point3; here any of those raises :class:`G2oWriteError`
    (a ValueError) naming it, and so does a robust noise model (GTSAM raises
    ValueError for it too, after printing it).  Remove what cannot be written
    (e.g. build the graph without its prior) to write the rest.

    GTSAM writes to a scratch file, which is copied to ``filename`` only once
    every factor and value is found in it; so a refusal leaves no file (GTSAM's
    own writer leaves a partial one), and a directory that does not exist
    raises (GTSAM's writes nothing, silently).  Keys are written as
    ``Symbol(key).index()``, as GTSAM does.
    """
    native = to_gtsam_graph(graph)
    if not (isinstance(native, gtsam.NonlinearFactorGraph) and isinstance(estimate, gtsam.Values)):
        gtsam.writeG2o(native, estimate, filename)  # GTSAM's TypeError for the wrong arguments
        return
    cache: dict = {}
    for k in range(native.size()):
        f = native.at(k)
        if f is None:
            continue
        _check_noise(f, k)  # first: GTSAM's writer prints a model it refuses
        if not _writes_edge(f, cache):
            raise G2oWriteError(
                f"writeG2o: {_describe(f, k)} has no g2o edge type; GTSAM's writer would "
                "leave it out of the file")
    fd, scratch = tempfile.mkstemp(suffix=".g2o")
    os.close(fd)
    try:
        gtsam.writeG2o(native, estimate, scratch)
        _check_written(scratch, native, estimate)
        shutil.copyfile(scratch, os.fspath(filename))
    finally:
        os.unlink(scratch)


# --------------------------------------------------------------------------- #
# GTSAM's other functions and classes that pick factors by class
# --------------------------------------------------------------------------- #

def _native_argument(arg):
    """``arg`` as GTSAM's functions take it: a factor graph (:func:`to_gtsam_graph`) or a list
    of factors (``ShonanAveraging2(factors, parameters)``) with our factors as GTSAM's own
    classes; anything else as it is."""
    if isinstance(arg, gtsam.NonlinearFactorGraph):
        return to_gtsam_graph(arg)
    if isinstance(arg, (list, tuple)) and _ours_exist():
        native = [to_gtsam(a) for a in arg]
        if any(n is not a for n, a in zip(native, arg)):
            return native
    return arg


def _ours_in(result):
    """``result`` of one of GTSAM's readers with its Between factors as ours: a graph
    (:func:`from_gtsam_graph`), a list of factors, or a tuple of those (``(graph, initial)``)."""
    if isinstance(result, gtsam.NonlinearFactorGraph):
        return from_gtsam_graph(result)
    if isinstance(result, tuple):
        return tuple(_ours_in(r) for r in result)
    if isinstance(result, list):
        return [from_gtsam(f) for f in result]
    return result


def _native_arguments(args, kwargs) -> tuple[list, dict]:
    """``args`` and ``kwargs`` with each argument as GTSAM takes it (:func:`_native_argument`)."""
    return [_native_argument(a) for a in args], {k: _native_argument(v) for k, v in kwargs.items()}


def _wrapped(function, name: str, reader: bool = False):
    """GTSAM's ``function`` taking our factors; a ``reader`` also returns ours (:func:`_ours_in`)."""

    def call(*args, **kwargs):
        args, kwargs = _native_arguments(args, kwargs)
        result = function(*args, **kwargs)
        return _ours_in(result) if reader else result

    call.__name__ = call.__qualname__ = name.rsplit(".", 1)[-1]
    call.__module__ = __name__
    what = ("returning lie_factors' factors in place of GTSAM's Between factors on Rot3, Pose2, Pose3, "
            "Similarity2, Similarity3 (same keys, measured value and noise model object, :func:`from_gtsam`)"
            if reader else
            "taking lie_factors' factors in a graph or a list, handed to GTSAM as its own classes "
            "(:func:`to_gtsam`), which it picks out by their C++ class")
    call.__doc__ = (f"``gtsam.{name}`` {what}; everything else GTSAM's, exceptions included.\n\n"
                    "GTSAM's signature::\n\n    " + (function.__doc__ or "").strip().replace("\n", "\n    "))
    return call


#: GTSAM's readers of g2o/TORO files, returning our factors: a script that reads a file
#: and optimizes it runs our factors after the import change.
_READERS = ("readG2o", "load2D", "load3D", "parse2DFactors", "parse3DFactors")

#: GTSAM's functions that take a graph and pick its factors by C++ class (``writeG2o``,
#: which never drops a factor silently, is above): save2D, the fastSync solvers of our groups.
_TAKERS = ("save2D", *(f"fastSync{g}" for g in BY_GTSAM))

#: GTSAM's classes whose constructors take a list of its Between factors.
_CLASSES = ("ShonanAveraging2", "ShonanAveraging3")


def _class_accepting(cls):
    """A subclass of GTSAM's ``cls`` whose constructor takes our factors where it takes GTSAM's."""

    def __init__(self, *args, **kwargs):
        args, kwargs = _native_arguments(args, kwargs)
        cls.__init__(self, *args, **kwargs)

    doc = (f"``gtsam.{cls.__name__}``, whose constructor also takes lie_factors' factors in its "
           "list of Between factors (handed to GTSAM as its own classes, :func:`to_gtsam`).")
    return type(cls.__name__, (cls,), {"__init__": __init__, "__doc__": doc, "__module__": __name__})


for _name in _READERS + _TAKERS:
    if hasattr(gtsam, _name):
        globals()[_name] = _wrapped(getattr(gtsam, _name), _name, reader=_name in _READERS)
for _name in _CLASSES:
    if hasattr(gtsam, _name):
        globals()[_name] = _class_accepting(getattr(gtsam, _name))


class InitializePose3:
    """``gtsam.InitializePose3`` on graphs of our factors (converted by :func:`to_gtsam_graph`).

    The same static methods (``initialize``, ``initializeOrientations``,
    ``buildPose3graph``, ``computeOrientationsChordal``, ``computeOrientationsGradient``),
    arguments, results and exceptions as GTSAM's; only the factor graphs are converted.
    Factors GTSAM's initializer does not use (landmarks, other types, a user's
    CustomFactor) it ignores, as in a graph of its own factors; a robust noise model is
    handed over as it is (GTSAM's factor with the same model), so GTSAM does with it
    what it does with its own.
    """


#: ``gtsam.lago`` on graphs of our factors (``lago.initialize``, ``lago.initializeOrientations``),
#: as :class:`InitializePose3` (GTSAM raises ValueError for a noise model that is not diagonal).
lago = SimpleNamespace(
    __name__="lie_factors.optimizers.compat.lago",
    __doc__="gtsam.lago's functions on graphs of lie_factors' factors (converted to GTSAM's classes).",
)

for _ours, _native, _prefix in ((InitializePose3, gtsam.InitializePose3, "InitializePose3."),
                                (lago, gtsam.lago, "lago.")):
    for _name in dir(_native):
        if not _name.startswith("_") and callable(getattr(_native, _name)):
            _function = _wrapped(getattr(_native, _name), _prefix + _name)
            setattr(_ours, _name, staticmethod(_function) if isinstance(_ours, type) else _function)

#: The names of ``gtsam`` that this module replaces (:mod:`lie_factors.dropin` puts them in place).
GTSAM_NAMES = ("writeG2o", "InitializePose3", "lago",
               *(n for n in (*_READERS, *_TAKERS, *_CLASSES) if hasattr(gtsam, n)))

__all__ = ["G2oWriteError", "GTSAM_NAMES", "from_gtsam", "from_gtsam_graph", "to_gtsam", "to_gtsam_graph",
           *GTSAM_NAMES]

del _name, _ours, _native, _prefix, _function
