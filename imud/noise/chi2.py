"""Chi-squared quantiles without scipy (a base install has numpy only): the regularised lower
incomplete gamma function P(k/2, x/2) by its series or continued fraction (Numerical Recipes
6.2), inverted by bisection on a bracket from the Wilson-Hilferty approximation. Above
WH_ABOVE degrees of freedom Wilson-Hilferty alone is used: its relative error there is under
1e-5, far below any Allan interval's width, and the exact series would need thousands of terms.
"""

from __future__ import annotations

import math
from functools import lru_cache

WH_ABOVE = 2000.0
_EPS = 1e-13


def gamma_pq(a: float, x: float) -> tuple[float, float]:
    """(P, Q): the regularised lower and upper incomplete gamma functions at (a, x), each
    computed on the side where it converges fast (the series for P below a + 1, the continued
    fraction for Q above, modified Lentz), so a small tail keeps its relative accuracy. The
    calibration's acceptance tests (imud.calib.stats) use the same."""
    if x <= 0.0:
        return 0.0, 1.0
    lead = math.exp(-x + a * math.log(x) - math.lgamma(a))
    if x < a + 1.0:  # the series converges fast here
        term = total = 1.0 / a
        ap = a
        for _ in range(100_000):
            ap += 1.0
            term *= x / ap
            total += term
            if abs(term) < abs(total) * _EPS:
                break
        p = min(1.0, total * lead)
        return p, max(0.0, 1.0 - p)
    tiny = 1e-300
    b = x + 1.0 - a
    c = 1.0 / tiny
    d = 1.0 / b
    h = d
    for i in range(1, 100_000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        step = d * c
        h *= step
        if abs(step - 1.0) < _EPS:
            break
    q = min(1.0, lead * h)
    return max(0.0, 1.0 - q), q


def chi2_cdf(x: float, k: float) -> float:
    """P(X <= x) for X chi-squared with k (> 0, not necessarily whole) degrees of freedom."""
    if not k > 0:
        raise ValueError(f"{k} degrees of freedom: must be positive")
    return gamma_pq(k / 2.0, x / 2.0)[0]


def _norm_ppf(p: float) -> float:
    """The standard normal quantile (Acklam's rational approximation, 1e-9 relative, refined by
    one Newton step on erf)."""
    a = (-3.969683028665376e01, 2.209460984245205e02, -2.759285104469687e02,
         1.383577518672690e02, -3.066479806614716e01, 2.506628277459239e00)  # fmt: skip
    b = (-5.447609879822406e01, 1.615858368580409e02, -1.556989798598866e02,
         6.680131188771972e01, -1.328068155288572e01)  # fmt: skip
    c = (-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e00,
         -2.549732539343734e00, 4.374664141464968e00, 2.938163982698783e00)  # fmt: skip
    d = (7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e00,
         3.754408661907416e00)  # fmt: skip
    if p < 0.02425:
        q = math.sqrt(-2 * math.log(p))
        z = (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) / (
            (((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1
        )
    elif p > 1 - 0.02425:
        return -_norm_ppf(1 - p)
    else:
        q = p - 0.5
        r = q * q
        z = (
            (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5])
            * q
            / (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1)
        )
    e = 0.5 * math.erfc(-z / math.sqrt(2)) - p
    return z - e * math.sqrt(2 * math.pi) * math.exp(z * z / 2)


@lru_cache(maxsize=4096)  # a fit asks for the same few degrees of freedom at every axis
def chi2_ppf(p: float, k: float) -> float:
    """The p-quantile (0 < p < 1) of chi-squared with k degrees of freedom."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"probability {p}: must be between 0 and 1")
    if not k > 0:
        raise ValueError(f"{k} degrees of freedom: must be positive")
    z = _norm_ppf(p)
    h = 2.0 / (9.0 * k)
    wh = k * max(1.0 - h + z * math.sqrt(h), 0.0) ** 3
    if k > WH_ABOVE:
        return wh
    # a bracket around the Wilson-Hilferty guess, widened until it holds the quantile
    lo, hi = (0.0, max(wh, k) * 2.0 + 10.0) if wh <= 0 else (wh / 2.0, wh * 2.0 + 1.0)
    while chi2_cdf(lo, k) > p:
        lo /= 10.0
    while chi2_cdf(hi, k) < p:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if chi2_cdf(mid, k) < p:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-12 * hi:
            break
    return 0.5 * (lo + hi)
