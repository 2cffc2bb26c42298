"""Small statistics the acceptance tests need, without SciPy (an optional extra here).

chi2_sf is the regularised upper incomplete gamma Q(dof/2, x/2), by its power series below
a+1 and Lentz's continued fraction above (Numerical Recipes' split); accurate to ~1e-12,
which is far more than a p < 0.01 decision needs.
"""

from __future__ import annotations

import math


def _gamma_p_series(a: float, x: float) -> float:
    term = total = 1.0 / a
    ap = a
    for _ in range(10_000):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * 1e-15:
            break
    return total * math.exp(-x + a * math.log(x) - math.lgamma(a))


def _gamma_q_fraction(a: float, x: float) -> float:
    tiny = 1e-300
    b = x + 1.0 - a
    c = 1.0 / tiny
    d = 1.0 / b
    h = d
    for i in range(1, 10_000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        step = d * c
        h *= step
        if abs(step - 1.0) < 1e-15:
            break
    return math.exp(-x + a * math.log(x) - math.lgamma(a)) * h


def chi2_sf(x: float, dof: float) -> float:
    """P(X >= x) for X ~ chi-squared with `dof` degrees of freedom."""
    if dof <= 0:
        raise ValueError(f"chi-squared needs dof > 0, got {dof}")
    if x <= 0:
        return 1.0
    a, hx = 0.5 * dof, 0.5 * x
    if hx < a + 1.0:
        return max(0.0, 1.0 - _gamma_p_series(a, hx))
    return _gamma_q_fraction(a, hx)
