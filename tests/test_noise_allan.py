"""The streamed overlapping Allan deviation against allantools (an independent implementation,
run here on the same samples) and against the physics of white noise."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from imud.noise.allan import EXACT_M, StreamingAllan, lags, oadev


@pytest.fixture
def allantools() -> object:
    """allantools (the dev extra): an independent implementation, run on the same samples."""
    return pytest.importorskip("allantools")


def _series(n: int, k: int, seed: int) -> np.ndarray:
    """White noise on a large constant rate with a random-walk bias: what a gyro gives."""
    rng = np.random.default_rng(seed)
    walk = np.cumsum(rng.normal(0.0, 2e-5, (n, k)), axis=0)
    return rng.normal(0.0, 0.01, (n, k)) + walk + np.array([0.02, -0.5, 9.81][:k])


@pytest.mark.extra
@pytest.mark.parametrize("chunk", [1, 997, 1 << 16])
def test_every_tau_summed_in_full_equals_allantools(allantools: Any, chunk: int) -> None:
    n = 2_000 if chunk == 1 else 400_000
    y = _series(n, 3, seed=chunk)
    r = oadev(y, 800.0, chunk=chunk)
    full = r.stride == 1
    assert full.sum() >= (14 if chunk == 1 else 20) and r.m[full].max() <= EXACT_M
    for ax in range(3):
        tau, dev, _, ns = allantools.oadev(y[:, ax], rate=800.0, data_type="freq",
                                           taus=r.tau_s[full])  # fmt: skip
        np.testing.assert_allclose(tau, r.tau_s[full], rtol=1e-12)
        np.testing.assert_array_equal(ns, r.terms[full])
        np.testing.assert_allclose(r.adev[full, ax], dev, rtol=1e-9, atol=0)


@pytest.mark.extra
def test_a_strided_tau_is_within_a_hundredth_of_the_full_sum(allantools: Any) -> None:
    """Past EXACT_M every stride-th start index: exact terms, fewer of them; on 400 s of white
    noise it stays within 1 % of allantools' full overlapping sum (the estimates' own spread at
    those taus is 10-30 %)."""
    y = _series(400_000, 1, seed=3)
    r = oadev(y, 1000.0)
    strided = r.stride > 1
    assert strided.sum() >= 8
    tau, dev, _, _ = allantools.oadev(y[:, 0], rate=1000.0, data_type="freq",
                                      taus=r.tau_s[strided])  # fmt: skip
    np.testing.assert_allclose(tau, r.tau_s[strided], rtol=1e-12)
    np.testing.assert_allclose(r.adev[strided, 0], dev, rtol=0.01)
    assert (r.m[strided] % r.stride[strided] == 0).all()
    assert (r.stride[strided] <= r.m[strided] // 64).all()


def test_white_noise_falls_as_one_over_root_tau() -> None:
    """Rate white noise of standard deviation sigma at rate f: adev(tau) = sigma / sqrt(f tau)
    (IEEE 952); the estimate's relative spread is about 1 / sqrt(edf), edf ~ 1.5 N / m here."""
    rng = np.random.default_rng(11)
    sigma, rate, n = 0.02, 500.0, 500_000
    r = oadev(rng.normal(0.0, sigma, (n, 2)), rate)
    truth = sigma / np.sqrt(rate * r.tau_s)
    spread = 1.0 / np.sqrt(1.5 * n / r.m)
    for ax in range(2):
        assert np.all(np.abs(r.adev[:, ax] / truth - 1) < 4 * spread + 1e-3)


def test_the_grid_has_eight_taus_a_decade_up_to_a_tenth_of_the_record() -> None:
    m = lags(1_000_000)
    assert m[0] == 1 and m[-1] <= 100_000 and m[-1] > 100_000 / 10 ** (1 / 8)
    per_decade = np.histogram(np.log10(m[m >= 10]), bins=np.arange(1, 6))[0]
    assert (per_decade >= 8).all()
    assert np.all(np.diff(m) > 0)


def test_history_stays_short_however_long_the_stream() -> None:
    """A day at 1 kHz keeps no more than a few thousand values an axis: fed 1.3 M samples in
    chunks, the kept history is bounded by 2 m for the full taus and 2 * 128 per stride."""
    acc = StreamingAllan(1000.0, 2, lags(86_400_000))
    rng = np.random.default_rng(5)
    for _ in range(20):
        acc.feed(rng.normal(0.0, 1.0, (1 << 16, 2)))
    kept = sum(buf.shape[0] for buf, _ in acc._levels.values())
    assert kept <= 2 * EXACT_M + 2 * 128 * len(acc._levels)
    assert acc.result().n == 20 << 16


def test_bad_samples_are_refused_with_a_reason() -> None:
    acc = StreamingAllan(100.0, 3, lags(10_000))
    with pytest.raises(ValueError, match="NaN or infinite"):
        acc.feed(np.array([[0.0, np.nan, 0.0]]))
    with pytest.raises(ValueError, match=r"expected \(n, 3\)"):
        acc.feed(np.zeros((5, 2)))
    with pytest.raises(ValueError, match="must be positive"):
        StreamingAllan(0.0, 3, lags(10))
    assert acc.result().tau_s.size == 0  # nothing fed: no tau yet


@pytest.mark.extra
def test_stretches_between_gaps_are_summed_and_no_term_spans_a_gap(allantools: Any) -> None:
    """Two stretches with a gap between: the result pools allantools' sums of each stretch
    (its deviation squared times its term count), as if each were analysed alone."""
    y = _series(60_000, 1, seed=8)
    a, b = y[:25_000, 0], y[25_000:, 0] + 3.0  # the rate jumps across the gap: no term sees it
    acc = StreamingAllan(200.0, 1, lags(60_000))
    acc.feed(a[:, None])
    acc.gap()
    acc.feed(b[:, None])
    r = acc.result()
    assert acc.stretches == 2 and r.n == 60_000
    full = r.stride == 1
    pooled = []
    for tau in r.tau_s[full]:
        s = n = 0.0
        for part in (a, b):
            _, dev, _, ns = allantools.oadev(part, rate=200.0, data_type="freq", taus=[tau])
            if len(dev):
                s += dev[0] ** 2 * ns[0]
                n += ns[0]
        pooled.append(np.sqrt(s / n))
    np.testing.assert_allclose(r.adev[full, 0], pooled, rtol=1e-9)
