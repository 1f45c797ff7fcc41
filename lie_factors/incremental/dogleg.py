"""ISAM2's Dogleg steps (``ISAM2DoglegParams``, ``ISAM2DoglegLineSearchParams``) on the smoother's factor.

With Dogleg parameters ISAM2 keeps two steps: the Gauss–Newton step
``dx_n`` of its Bayes tree, brought up to date by wildfire back-substitution
as the Gauss–Newton smoother's δ is, and the step δ it reports and
relinearizes with: the dogleg point between the steepest-descent point
``dx_u = −(gᵀg / ‖R g‖²) g`` (g = −Rᵀd, the gradient at zero of the
conditionals' error ½‖R x − d‖²) and ``dx_n``, inside a trust region whose
radius Δ carries over from one update to the next (``initialDelta`` at first).
One Dogleg iteration (:func:`lie_factors.dogleg.iterate`, in the parameters'
adaptation mode) runs each time δ is brought up to date: its model M is the
conditionals' error, its f the error of every factor at θ ⊕ step
(``ISAM2::updateDelta``).  With line-search parameters, the radius is searched
outward along the dogleg path instead (:func:`lie_factors.dogleg.line_search`)
and does not carry over.  Each f costs one pass over the factors.
"""

from __future__ import annotations

import numpy as np

from .. import dogleg


def dogleg_step(s, delta: float) -> tuple[np.ndarray, float]:
    """(the step δ, (nscalar,) or longer, and the new trust-region radius) of the smoother ``s``
    from its factor's Gauss–Newton step ``s.bf.delta`` (module docstring)."""
    bf = s.bf
    n = bf.nscalar
    dx_n = bf.delta[:n]
    g = bf.gradient_at_zero()
    rg = bf.r_squared(g)
    gg = float(g @ g)
    dx_u = (-gg / rg) * g if rg > 0 else np.zeros(n)
    graph = s.getFactorsUnsafe()
    out = np.zeros(bf.delta.shape[0])

    def point(a: float, b: float) -> np.ndarray:
        if b == 0.0:
            return a * dx_u
        return dx_n.copy() if a == 0.0 else a * dx_u + b * dx_n

    def evaluate(a: float, b: float) -> tuple[float, float, float]:
        out[:n] = point(a, b)
        return (float(graph.error(s._estimate(out))), m_error - bf.conditional_error(out[:n]),
                float(np.linalg.norm(out[:n])))

    out[:n] = 0.0
    f_error = float(graph.error(s._estimate(out)))
    m_error = bf.conditional_error(out[:n])
    p = s.smoother_params
    norms = (float(dx_u @ dx_u), float(dx_n @ dx_n), float(dx_u @ dx_n))
    if p.optimizer == "Dogleg":
        a, b, _, delta = dogleg.iterate(delta, p.adaptationMode, norms, evaluate, f_error, m_error)
    else:
        a, b, _, delta = dogleg.line_search(norms, evaluate, f_error, p.minDelta, p.maxDelta, p.stepSize,
                                            p.sufficientDecreaseCoeff)
    out[:n] = point(a, b) if (a, b) != (0.0, 0.0) else 0.0
    return out, delta
