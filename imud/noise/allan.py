"""Overlapping Allan deviation of rate samples (gyro rad/s, accel m/s^2), streamed: the samples
arrive a chunk at a time and nothing but a short history is kept, so a day at 1 kHz needs no
more memory than a minute.

Definitions (IEEE Std 952, NIST SP 1065 eq. 11): with sample period tau0 and the integral
x[0] = 0, x[i] = tau0 * (y[0] + ... + y[i-1]) of the N samples y, at tau = m * tau0

    avar(tau) = sum_i (x[i+2m] - 2 x[i+m] + x[i])^2 / (2 tau^2 (N + 1 - 2m)),  i = 0 .. N - 2m

the same as allantools' `oadev(y, rate, data_type="freq")`. Each term needs the integral 2m
samples back, so an exact streamed estimate keeps 2m values per axis: a tenth of a day at 1 kHz
is 17 M values an axis. Past `exact_m` (1024 samples by default) the sum runs over every s-th
start index i only, s a power of two at most m / STRIDE_DIV: the terms are still exact Allan
terms (the integral at those indices is kept exactly) and neighbouring terms overlap by 1 - s/m
or more, so the estimate loses almost nothing to the full overlapping one (the equivalent
degrees of freedom differ by under a few per cent); what is kept is 2 * STRIDE_DIV values per
axis and stride. Below `exact_m` every term is summed: the values equal allantools'.

The mean of the first chunk is taken out of every sample before the integral (a constant rate
adds a straight line to x, which the second difference removes), so the integral stays small and
its rounding with it: allantools takes out the whole series' mean for the same reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

PER_DECADE = 8  # tau values per decade (at least: rounding m to integers can only merge)
MAX_FRACTION = 0.1  # the longest tau is this much of the record
EXACT_M = 1024  # every start index summed up to here
STRIDE_DIV = 64  # beyond: a stride of at most m / STRIDE_DIV


def lags(n: int, per_decade: int = PER_DECADE, max_fraction: float = MAX_FRACTION) -> I64:
    """The averaging factors m (tau = m * tau0) for a record of n samples: geometric from 1 at
    `per_decade` a decade up to `max_fraction` of the record, as distinct integers."""
    top = max(1.0, n * max_fraction)
    k = math.floor(math.log10(top) * per_decade + 1e-9)
    m = np.unique(np.round(10.0 ** (np.arange(k + 1) / per_decade)).astype(np.int64))
    return m[m <= max(1, int(top))]


def stride(m: int, exact_m: int = EXACT_M) -> int:
    """The start-index stride used at averaging factor m (1: every term)."""
    if m <= exact_m:
        return 1
    return 1 << max(0, math.floor(math.log2(m / STRIDE_DIV)))


@dataclass(frozen=True)
class AllanResult:
    """Per tau: tau (s), m, the deviation per axis (k columns), the terms summed, the stride."""

    tau_s: F64
    m: I64
    adev: F64  # (T, k)
    terms: I64
    stride: I64
    n: int  # samples analysed
    # the samples of each contiguous stretch (a gap starts the next): the equivalent degrees of
    # freedom of each tau's estimate are summed over them (imud/noise/fit.py)
    stretch_n: tuple[int, ...] = ()


class StreamingAllan:
    """Feed (n, k) chunks of rate samples in order; `result()` at any point."""

    def __init__(
        self,
        rate_hz: float,
        axes: int,
        m: I64,
        exact_m: int = EXACT_M,
    ) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate {rate_hz} Hz: must be positive")
        self.tau0 = 1.0 / rate_hz
        self.k = axes
        # each m rounded to a multiple of its stride (its tau is then m * tau0 exactly)
        s = np.array([stride(int(x), exact_m) for x in m], dtype=np.int64)
        mm = np.unique(np.maximum(s, np.round(np.asarray(m) / s).astype(np.int64) * s))
        self.m = mm
        self.s = np.array([stride(int(x), exact_m) for x in mm], dtype=np.int64)
        self.sums = np.zeros((mm.size, axes))
        self.terms = np.zeros(mm.size, dtype=np.int64)
        self.n = 0  # samples seen, over every stretch
        self.stretches = 1  # runs of contiguous samples (a gap starts another)
        self.offset: F64 | None = None  # the rate taken out (the first chunk's mean)
        self._done: list[int] = []  # the lengths of the stretches before the current one
        self._restart()
        self._keep = {
            int(v): 2 * int(self.m[self.s == v].max()) // int(v) for v in np.unique(self.s)
        }

    def _restart(self) -> None:
        self._seg = 0  # samples of this stretch; its integral has _seg + 1 points, x[0] = 0
        self.x_last = np.zeros(self.k)  # x[_seg]
        # per stride: the integral at the last indices that are multiples of it (the newest
        # last), enough for that stride's longest lag, and the index of the first of them
        self._levels: dict[int, tuple[F64, int]] = {
            int(v): (np.zeros((1, self.k)), 0) for v in np.unique(self.s)
        }

    def gap(self) -> None:
        """Samples are missing here: the next one starts a new stretch. The sums go on over
        every stretch; no term spans a gap (each term needs 2m + 1 contiguous samples)."""
        if self._seg:
            self._done.append(self._seg)
            self._restart()
            self.stretches += 1

    def feed(self, y: F64) -> None:
        """The next samples, (n, k) in the axes' order; NaN is refused (cut gaps out first)."""
        y = np.asarray(y, dtype=np.float64)
        if y.ndim != 2 or y.shape[1] != self.k:
            raise ValueError(f"samples of shape {y.shape}: expected (n, {self.k})")
        if not y.shape[0]:
            return
        if not np.isfinite(y).all():
            raise ValueError("a sample that is NaN or infinite: the Allan sum needs every one")
        if self.offset is None:
            self.offset = y.mean(axis=0)
        # x[n+1 .. n+len]; the running sum continues x[n] (one cumsum, its first term carried)
        d = (y - self.offset) * self.tau0
        d[0] += self.x_last
        x = np.cumsum(d, axis=0)
        first = self._seg + 1  # index in the stretch of x[0] of this chunk
        self._seg += y.shape[0]
        self.n += y.shape[0]
        self.x_last = x[-1].copy()
        for s, (hist, start) in list(self._levels.items()):
            # this chunk's indices that are multiples of s
            k0 = (-first) % s
            new = x[k0::s]
            if not new.shape[0]:
                continue
            buf = np.concatenate((hist, new))
            buf_start = start  # global index / s of buf[0]
            n_new = new.shape[0]
            for j in np.flatnonzero(self.s == s):
                lag = int(self.m[j]) // s
                # terms whose last point x[i + 2m] is new: their first point is in buf too
                lo = max(buf.shape[0] - n_new, 2 * lag)
                if lo >= buf.shape[0]:
                    continue
                a = buf[lo:]
                v = (
                    a
                    - 2.0 * buf[lo - lag : buf.shape[0] - lag]
                    + buf[lo - 2 * lag : buf.shape[0] - 2 * lag]
                )
                self.sums[j] += np.einsum("ik,ik->k", v, v)
                self.terms[j] += a.shape[0]
            keep = self._keep[s]
            if buf.shape[0] > keep:
                buf_start += buf.shape[0] - keep
                buf = buf[-keep:]
            self._levels[s] = (buf.copy() if buf.base is not None else buf, buf_start)

    def result(self) -> AllanResult:
        """The deviations so far, for the taus with at least one term."""
        ok = self.terms > 0
        m = self.m[ok]
        tau = m * self.tau0
        avar = self.sums[ok] / (2.0 * (tau**2)[:, None] * self.terms[ok][:, None])
        lengths = (*self._done, self._seg) if self._seg else tuple(self._done)
        return AllanResult(tau, m, np.sqrt(avar), self.terms[ok], self.s[ok], self.n, lengths)


def oadev(y: F64, rate_hz: float, m: I64 | None = None, chunk: int = 1 << 16) -> AllanResult:
    """The overlapping Allan deviation of all of `y` ((n,) or (n, k)), fed a chunk at a time."""
    y = np.asarray(y, dtype=np.float64)
    y2 = y[:, None] if y.ndim == 1 else y
    acc = StreamingAllan(rate_hz, y2.shape[1], lags(y2.shape[0]) if m is None else m)
    for i in range(0, y2.shape[0], chunk):
        acc.feed(y2[i : i + chunk])
    return acc.result()
