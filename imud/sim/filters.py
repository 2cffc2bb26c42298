"""The chips' digital low-pass filters, as the simulators model them: a delay and a colouring.

A chip's configured low-pass filter delays every sample by a documented group delay and narrows
its noise to the filter's band. The simulators model each filter as a linear-phase FIR on the
chip's internal sample grid (a truncated Gaussian: no ringing, a flat group delay, one width
parameter) followed by a pure delay:

- the FIR is as long as the documented delay allows (its own delay, (L - 1)/2 internal samples, is
  at most the documented one) and its width is set so that its noise-equivalent bandwidth is the
  datasheet's; the rest of the documented delay is a pure delay of the motion, so the output at
  latch time t is the motion around t - delay, exactly (the motion is a function of time);
- the same FIR filters the white noise, which is drawn on the internal grid with the one-sided
  density convention: per internal sample sigma = density * sqrt(f_int / 2), so the filtered
  noise has RMS density * sqrt(ENBW) and low-frequency one-sided density `density` (Allan
  N = density / sqrt(2): `docs/timestamps.md`);
- an output rate below the internal rate keeps every m-th filtered internal sample (decimation,
  as the chips do).

A linear-phase FIR with the datasheet's delay cannot always reach the datasheet's bandwidth: a
non-negative impulse response of mean delay d has a noise bandwidth of at least about 0.22/d, so
e.g. the MPU6050's "5 Hz, 18.6 ms" row is a filter whose noise band is wider than 5 Hz. There the
FIR is the boxcar of that length (the narrowest it can be): the delay, which stamps depend on, is
always the documented one; the noise bandwidth then is the model's (`SensorFilter.enbw_hz`).

Where a chip's filter delay is not published, its band limit colours the noise only
(`SensorFilter.pre`, `enbw_fir`): the motion passes undelayed and the declared delay stays 0. A
simulator with its own sample path (a window of documented length, like `bartlett_taps`) draws
its noise with `NoiseStream`.

Hot path: NumPy only, one `np.convolve` per axis and chunk, the last L - 1 internal noise
samples carried between chunks; the motion is re-evaluated for the L - 1 internal instants
before a chunk (it is a pure function of time, so nothing of it needs carrying).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from imud.sim.chip import STAGE_NS, Measured, SampledChip

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


def gaussian_fir(length: int, enbw_hz: float, rate_hz: float) -> F64:
    """A symmetric FIR of `length` taps, unit DC gain, whose one-sided noise-equivalent bandwidth
    (rate/2 * sum h^2) is `enbw_hz` when a truncated Gaussian of that length can have it: the
    boxcar (the narrowest) or the narrowest Gaussian of the length otherwise."""
    if length <= 1:
        return np.ones(1)
    k = np.arange(length) - (length - 1) / 2
    target = 2.0 * enbw_hz / rate_hz  # sum h^2 wanted

    def taps(width: float) -> F64:
        h = np.exp(-0.5 * (k / width) ** 2)
        out: F64 = h / h.sum()
        return out

    if target <= 1.0 / length:
        return np.full(length, 1.0 / length)  # the boxcar: nothing of this length is narrower
    lo, hi = 0.1, 1e3 * length  # sum h^2 falls as the width grows
    if float((taps(lo) ** 2).sum()) <= target:
        return taps(lo)
    for _ in range(80):
        mid = math.sqrt(lo * hi)
        if float((taps(mid) ** 2).sum()) > target:
            lo = mid
        else:
            hi = mid
    return taps(math.sqrt(lo * hi))


def enbw_fir(enbw_hz: float, rate_hz: float) -> F64:
    """A symmetric FIR of unit DC gain whose one-sided noise-equivalent bandwidth on a grid of
    `rate_hz` is `enbw_hz` (a Gaussian about twice as long as the boxcar of that bandwidth), or
    the identity when the band reaches Nyquist. For colouring noise only: a sensor's band limit
    whose delay is not published."""
    target = 2.0 * enbw_hz / rate_hz
    if target >= 1.0:
        return np.ones(1)
    return gaussian_fir(2 * math.ceil(1.0 / target) + 1, enbw_hz, rate_hz)


def bartlett_taps(n: int) -> F64:
    """Two cascaded n-sample averages: the triangle of 2n - 1 taps (delay n - 1 samples)."""
    box = np.full(n, 1.0 / n)
    out: F64 = np.convolve(box, box)
    return out


@dataclass(frozen=True)
class SensorFilter:
    """One sensor's low-pass at one configuration.

    `delay_s`: the documented group delay at the nominal clock; `internal_hz`: the nominal rate
    the filter runs at; `decimation`: internal samples per output sample; `white_band_hz`: the
    one-sided band of the white noise entering the filter (default internal_hz / 2); `pre`: a
    colouring of the noise only, before `taps` (a sensor's own band limit whose delay is not
    published, so the motion does not pass it)."""

    delay_s: float
    internal_hz: float
    taps: F64
    decimation: int = 1
    white_band_hz: float | None = None
    pre: F64 | None = None

    @property
    def noise_taps(self) -> F64:
        """What the white noise passes: `pre`, then `taps`."""
        if self.pre is None or self.pre.shape[0] == 1:
            return self.taps
        out: F64 = np.convolve(self.pre, self.taps)
        return out

    @property
    def delay_samples(self) -> float:
        """The documented delay in internal samples (it scales with the chip's clock)."""
        return self.delay_s * self.internal_hz

    @property
    def fir_delay_samples(self) -> float:
        return (len(self.taps) - 1) / 2

    @property
    def band_hz(self) -> float:
        return self.white_band_hz if self.white_band_hz is not None else self.internal_hz / 2

    @property
    def enbw_hz(self) -> float:
        """One-sided noise-equivalent bandwidth of the output: RMS = density * sqrt(this)."""
        return self.band_hz * float((self.noise_taps**2).sum())


def design(
    bandwidth_hz: float,
    delay_s: float,
    internal_hz: float,
    decimation: int = 1,
    white_band_hz: float | None = None,
) -> SensorFilter:
    """A chip filter of noise bandwidth `bandwidth_hz` (the datasheet's) and documented group
    delay `delay_s`, running at `internal_hz`: the longest FIR whose own delay fits in it."""
    d = delay_s * internal_hz
    length = math.floor(2 * d + 1e-9) + 1
    band = white_band_hz if white_band_hz is not None else internal_hz / 2
    if bandwidth_hz >= band:
        length = 1  # nothing to narrow: a pure delay
    h = gaussian_fir(length, bandwidth_hz * (internal_hz / 2) / band, internal_hz)
    return SensorFilter(delay_s, internal_hz, h, max(1, decimation), white_band_hz)


class NoiseStream:
    """White noise of one-sided density D (per sample sigma = D sqrt(rate / 2)) on a grid,
    through a FIR, for a simulator that runs its own sample path; the last len(taps) - 1 white
    samples are carried between calls, so chunking does not change the noise's spectrum."""

    def __init__(self, taps: F64) -> None:
        self.taps = taps
        self.carry: F64 | None = None

    def draw(self, rng: np.random.Generator, density: float, rate_hz: float, n: int) -> F64:
        """n samples (n, 3) at `rate_hz`."""
        sigma = density * math.sqrt(rate_hz / 2)
        length = self.taps.shape[0]
        if density <= 0:
            return np.zeros((n, 3))
        if length == 1:
            return rng.normal(0.0, sigma, (n, 3))
        if self.carry is None:
            self.carry = rng.normal(0.0, sigma, (length - 1, 3))
        w = np.concatenate([self.carry, rng.normal(0.0, sigma, (n, 3))])
        self.carry = w[n:]
        out: F64 = np.stack(
            [np.convolve(w[:, a], self.taps, mode="valid") for a in range(3)], axis=1
        )
        return out


@dataclass
class _Noise:
    """Carried internal-grid noise of one sensor (3 axes)."""

    key: Any = None
    carry: F64 = field(default_factory=lambda: np.zeros((0, 3)))


class FilteredChip(SampledChip):
    """A simulated chip whose samples pass its configured low-pass filters.

    A subclass says which filters its registers configure (`filters`: accel, gyro); `_produce`
    then samples the motion on the internal grid, filters it and the noise, applies the other
    sensor errors, and records the truth at the instant the motion happened: the latch time less
    the gyro's group delay (on the chip's clock)."""

    def filters(self) -> tuple[SensorFilter, SensorFilter]:
        raise NotImplementedError

    _noise: tuple[_Noise, _Noise] | None = None
    _last_true_ns: float | None = None  # the instant the newest sample's motion happened

    def _anchor(self, now: int) -> None:
        """Restart the sample grid; after a change to a longer filter delay, the first sample
        of the new setting comes once the filter holds motion newer than the last sample's (a
        restarted filter refills), so the instants the samples stand for keep their order and
        at least a period apart."""
        super()._anchor(now)
        if self._last_true_ns is None:
            return
        period = 1e9 / self.rate_hz
        first_true = self.grid_origin_ns + period - self.group_delay_ns()
        late = self._last_true_ns + period - first_true
        if late > 0:
            self.grid_origin_ns += late

    def group_delay_ns(self) -> float:
        """The gyro's group delay in true time (ns): the documented delay on the chip's clock."""
        g = self.filters()[1]
        return g.delay_samples / (g.internal_hz * (1 + self.clock_error)) * 1e9

    def _filtered(
        self,
        f: SensorFilter,
        t_ns: I64,
        sensor: int,
        density: float,
        state: _Noise,
        motion: dict[Any, tuple[F64, F64]],
    ) -> tuple[F64, F64]:
        """The filtered true signal and the filtered noise of one sensor at latch times t_ns
        (`motion`: the motion sampled on a grid already, shared by the two sensors)."""
        n = t_ns.shape[0]
        m, h = f.decimation, f.taps
        length = h.shape[0]
        t_int = 1.0 / (self.rate_hz * m)  # true internal period, s
        pure = (f.delay_samples - f.fir_delay_samples) * t_int
        t_last = (t_ns - self.t_origin_ns) / 1e9  # latch instants, s
        # the internal instants the outputs need: a contiguous grid ending at each latch
        count = (n - 1) * m + length
        start = float(t_last[0]) - (length - 1) * t_int - pure
        key = (start, count, t_int)
        if key not in motion:
            motion[key] = self.motion.sample(start + t_int * np.arange(count))
        f_all, w_all = motion[key]
        x = w_all if sensor else f_all
        if length == 1:
            sig = x[::m]
        else:
            sig = np.stack([np.convolve(x[:, a], h, mode="valid")[::m] for a in range(3)], axis=1)
        if density <= 0:
            return sig, np.zeros((n, 3))
        return sig, self._noise_of(f, n, density, state)

    def _noise_of(self, f: SensorFilter, n: int, density: float, state: _Noise) -> F64:
        """n outputs of white noise of one-sided `density` on the internal grid through the
        filter (and its noise-only colouring), carried across chunks."""
        m, h = f.decimation, f.noise_taps
        length = h.shape[0]
        sigma = density * math.sqrt(f.band_hz)
        rng = self.errors.noise_rng
        if m >= length:  # outputs share no internal sample: independent draws
            return rng.normal(0.0, sigma * math.sqrt(float((h**2).sum())), (n, 3))
        key = (length, m, tuple(h))
        if state.key != key or state.carry.shape[0] != length - 1:
            state.key = key
            state.carry = rng.normal(0.0, sigma, (length - 1, 3))
        count = (n - 1) * m + length
        reuse = length - m  # internal samples shared with the previous chunk's last output
        fresh = rng.normal(0.0, sigma, (count - reuse, 3))
        w = np.concatenate([state.carry[state.carry.shape[0] - reuse :], fresh])
        state.carry = w[w.shape[0] - (length - 1) :]
        noise: F64 = np.stack(
            [np.convolve(w[:, a], h, mode="valid")[::m] for a in range(3)], axis=1
        )
        return noise

    stage_ns = STAGE_NS  # a FIFO chip: its samples are computed ahead (imud/sim/chip.py)

    def _compute(self, t_ns: I64) -> Measured:
        fa, fg = self.filters()
        if self._noise is None:
            self._noise = (_Noise(), _Noise())
        e = self.errors
        t_s = (t_ns - self.t_origin_ns) / 1e9
        temp = self.temp.at(t_s)
        motion: dict[Any, tuple[F64, F64]] = {}
        f_sig, f_noise = self._filtered(fa, t_ns, 0, e.accel.noise, self._noise[0], motion)
        w_sig, w_noise = self._filtered(fg, t_ns, 1, e.gyro.noise, self._noise[1], motion)
        fm = e.accel.deterministic(t_s, f_sig, temp) + f_noise
        wm = e.gyro.deterministic(t_s, w_sig, temp) + w_noise
        delay = round(self.group_delay_ns())
        t_true = t_ns - np.int64(delay)
        f: F64 | None = None
        w: F64 | None = None
        if self.record_truth:
            if delay == 0 and fa.taps.shape[0] == fg.taps.shape[0] == 1:
                f, w = f_sig, w_sig  # unfiltered, undelayed: the motion at the latches
            else:
                f, w = self.motion.sample((t_true - self.t_origin_ns) / 1e9)
        return Measured(t_ns, fm, wm, temp, t_true, f, w)

    def _reveal(self, m: Measured, i: int, j: int) -> None:
        super()._reveal(m, i, j)
        self._last_true_ns = float(m.truth_t_ns[j - 1])
