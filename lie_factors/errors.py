"""The exceptions lie_factors raises: one root, so that ``except lie_factors.LieFactorsError`` catches
every failure the library reports on purpose (the command line maps them to exit status 2).

- :class:`InputError` (also a ``ValueError``): bad input — a malformed file, arrays of
  the wrong shape or values, an unknown option, key or backend. Its message is one
  line naming what was expected.
- :class:`InitializationError`: an initializer cannot run on this graph.
- :class:`ArgumentTypeError` (also a ``TypeError``, what GTSAM's wrapper raises for these): an
  argument of the wrong kind, such as a key that is not a non-negative integer.
- :class:`EvaluationError` (also a ``RuntimeError``, what GTSAM raises for these): a factor
  cannot be evaluated at the values it is given; :class:`ValuesKeyDoesNotExist`,
  :class:`ValuesIncorrectType` (also a ``TypeError``) and :class:`CheiralityException` are
  GTSAM's names for the cases it has.
- :class:`NotPositiveDefinite` (also a ``numpy.linalg.LinAlgError``): a matrix that must be
  positive definite is not, numerically; :class:`IndeterminantLinearSystem`, GTSAM's name
  for it, when the graph does not determine every variable.
"""

from __future__ import annotations

import numpy as np

__all__ = ["LieFactorsError", "InputError", "InitializationError", "ArgumentTypeError", "EvaluationError",
           "ValuesKeyDoesNotExist", "ValuesIncorrectType", "CheiralityException", "NotPositiveDefinite",
           "IndeterminantLinearSystem", "first_line", "gtsam_failure", "nonfinite_error"]


class LieFactorsError(Exception):
    """Root of every exception lie_factors raises on purpose."""


class InputError(LieFactorsError, ValueError):
    """Bad input (file, arrays, option, key, backend): one line naming what was expected."""


class InitializationError(InputError):
    """An initializer cannot run on this graph; the message is the one-line reason."""


class ArgumentTypeError(LieFactorsError, TypeError):
    """An argument of the wrong kind or number, where GTSAM's wrapper raises a ``TypeError``: a key
    that is not a non-negative integer, a noise model that is not one, a factor constructed with
    arguments that fit none of GTSAM's signatures."""


class EvaluationError(LieFactorsError, RuntimeError):
    """A factor cannot be evaluated at the values it is given, where GTSAM raises a
    ``RuntimeError``: a division by zero, a residual that is not finite, a derivative that is
    undefined there; the subclasses are GTSAM's named cases."""


class ValuesKeyDoesNotExist(EvaluationError):
    """A factor's key is missing from the ``Values`` it is evaluated at (GTSAM's
    ``ValuesKeyDoesNotExist``)."""


class ValuesIncorrectType(EvaluationError, TypeError):
    """A factor's key holds a value of another type than the factor reads (GTSAM's
    ``ValuesIncorrectType``)."""


class CheiralityException(EvaluationError):
    """A point projected by a camera it is not in front of (depth ≤ 0): GTSAM's
    ``CheiralityException``."""


class NotPositiveDefinite(LieFactorsError, np.linalg.LinAlgError):
    """A matrix that must be positive definite is not, numerically.

    ``column``: the column of the matrix, as factored, where it showed (None if unknown).
    """

    def __init__(self, message: str, column: int | None = None):
        super().__init__(message)
        self.column = column


class IndeterminantLinearSystem(NotPositiveDefinite):
    """The linear system does not determine every variable (GTSAM's
    ``IndeterminantLinearSystemException``): no prior fixes the gauge, or a variable is not
    constrained by the factors so far.

    ``variable``: the index of a variable near where it showed (GTSAM's ``nearbyVariable``), or None.
    """

    def __init__(self, message: str, variable: int | None = None):
        super().__init__(message)
        self.variable = variable


def first_line(exc: BaseException, limit: int = 200) -> str:
    """The first line of ``exc``'s message, at most ``limit`` characters (its type's name if empty):
    what a one-line report of a failure from GTSAM or numpy shows."""
    text = str(exc).strip()
    return text.splitlines()[0][:limit] if text else type(exc).__name__


def gtsam_failure(exc: BaseException, what: str = "optimization failed") -> LieFactorsError:
    """The exception to raise for a ``RuntimeError`` GTSAM's C++ threw: its indeterminate-system
    exception as :class:`IndeterminantLinearSystem`, anything else as :class:`InputError` (the
    graph or its values are not what GTSAM can work with); ``what: <first line>``."""
    text = f"{what}: {first_line(exc)}"
    if "ndetermin" in str(exc):
        return IndeterminantLinearSystem(text)
    return InputError(text)


def nonfinite_error(when: str, errors: np.ndarray, describe) -> InputError:
    """The refusal of a graph error that is not a finite number ``when`` (``at the initial
    values``, ``after Gauss-Newton step 3``), naming the first factor whose error is not:
    ``errors`` (F,) every factor's error, ``describe(k)`` factor k's name (`` (Type on x1, l2)``)."""
    bad = np.flatnonzero(~np.isfinite(np.asarray(errors, dtype=np.float64)))
    if not bad.size:
        return InputError(f"the graph's error {when} is not a finite number")
    k = int(bad[0])
    more = f", and {bad.size - 1} more factors" if bad.size > 1 else ""
    return InputError(f"the graph's error {when} is not a finite number: factor {k}{describe(k)} has error "
                      f"{float(errors[k])}{more}")
