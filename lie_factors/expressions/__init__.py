"""Factors written as residuals in Lie-group operations, with exact Jacobians by the chain rule.

``lf.factor`` (:func:`~lie_factors.expressions.kind.factor`) turns a residual function into a
GTSAM factor class whose factors evaluate in one compiled call, and which the batch solver
evaluates a whole kind at a time.  The vocabulary: :class:`~lie_factors.expressions.expr.Expr`'s
methods and :mod:`lie_factors.expressions.ops`; the types: :mod:`lie_factors.expressions.types`;
ready factors written with it: :mod:`lie_factors.expressions.ready`.  docs/factors.md derives
each operation's Jacobian.
"""

from . import ops
from .kind import Kind, KindFactor, factor
from .types import ValueType, value_type, vector

__all__ = ["factor", "Kind", "KindFactor", "ops", "ValueType", "value_type", "vector"]
