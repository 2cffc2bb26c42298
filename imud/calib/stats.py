"""Small statistics the acceptance tests need, without SciPy (an optional extra here).

chi2_sf is the regularised upper incomplete gamma Q(dof/2, x/2) (imud.noise.chi2.gamma_pq:
its power series below a+1 and Lentz's continued fraction above, Numerical Recipes' split);
accurate to ~1e-12, which is far more than a p < 0.01 decision needs. t_sf_two_sided is the
regularised incomplete beta I_x(dof/2, 1/2) with x = dof / (dof + t^2), by its continued
fraction (Lentz again, evaluated on the side where it converges fast).
"""

from __future__ import annotations

import math

from imud.noise.chi2 import gamma_pq


def chi2_sf(x: float, dof: float) -> float:
    """P(X >= x) for X ~ chi-squared with `dof` degrees of freedom."""
    if dof <= 0:
        raise ValueError(f"chi-squared needs dof > 0, got {dof}")
    if x <= 0:
        return 1.0
    return gamma_pq(0.5 * dof, 0.5 * x)[1]


def _beta_fraction(a: float, b: float, x: float) -> float:
    """The continued fraction of I_x(a, b) (its even and odd terms), Lentz's method."""
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (tiny if abs(d) < tiny else d)
    h = d
    for m in range(1, 10_000):
        for num in (
            m * (b - m) * x / ((a + 2 * m - 1.0) * (a + 2 * m)),
            -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1.0)),
        ):
            d = 1.0 + num * d
            d = 1.0 / (tiny if abs(d) < tiny else d)
            c = 1.0 + num / c
            c = tiny if abs(c) < tiny else c
            h *= d * c
        if abs(d * c - 1.0) < 1e-15:
            break
    return h


def _beta_inc(a: float, b: float, x: float) -> float:
    """Regularised incomplete beta I_x(a, b), 0 <= x <= 1."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    front = math.exp(
        math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    )
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _beta_fraction(a, b, x) / a
    return 1.0 - front * _beta_fraction(b, a, 1.0 - x) / b


def t_sf_two_sided(t: float, dof: float) -> float:
    """P(|T| >= t) for T ~ Student's t with `dof` degrees of freedom."""
    if dof <= 0:
        raise ValueError(f"Student's t needs dof > 0, got {dof}")
    if not math.isfinite(t):
        return 0.0
    return _beta_inc(0.5 * dof, 0.5, dof / (dof + t * t))


def f_sf(f: float, d1: float, d2: float) -> float:
    """P(F >= f) for F ~ Fisher's F with (d1, d2) degrees of freedom."""
    if d1 <= 0 or d2 <= 0:
        raise ValueError(f"the F distribution needs positive degrees of freedom, got {d1}, {d2}")
    if f <= 0:
        return 1.0
    if not math.isfinite(f):
        return 0.0
    return _beta_inc(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * f))
