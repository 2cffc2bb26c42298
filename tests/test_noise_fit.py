"""The noise-term fit (imud/noise/fit.py) against series whose terms are known by construction,
and its chi-squared quantiles and degrees of freedom against tables and independent code."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from imud.noise.allan import StreamingAllan, lags, oadev
from imud.noise.chi2 import chi2_cdf, chi2_ppf
from imud.noise.fit import B_FLOOR, edf_simple, fit

# --- a series with known N, B and K ----------------------------------------------------------
#
# White rate noise of density N (per-sample sigma N / sqrt(dt)), a rate random walk of K (step
# sigma K sqrt(dt)) and, for B, flicker (1/f) rate noise made of first-order Gauss-Markov
# processes one a decade apart (correlation times 0.1 s .. 10,000 s, each of variance q): each
# has the one-sided PSD 4 q T / (1 + (2 pi f T)^2), and a sum of them log-spaced by a factor r
# integrates to q / (f ln r) between the extreme corners. A one-sided 1/f PSD h / f has the Allan
# floor 2 ln2 h (NIST SP 1065 table 6), and IEEE 952's B has the floor (2 ln2 / pi) B^2; so
# B^2 = pi q / ln r, i.e. q = B^2 ln r / pi. test_the_flicker_sum_is_flat checks that floor on the
# exact Allan variance of the discrete processes.

RATE, N_SAMPLES, TRIALS = 20.0, 40_000, 200
N_TRUE, B_TRUE, K_TRUE = 4e-4, 1.5e-4, 2.2e-5
GM_T = 10.0 ** np.arange(-1, 5)  # s
GM_Q = B_TRUE**2 * math.log(10.0) / math.pi


def _ar1(rng: np.random.Generator, n: int, k: int, t_corr: float, dt: float) -> np.ndarray:
    """n steps of k stationary AR(1) (first-order Gauss-Markov) series of variance GM_Q:
    y[i] = phi y[i-1] + w[i], in blocks short enough for phi^-j to stay in range (a cumulative
    sum per block instead of a Python loop per sample)."""
    phi = math.exp(-dt / t_corr)
    w = rng.normal(0.0, math.sqrt(GM_Q * (1 - phi * phi)), (n, k))
    w[0] = rng.normal(0.0, math.sqrt(GM_Q), k)
    block = max(1, min(n, int(math.log(1e8) * t_corr / dt)))
    out = np.empty((n, k))
    last = np.zeros(k)
    for s in range(0, n, block):
        j = np.arange(min(block, n - s))[:, None]
        y = phi**j * (np.cumsum(w[s : s + j.size] * phi ** (-j), axis=0) + phi * last)
        out[s : s + j.size] = y
        last = y[-1]
    return out


def _gm(rng: np.random.Generator, n: int, k: int, t_corr: float) -> np.ndarray:
    """A Gauss-Markov series at RATE; a slow one drawn exactly on a grid of t_corr / 50 and
    linearly interpolated (it changes little within a step; drawing it per sample costs 50x)."""
    dt = 1.0 / RATE
    step = max(1, int(t_corr / dt / 50))
    if step == 1:
        return _ar1(rng, n, k, t_corr, dt)
    coarse = _ar1(rng, n // step + 2, k, t_corr, dt * step)
    x = np.arange(n) / step
    i = x.astype(np.int64)
    f = (x - i)[:, None]
    out: np.ndarray = coarse[i] * (1 - f) + coarse[i + 1] * f
    return out


def _series(rng: np.random.Generator, k: int) -> np.ndarray:
    dt = 1.0 / RATE
    y = rng.normal(0.0, N_TRUE / math.sqrt(dt), (N_SAMPLES, k))
    y += np.cumsum(rng.normal(0.0, K_TRUE * math.sqrt(dt), (N_SAMPLES, k)), axis=0)
    for t_corr in GM_T:
        y += _gm(rng, N_SAMPLES, k, float(t_corr))
    return y


def _ar1_avar(m: np.ndarray, phi: float, q: float) -> np.ndarray:
    """The exact Allan variance of m-sample means of a stationary AR(1) of variance q (sample
    units): Var(mean) - Cov(adjacent means), from its autocovariance q phi^|k|."""
    m = m.astype(np.float64)
    var = q / m**2 * (m * (1 + phi) / (1 - phi) - 2 * phi * (1 - phi**m) / (1 - phi) ** 2)
    cov = q / m**2 * phi * ((1 - phi**m) / (1 - phi)) ** 2
    out: np.ndarray = var - cov
    return out


def test_the_flicker_sum_is_flat_at_the_bias_instability_floor() -> None:
    """The generator's B: the exact Allan deviation of its Gauss-Markov sum (no simulation) is
    within 6 % of 0.664 B from 0.3 s to 2,000 s, the taus the trials fit over."""
    m = np.unique(np.round(np.logspace(np.log10(6), np.log10(40_000), 60))).astype(np.int64)
    dt = 1.0 / RATE
    avar = sum(_ar1_avar(m, math.exp(-dt / t), GM_Q) for t in GM_T)
    ratio = np.sqrt(avar) / (B_FLOOR * B_TRUE)
    assert np.all(np.abs(ratio - 1) < 0.06), ratio


def test_the_truth_is_inside_the_95_percent_interval_in_200_trials() -> None:
    """200 series of 2,000 s at 20 Hz with N, B and K known by construction (above): each
    term's truth inside its stated 95 % interval in >= 90 % of them, and the estimates
    centred on the truth (their median within the intervals' typical half-width)."""
    rng = np.random.default_rng(2024)
    fits = []
    for _ in range(TRIALS // 50):  # 50 series at a time: a quarter of the memory
        y = _series(rng, 50)
        acc = StreamingAllan(RATE, 50, lags(N_SAMPLES))
        for i in range(0, N_SAMPLES, 1 << 14):
            acc.feed(y[i : i + (1 << 14)])
        fits += fit(acc.result())
    assert len(fits) == TRIALS
    for name, truth in (("N", N_TRUE), ("B", B_TRUE), ("K", K_TRUE)):
        terms = [f.terms[name] for f in fits]
        inside = np.mean([t.lo <= truth <= t.hi for t in terms])
        assert inside >= 0.9, (name, inside)
        half = np.median([(t.hi - t.lo) / 2 for t in terms])
        assert abs(np.median([t.value for t in terms]) - truth) < half, name
    # N is read where it dominates: its interval is tight (0.5 % of 0.67 * 40,000 degrees)
    n_half = np.median([(f.terms["N"].hi - f.terms["N"].lo) / 2 / N_TRUE for f in fits])
    assert n_half < 0.02


def test_white_noise_alone_gives_n_and_no_other_term() -> None:
    """Rate white noise of sigma at rate f: N = sigma / sqrt(f); the other terms unresolved
    (their intervals reach zero) and their upper bounds small beside N's curve."""
    rng = np.random.default_rng(3)
    sigma, rate = 0.01, 200.0
    r = oadev(rng.normal(0.0, sigma, (200_000, 2)), rate)
    for f in fit(r):
        n = f.terms["N"]
        assert n.lo <= sigma / math.sqrt(rate) <= n.hi
        assert n.hi / n.lo < 1.02  # 200,000 samples: N to a per cent
        for name in ("Q", "K", "R"):
            assert f.terms[name].lo == 0.0, name


def test_quantisation_and_ramp_are_read_on_their_lines() -> None:
    """White phase noise of sigma_x (the rate is its difference / tau0) has avar 3 sigma_x^2 /
    tau^2 exactly: Q = sigma_x. A ramp y = R t has avar R^2 tau^2 / 2 exactly: its line's
    reading at sqrt(2) s is R."""
    rng = np.random.default_rng(6)
    rate, sx = 100.0, 1e-4
    x = rng.normal(0.0, sx, 200_001)
    (f,) = fit(oadev(np.diff(x)[:, None] * rate, rate))
    assert f.terms["Q"].lo <= sx <= f.terms["Q"].hi
    assert f.terms["Q"].value == pytest.approx(sx, rel=0.02)
    ramp = 3e-5
    t = np.arange(100_000) / rate
    y = ramp * t + rng.normal(0.0, 1e-4, t.size)
    (f,) = fit(oadev(y[:, None], rate))
    assert f.terms["R"].lo <= ramp <= f.terms["R"].hi
    assert f.terms["R"].value == pytest.approx(ramp, rel=0.05)


def test_chi_squared_quantiles_match_the_tables() -> None:
    """Abramowitz & Stegun table 26.8 (and any chi-squared table) to the printed digits."""
    for p, k, want in ((0.975, 1, 5.02389), (0.025, 1, 0.000982069), (0.025, 10, 3.24697),
                       (0.975, 10, 20.4832), (0.5, 2, 1.38629), (0.025, 100, 74.2219),
                       (0.975, 100, 129.561)):  # fmt: skip
        assert chi2_ppf(p, k) == pytest.approx(want, rel=2e-5), (p, k)
        assert chi2_cdf(chi2_ppf(p, k), k) == pytest.approx(p, abs=1e-9)
    # far above the exact routine's range, Wilson-Hilferty: the Cornish-Fisher expansion
    # k + z sqrt(2k) + 2 (z^2 - 1) / 3, whose next term is O(1 / sqrt(k))
    z = 1.959964
    assert chi2_ppf(0.975, 1e6) == pytest.approx(1e6 + z * math.sqrt(2e6) + 2 * (z * z - 1) / 3,
                                                 abs=0.01)  # fmt: skip
    with pytest.raises(ValueError, match="between 0 and 1"):
        chi2_ppf(1.0, 3)


@pytest.fixture
def allantools() -> object:
    """allantools (the dev extra): an independent implementation of SP 1065's table 5."""
    return pytest.importorskip("allantools")


@pytest.mark.extra
def test_degrees_of_freedom_equal_allantools_edf_simple(allantools: Any) -> None:
    for n in (100, 10_001, 3_600_001):
        for m in (1, 2, 7, 30, max(1, (n - 1) // 10)):
            for alpha in (2, 0, -1, -2):
                want = allantools.edf_simple(n, m, alpha)
                assert edf_simple(n, m, alpha) == pytest.approx(max(want, 1.0), rel=1e-12)


@pytest.mark.extra
def test_chi_squared_quantiles_equal_scipys() -> None:
    stats = pytest.importorskip("scipy.stats")
    for k in (0.5, 1.0, 2.7, 13.0, 250.0, 1999.0, 5e4):
        for p in (0.001, 0.025, 0.5, 0.975, 0.999):
            assert chi2_ppf(p, k) == pytest.approx(stats.chi2.ppf(p, k), rel=2e-5)
