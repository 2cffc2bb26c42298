"""`imud noise --by-temperature`: the gyro's mean (its bias, when the device is still) and every
axis' white noise N per temperature bin, for a thermal-chamber run.

Each bin has its own streamed Allan deviation; the samples of a bin arrive in runs (the chamber
passes through it, leaves, comes back), each run a stretch of that bin's estimate: no Allan term
spans two visits. The taus go up to MAX_TAU_S (N is read at the short end; a bin is visited for
minutes, not hours), and N comes from the same fit as the whole record's, with its interval."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from imud.noise.allan import StreamingAllan, lags
from imud.noise.fit import AxisFit, fit

F64 = npt.NDArray[np.float64]
MAX_TAU_S = 60.0


@dataclass
class _Bin:
    acc: StreamingAllan
    gyro_sum: F64
    n: int = 0


class TemperatureBins:
    """Feed (n, 6) samples (gyro x y z, accel x y z) with their (n,) temperatures."""

    def __init__(self, rate_hz: float, bin_c: float) -> None:
        if not (bin_c > 0 and math.isfinite(bin_c)):
            raise ValueError(f"--by-temperature {bin_c}: the bin width must be a positive °C")
        self.rate = rate_hz
        self.width = bin_c
        self.m = lags(int(rate_hz * MAX_TAU_S * 10))
        self.bins: dict[int, _Bin] = {}
        self._last: int | None = None  # the bin of the previous sample (None: after a gap)

    def gap(self) -> None:
        self._last = None

    def feed(self, y: F64, temp: F64) -> None:
        ok = np.isfinite(temp)
        if not ok.all():  # a sample without its temperature: a gap for the bins
            cuts = np.flatnonzero(~ok)
            pairs = zip(np.split(y, cuts), np.split(temp, cuts), strict=True)
            for k, (part, t) in enumerate(pairs):
                if k:
                    part, t = part[1:], t[1:]
                    self.gap()
                if part.shape[0]:
                    self.feed(part, t)
            return
        idx = np.floor(temp / self.width).astype(np.int64)
        cuts = np.flatnonzero(np.diff(idx)) + 1
        for part, t_idx in zip(np.split(y, cuts), np.split(idx, cuts), strict=True):
            b = int(t_idx[0])
            if b not in self.bins:
                self.bins[b] = _Bin(StreamingAllan(self.rate, 6, self.m), np.zeros(3))
            acc = self.bins[b]
            if self._last != b:
                acc.acc.gap()  # a new visit: a new stretch of this bin's estimate
            acc.acc.feed(part)
            acc.gyro_sum += part[:, 0:3].sum(axis=0)
            acc.n += part.shape[0]
            self._last = b

    def results(self) -> list[tuple[float, float, int, F64, list[AxisFit] | None]]:
        """Per bin, coolest first: (low edge, high edge, samples, mean gyro (3,), the six axes'
        fits, or None when the bin has too few samples for one tau)."""
        out = []
        for b in sorted(self.bins):
            x = self.bins[b]
            r = x.acc.result()
            fits = fit(r) if r.tau_s.size else None
            out.append((b * self.width, (b + 1) * self.width, x.n, x.gyro_sum / max(x.n, 1), fits))
        return out
