"""The noise terms of an Allan deviation curve, with 95 % intervals.

The model (IEEE Std 952-1997 annex C, two-sided PSD convention) is a sum of independent terms

    avar(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2

quantisation Q (adev slope -1), white noise N (-1/2), bias instability B (flat; its floor is
sqrt(2 ln 2 / pi) B = 0.6643 B, so B = floor / 0.664), rate random walk K (+1/2) and rate ramp
R (+1). Each coefficient is its line's reading at the conventional tau: N is the -1/2 line at
1 s, K the +1/2 line at 3 s, Q the -1 line at sqrt(3) s, R the +1 line at sqrt(2) s.

How it is fitted, and why: the model is linear in (Q^2, N^2, B^2, K^2, R^2), so the five are fitted
together by non-negative least squares on the variances, each tau weighted by the inverse of its
estimate's variance, 2 avar^2 / edf (a chi-squared variable with edf degrees of freedom), edf
from NIST SP 1065 section 5.3 (Howe's approximations, table 5) for the term that dominates there.
The weights use the model, not the noisy estimate (an estimate that falls low would otherwise
weigh more and drag the fit down), so the fit is iterated (IRLS) from the estimates. Fitting the
sum rather than slopes in hand-picked windows needs no window per term: where two terms overlap
both are fitted, and a term the data do not show comes out zero with an upper bound.

The only window is at the short end: a chip's low-pass filter makes the curve flatter than
-1/2 over its first few samples (the filtered noise is correlated over them), which no term
models. The fit starts where the local slope first reaches -0.49, times 10 (the filter's excess
falls as 1/tau or a little slower: the simulated STIM300's is still 3 % at 20 filter time
constants), unless the curve starts that steep.

Intervals: the term's coefficient is the fitted one; its 95 % interval maps the chi-squared
interval of the avar at one tau onto it, the other terms held at their fitted values there, at
the tau where that interval is narrowest in the term's units (where the term dominates and the
degrees of freedom are many). Overlapping estimates at neighbouring taus are strongly correlated,
so one tau's degrees of freedom are what the curve knows about the term, not their sum over taus
(summing would claim intervals many times too narrow: the reference notes measured allantools'
errs 10-1000x too optimistic for that reason). tests/test_noise_fit.py checks the truth falls
inside the interval in >= 90 % of 200 synthetic series.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from imud.noise.allan import AllanResult
from imud.noise.chi2 import chi2_ppf

F64 = npt.NDArray[np.float64]

TERMS = ("Q", "N", "B", "K", "R")
# sqrt(2 ln 2 / pi): the flat floor of flicker (1/f) rate noise of bias instability B
B_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
# each term's noise type as the exponent alpha of the rate's PSD f^alpha (NIST SP 1065 table 5);
# the rate ramp is not a noise: its estimate is as uncertain as random walk's, the steepest type
ALPHA = {"Q": 2, "N": 0, "B": -1, "K": -2, "R": -2}
READ_AT_S = {"Q": math.sqrt(3.0), "N": 1.0, "B": None, "K": 3.0, "R": math.sqrt(2.0)}
SLOPE = {"Q": -1.0, "N": -0.5, "B": 0.0, "K": 0.5, "R": 1.0}
FILTER_SLOPE = -0.45  # a first slope flatter than this is a low-pass filter's
START_SLOPE = -0.49  # and it is over where the local slope reaches this
START_FACTOR = 10.0
IRLS_ROUNDS = 6
# the terms dropped when the data do not resolve them (N, B and K are always fitted, and come out
# zero with an upper bound when absent): quantisation and ramp are rare in MEMS rate data and,
# fitted where they are absent, they trade variance with N and K over the taus they share
OPTIONAL = ("Q", "R")


def basis(tau: F64) -> F64:
    """(T, 5): each term's avar per unit squared coefficient, the columns in TERMS' order."""
    tau = np.asarray(tau, dtype=np.float64)
    return np.column_stack((3.0 / tau**2, 1.0 / tau, np.full(tau.shape, B_FLOOR**2), tau / 3.0,
                            tau**2 / 2.0))  # fmt: skip


def edf_simple(n_phase: float, m: float, alpha: int) -> float:
    """Equivalent degrees of freedom of the overlapping Allan variance at averaging factor m
    from n_phase phase points (rate samples + 1) for PSD exponent alpha: NIST SP 1065 table 5
    (Howe, Allan and Barnes' approximations). At least 1: the formulas go below it (even
    negative) only where m nears n / 2 and a single term remains."""
    n, m = float(n_phase), float(m)
    if alpha == 2:
        e = (n + 1) * (n - 2 * m) / (2 * (n - m))
    elif alpha == 1:
        a, b = (n - 1) / (2 * m), (2 * m + 1) * (n - 1) / 4
        e = math.exp(math.sqrt(math.log(a) * math.log(b))) if a > 1 and b > 1 else 1.0
    elif alpha == 0:
        e = (3 * (n - 1) / (2 * m) - 2 * (n - 2) / n) * 4 * m * m / (4 * m * m + 5)
    elif alpha == -1:
        e = 2 * (n - 2) / (2.3 * n - 4.9) if m == 1 else 5 * n * n / (4 * m * (n + 3 * m))
    elif alpha == -2:
        e = (n - 2) / (m * (n - 3) ** 2) * ((n - 1) ** 2 - 3 * m * (n - 1) + 4 * m * m)
    else:
        raise ValueError(f"alpha {alpha}: one of 2, 1, 0, -1, -2")
    return max(1.0, e) if math.isfinite(e) else 1.0


def edf_table(r: AllanResult) -> F64:
    """(T, 5): each tau's degrees of freedom for each term's noise type, summed over the
    stretches long enough for a term at that tau (each is an independent estimate), and never
    more than the terms summed (a strided tau sums fewer)."""
    lengths = r.stretch_n or (r.n,)
    out = np.zeros((r.tau_s.size, len(TERMS)))
    for i, m in enumerate(r.m.tolist()):
        for j, name in enumerate(TERMS):
            e = sum(edf_simple(n + 1, m, ALPHA[name]) for n in lengths if n >= 2 * m + 1)
            out[i, j] = min(max(e, 1.0), float(r.terms[i]))
    return out


@dataclass(frozen=True)
class Term:
    """One fitted term: its value and 95 % interval (lo <= value <= hi), in the term's units;
    the tau whose degrees of freedom set the interval, and those degrees of freedom."""

    name: str
    value: float
    lo: float
    hi: float
    tau_s: float
    edf: float


@dataclass(frozen=True)
class AxisFit:
    """The five terms of one axis, the fitted window and the curve's minimum (a bias instability
    read the conventional way, min adev / 0.664, which is above the fitted B where the white
    and random walk lines cross near the floor)."""

    terms: dict[str, Term]
    tau_lo_s: float
    adev_min: float
    tau_min_s: float
    coef: tuple[float, ...] = field(default=())  # (Q^2, N^2, B^2, K^2, R^2)

    def model(self, tau: F64) -> F64:
        """The fitted adev at tau."""
        return np.asarray(np.sqrt(basis(tau) @ np.asarray(self.coef)), dtype=np.float64)

    @property
    def b_from_min(self) -> float:
        return self.adev_min / B_FLOOR


def _nnls(a: F64, b: F64) -> F64:
    """min |a x - b| over x >= 0, for a handful of columns: every support set is tried (32 least
    squares of <= 5 unknowns), the best with no negative coefficient kept: exact, and no
    iteration that can stall."""
    k = a.shape[1]
    scale = np.linalg.norm(a, axis=0)
    scale[scale == 0] = 1.0
    an = a / scale
    best, best_cost = np.zeros(k), float(b @ b)
    for size in range(1, k + 1):
        for cols in itertools.combinations(range(k), size):
            sub = an[:, cols]
            x, *_ = np.linalg.lstsq(sub, b, rcond=None)
            if (x < 0).any() or not np.isfinite(x).all():
                continue
            res = sub @ x - b
            cost = float(res @ res)
            if cost < best_cost:
                best_cost = cost
                best = np.zeros(k)
                best[list(cols)] = x
    out: F64 = best / scale
    return out


def start_index(tau: F64, adev: F64) -> int:
    """The first tau the fit uses (see the module's docstring)."""
    if tau.size < 3:
        return 0
    slope = np.diff(np.log(adev)) / np.diff(np.log(tau))
    if not np.isfinite(slope).all() or slope[0] <= FILTER_SLOPE:
        return 0  # no flattening the estimate's own scatter could not make
    steep = np.flatnonzero(slope <= START_SLOPE)
    if not steep.size:  # never reaches -1/2: start at its steepest
        return int(np.argmin(slope))
    at = tau[int(steep[0])] * START_FACTOR
    return min(int(np.searchsorted(tau, at)), tau.size - 2)


def _irls(a: F64, v: F64, e: F64, use: list[int]) -> tuple[F64, F64]:
    """The coefficients (zero outside `use`) and the fitted avar."""
    model = v.copy()
    coef = np.zeros(a.shape[1])
    white = np.zeros(a.shape[1])
    white[1] = 1.0
    for _ in range(IRLS_ROUNDS):
        # the estimate's standard deviation, from the type that dominates the model here
        share = a * (coef if coef.any() else white) / model[:, None]
        dof = e[np.arange(v.size), np.argmax(share, axis=1)]
        sd = model * np.sqrt(2.0 / dof)
        coef = np.zeros(a.shape[1])
        coef[use] = _nnls(a[:, use] / sd[:, None], v / sd)
        fitted = a @ coef
        model = np.where(fitted > 0, fitted, v)
    return coef, model


def _interval(
    j: int,
    coef: F64,
    model: F64,
    a: F64,
    e: F64,
    t: F64,
    confidence: float,
    others: dict[int, tuple[float, float]] | None = None,
) -> tuple[float, float, float, float]:
    """Term j's interval (in its coefficient, a variance) at the tau where it is narrowest: the
    chi-squared interval of the avar there, less the other terms, held at their fit or (given
    `others`, their intervals) taken at whichever end of their interval widens j's."""
    lo_p, hi_p = (1 - confidence) / 2, 1 - (1 - confidence) / 2
    best = (0.0, math.inf, float(t[0]), 1.0)
    for i in range(t.size):
        k = float(e[i, j])
        rest_lo = rest_hi = float(model[i] - coef[j] * a[i, j])
        if others is not None:
            rest_lo = sum(others[q][0] * a[i, q] for q in others if q != j)
            rest_hi = sum(others[q][1] * a[i, q] for q in others if q != j)
        lo = max((model[i] * k / chi2_ppf(hi_p, k) - rest_hi) / a[i, j], 0.0)
        hi = (model[i] * k / chi2_ppf(lo_p, k) - rest_lo) / a[i, j]
        if hi - lo < best[1] - best[0]:
            best = (lo, max(hi, lo), float(t[i]), k)
    return best


def fit_axis(tau: F64, adev: F64, edf: F64, confidence: float = 0.95) -> AxisFit:
    """The terms of one axis from its adev at tau and the (T, 5) degrees of freedom.

    Every term is fitted first; then, one at a time, the term whose interval reaches down to
    zero by the largest margin is dropped and the rest refitted, until every term left is
    resolved: an unresolved quantisation or ramp otherwise trades off against N or K (fitted
    together over a short stretch of taus they can swap variance) and biases them. A dropped
    term reads 0 with its upper bound from the final fit."""
    tau = np.asarray(tau, dtype=np.float64)
    adev = np.asarray(adev, dtype=np.float64)
    ok = np.isfinite(adev) & (adev > 0)
    if not ok.any():
        raise ValueError("no tau with a finite, positive Allan deviation to fit")
    tau, adev, edf = tau[ok], adev[ok], edf[ok]
    imin = int(np.argmin(adev))
    i0 = start_index(tau, adev)
    t, v, e = tau[i0:], adev[i0:] ** 2, edf[i0:]
    a = basis(t)
    use = list(range(len(TERMS)))
    while True:
        coef, model = _irls(a, v, e, use)
        held = {j: _interval(j, coef, model, a, e, t, confidence)[:2] for j in use}
        # each term's interval with the others' uncertainty included (the fitted terms trade
        # off against each other where their taus overlap; holding the others at their fit
        # claims too narrow an interval there)
        spans = {j: _interval(j, coef, model, a, e, t, confidence, held) for j in use}
        loose = [j for j in use if spans[j][0] <= 0.0 and TERMS[j] in OPTIONAL]
        if not loose:
            break
        # the least resolved: its fitted value smallest beside its upper bound
        use.remove(min(loose, key=lambda j: coef[j] / spans[j][1] if spans[j][1] > 0 else 0.0))
    terms: dict[str, Term] = {}
    for j, name in enumerate(TERMS):
        lo, hi, at, k = spans[j] if j in spans else _interval(j, coef, model, a, e, t,
                                                              confidence, held)  # fmt: skip
        lo, hi = min(lo, coef[j]), max(hi, coef[j])
        terms[name] = Term(name, math.sqrt(coef[j]), math.sqrt(lo), math.sqrt(hi), at, k)
    return AxisFit(terms, float(t[0]), float(adev[imin]), float(tau[imin]), tuple(coef.tolist()))


def fit(r: AllanResult, confidence: float = 0.95) -> list[AxisFit]:
    """Every axis of an Allan result."""
    e = edf_table(r)
    return [fit_axis(r.tau_s, r.adev[:, k], e, confidence) for k in range(r.adev.shape[1])]
