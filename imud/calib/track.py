"""Gyro-bias tracking while still: a slow correction of the residual gyro bias, learned only
from windows in which the device is judged not to move.

A MEMS gyro's bias wanders after calibration (bias instability, ageing, a temperature the
calibration did not cover). Whenever the device rests, the gyro's mean over the rest *is* its
bias, so a daemon can keep re-learning it. The danger is learning motion as bias: a slow turn
becomes a permanent drift in everything downstream. So a window is used only when every test
below says still, and the tests are made against the noise measured from the data, not fixed
thresholds in rad/s that suit one chip and no other:

1. Gyro and accel variance (summed over axes) within the window are near the quietest seen
   recently (the noise floor): motion, vibration or handling raise them.
2. The window's accel mean agrees with the mean of the still run it would extend (every window
   since the run began), and its gyro mean with the previous window's, within their standard
   errors (chi-squared tests, 3 degrees of freedom, p = 1e-4; a standard error is the window's
   variance / m times the noise's long-run factor, learned from still windows: a chip's
   low-pass filter correlates neighbouring samples, so means scatter more). A slow rotation about a
   horizontal axis adds no variance, but turns gravity in the body frame: against the run's
   mean the change accumulates until it shows. The gyro is compared window to window only: its
   bias may drift with temperature during a run, and that drift is what is being tracked.
3. A window's gyro mean is learned only once `confirm_s` more of the same run have passed both
   tests: a rotation too slow to show in one window shows within that horizon, and the run's
   unconfirmed windows are then dropped. Only turns about a horizontal axis slower than about
   2 x 4.6 sigma_a / (g sqrt(m) confirm_s) can leak: 0.02 deg/s for an MPU6050 at 200 Hz with
   1-s windows and 10 s of confirmation (on synthetic data 0.05 deg/s is never learned and
   0.01 deg/s mostly is), below a MEMS
   gyro's own bias instability.
4. The gyro mean is within `max_rate_rad_s` of zero (after calibration): a constant rotation
   about the vertical changes neither variance nor gravity, and only a magnitude bound can keep
   it out. That bound is the one fixed number here, and it is the user's to set.

The tracked bias is an exponential average of the confirmed windows' gyro means, with the
configured time constant: the published gyro (and delta angle) is corrected by the value held
at the start of each batch, so a batch is corrected by one number and the correction is causal.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np
import numpy.typing as npt

from imud.compiled import load
from imud.settings import GyroBiasTracking

F64 = npt.NDArray[np.float64]
_kernels = load("imud._kernels")  # the windows' statistics in one call a batch, when built

CHI2_3DOF_P1E4 = 21.108  # chi-squared quantile, 3 degrees of freedom, upper tail 1e-4
LEARN_WINDOWS = 10  # windows seen before a floor is trusted
MIN_WINDOW = 8  # samples: below this a window's variance says nothing
FLOOR_DOUBLING_S = 600.0  # the floor may rise by 2x in this time (noise changes with temperature)


class TrackState(StrEnum):
    LEARNING = "learning"  # too few windows yet to know the noise floor
    STILL = "still"  # the last window was still: the estimate moved toward it
    MOVING = "moving"  # the last window moved (variance or mean change)
    BEYOND_LIMIT = "beyond_limit"  # still, but its mean gyro exceeds max_rate_rad_s
    NO_DATA = "no_data"  # the last window had invalid samples


def variance_factor(m: int) -> float:
    """How far above the noise floor a window's summed variance may be and still count as
    still. The floor is the lowest of many window variances (biased low by about 3 standard
    errors of one), the window's own has a relative standard error sqrt(2 / (3 (m - 1))) (a
    chi-squared of 3(m-1) degrees of freedom): allow 4 of those above the truth."""
    se = math.sqrt(2.0 / (3.0 * (m - 1)))
    return (1.0 + 4.0 * se) / max(1.0 - 3.0 * se, 0.25)


@dataclass
class _Stats:
    """Sums over windows: enough for the mean of a run and the window's own mean and variance."""

    g_mean: F64
    g_var: F64
    a_mean: F64 | None
    a_var: F64 | None
    m: int  # samples
    g_ratio: float = 1.0  # this window's long-run variance ratio (`long_run_ratio`)
    a_ratio: float = 1.0

    def merged(self, w: _Stats) -> _Stats:
        """This run's mean extended by window `w` (variances: the window's own, for the test)."""
        n = self.m + w.m
        g = (self.g_mean * self.m + w.g_mean * w.m) / n
        a = None
        if self.a_mean is not None and w.a_mean is not None:
            a = (self.a_mean * self.m + w.a_mean * w.m) / n
        return _Stats(g, w.g_var, a, w.a_var, n)


BLOCKS = 8  # a window's block means, for the long-run variance of its mean
# a finished window's statistics as a row (the kernel's layout, imud/_kernels.c TR_*): whether
# it had no invalid value, whether it had the accelerometer throughout, the gyro's mean and
# variance per axis, the accelerometer's, and their long-run variance ratios
ROW = 16
_STATE = 70  # the kernel's running window (TW_STATE doubles)
CORR_GAIN = 0.1  # how fast the learned correlation factor follows new still windows


def long_run_ratio(x: F64) -> F64:
    """Per window of `x` (windows, samples, axes): the variance of its mean over what the sample
    variance alone predicts (batch means over `BLOCKS` blocks, axes pooled). A chip's low-pass
    filter correlates neighbouring samples' noise, so a window's mean scatters more than
    variance / m: 1 for white noise, about rate / (2 x noise bandwidth) behind a filter."""
    k, m, _ = x.shape
    if m < 4 * BLOCKS:
        return np.ones(k)
    b = m // BLOCKS
    means = x[:, : b * BLOCKS].reshape(k, BLOCKS, b, -1).mean(axis=2)
    long_run = means.var(axis=1, ddof=1).sum(axis=1) * b
    out: F64 = long_run / np.maximum(x.var(axis=1, ddof=1).sum(axis=1), 1e-30)
    return out


def _chi2(d: F64, var: F64, scale: float) -> float:
    return float(np.sum(d * d / (np.maximum(var, 1e-30) * scale)))


def _mean_change(
    run: _Stats, prev: _Stats, w: _Stats, corr: tuple[float, float]
) -> tuple[float, float]:
    """Chi-squared statistics (3 dof each), with the window's own variance as the noise (times
    the learned correlation factors `corr`, gyro and accel): of its gyro mean against the
    previous window's (a turn starting or stopping; the bias itself may drift with temperature
    over a run, and that is what is being tracked), and of its accel mean against the whole
    run's (a slow tilt accumulates; 0 when there is no accel)."""
    chi_g = _chi2(w.g_mean - prev.g_mean, w.g_var * corr[0], 1.0 / w.m + 1.0 / prev.m)
    chi_a = 0.0
    if w.a_mean is not None and run.a_mean is not None and w.a_var is not None:
        chi_a = _chi2(w.a_mean - run.a_mean, w.a_var * corr[1], 1.0 / w.m + 1.0 / run.m)
    return chi_g, chi_a


class GyroBiasTracker:
    """The tracker's state, fed one batch of corrected samples at a time."""

    def __init__(self, settings: GyroBiasTracking) -> None:
        self.settings = settings
        self.bias = np.zeros(3)  # rad/s, subtracted from the (calibrated) gyro
        self.state = TrackState.LEARNING
        self.windows = 0
        self.still_windows = 0  # windows that passed the stillness tests
        self.learned_windows = 0  # of which confirmed and learned
        # the twin's samples not yet in a window (with None for a batch without accelerometer)
        self._pending_g: list[F64] = []
        self._pending_a: list[F64 | None] = []
        self._pending_n = 0
        # the kernel's running window (its sums) and the rows it writes finished windows into
        self._state = np.zeros(_STATE)
        self._out = np.empty((4, ROW))
        self._floor_g: float | None = None
        self._floor_a: float | None = None
        # the noise's long-run variance factors (gyro, accel), learned from still windows
        self._corr: tuple[float, float] | None = None
        self._run: _Stats | None = None  # the current still run's means
        self._prev: _Stats | None = None  # its last window
        # its windows' gyro means and the variances of those means, oldest first
        self._unconfirmed: list[tuple[F64, F64]] = []
        # set: a confirmed window goes to it (mean, variance of the mean) instead of into the
        # average here, and `bias` is whatever its owner says (the orientation filter's
        # estimate: one bias, not two)
        self.sink: Callable[[F64, F64], None] | None = None

    def reset(self) -> None:
        """A new calibration was loaded: what was learned was relative to the old one."""
        self.bias = np.zeros(3)
        self._run, self._prev, self._unconfirmed = None, None, []

    def correct(self, gyro: F64, accel: F64 | None, period_s: float) -> F64:
        """The batch's gyro with the current estimate removed; then learn from the batch."""
        out = gyro - self.bias if self.bias.any() else gyro
        self._feed(gyro, accel, period_s)
        return out

    def observe(self, gyro: F64, accel: F64 | None, period_s: float) -> None:
        """Learn from the batch alone (its stillness tests, for an owner that corrects the gyro
        itself)."""
        self._feed(gyro, accel, period_s)

    # --- learning -------------------------------------------------------------------------
    def _feed(self, gyro: F64, accel: F64 | None, period_s: float) -> None:
        m = max(MIN_WINDOW, round(self.settings.window_s / period_s))
        if _kernels is not None:
            rows = self._windows(gyro, accel, m)
        else:
            rows = self._windows_numpy(gyro, accel, m)
        if not rows:
            return
        rise = 2.0 ** (m * period_s / FLOOR_DOUBLING_S)
        gain = 1.0 - math.exp(-m * period_s / self.settings.time_constant_s)
        confirm = math.ceil(self.settings.confirm_s / (m * period_s) - 1e-9)
        for row in rows:  # a handful of windows per batch at most
            self.windows += 1
            if not row[0]:
                self.state, self._unconfirmed = TrackState.NO_DATA, []
                self._run = self._prev = None
                continue
            accel_seen = bool(row[1])
            w = _Stats(
                np.array(row[2:5]),
                np.array(row[5:8]),
                np.array(row[8:11]) if accel_seen else None,
                np.array(row[11:14]) if accel_seen else None,
                m,
                row[14],
                row[15],
            )
            self._judge(w, rise, gain, confirm)

    def _windows(self, gyro: F64, accel: F64 | None, m: int) -> list[list[float]]:
        """The windows this batch completes, as rows (`ROW`), from the compiled kernel, which
        keeps the running window's sums instead of the samples."""
        assert _kernels is not None
        cap = gyro.shape[0] // m + 1
        if self._out.shape[0] < cap:
            self._out = np.empty((cap, ROW))
        try:  # float64 rows are read in place
            k: int = _kernels.track_windows(gyro, accel, m, self._state, self._out)
        except (TypeError, ValueError, BufferError):  # another dtype or layout: a copy
            g = np.ascontiguousarray(gyro, dtype=np.float64)
            a = None if accel is None else np.ascontiguousarray(accel, dtype=np.float64)
            k = _kernels.track_windows(g, a, m, self._state, self._out)
        if not k:  # most batches: the window goes on
            return []
        rows: list[list[float]] = self._out[:k].tolist()
        return rows

    def _windows_numpy(self, gyro: F64, accel: F64 | None, m: int) -> list[list[float]]:
        """`_windows` in NumPy: the kernel's twin and reference. A window has accelerometer
        statistics only if every batch of it had an accelerometer."""
        self._pending_g.append(gyro)
        self._pending_a.append(accel)
        self._pending_n += gyro.shape[0]
        if self._pending_n < m:
            return []
        g = np.concatenate(self._pending_g)
        have = [a is not None for a in self._pending_a]
        a = np.concatenate([x for x in self._pending_a if x is not None]) if all(have) else None
        k = g.shape[0] // m
        used = k * m
        rest_g = g[used:]
        # what is left over starts the next window; its accelerometer only if it all had one
        rest_a = a[used:] if a is not None else None
        self._pending_g, self._pending_a = [rest_g], [rest_a]
        self._pending_n = rest_g.shape[0]
        gw = g[:used].reshape(k, m, 3)
        aw = a[:used].reshape(k, m, 3) if a is not None else None
        bad = np.count_nonzero(~np.isfinite(gw.reshape(k, -1)), axis=1)
        if aw is not None:
            bad = bad + np.count_nonzero(~np.isfinite(aw.reshape(k, -1)), axis=1)
        rows = np.zeros((k, ROW))
        rows[:, 0] = bad == 0
        rows[:, 2:5] = gw.mean(axis=1)
        rows[:, 5:8] = gw.var(axis=1, ddof=1)
        rows[:, 14] = long_run_ratio(gw)
        rows[:, 15] = 1.0
        if aw is not None:
            rows[:, 1] = 1.0
            rows[:, 8:11] = aw.mean(axis=1)
            rows[:, 11:14] = aw.var(axis=1, ddof=1)
            rows[:, 15] = long_run_ratio(aw)
        out: list[list[float]] = rows.tolist()
        return out

    def _quiet(self, w: _Stats, rise: float) -> bool:
        """Test 1, after updating the noise floors with this window."""
        vg = float(w.g_var.sum())
        self._floor_g = vg if self._floor_g is None else min(vg, self._floor_g * rise)
        quiet = vg <= variance_factor(w.m) * self._floor_g
        if w.a_var is not None:
            va = float(w.a_var.sum())
            self._floor_a = va if self._floor_a is None else min(va, self._floor_a * rise)
            quiet = quiet and va <= variance_factor(w.m) * self._floor_a
        return quiet

    def _learn_corr(self, w: _Stats) -> None:
        """Follow the noise's correlation factors with a window judged still (at least 1: a
        factor below white noise's is a window's chance)."""
        r = (max(1.0, w.g_ratio), max(1.0, w.a_ratio))
        c = self._corr or r
        self._corr = (c[0] + CORR_GAIN * (r[0] - c[0]), c[1] + CORR_GAIN * (r[1] - c[1]))

    def _judge(self, w: _Stats, rise: float, gain: float, confirm: int) -> None:
        quiet = self._quiet(w, rise)
        if self.windows <= LEARN_WINDOWS:
            self.state = TrackState.LEARNING
            if quiet:
                self._learn_corr(w)
            return
        run, prev = self._run, self._prev
        if not quiet:
            self.state, self._unconfirmed = TrackState.MOVING, []
            self._run = self._prev = None
            return
        self._prev = w
        if run is not None and prev is not None:
            chi_g, chi_a = _mean_change(run, prev, w, self._corr or (1.0, 1.0))
            if chi_g > CHI2_3DOF_P1E4 or chi_a > CHI2_3DOF_P1E4:
                # the run has ended (it was turning, or something moved it): drop what it has
                # not confirmed, and start a new run at this window
                self.state, self._run, self._unconfirmed = TrackState.MOVING, w, []
                return
        self._run = w if run is None else run.merged(w)
        self._learn_corr(w)
        self.still_windows += 1
        if float(np.max(np.abs(w.g_mean))) > self.settings.max_rate_rad_s:
            self.state = TrackState.BEYOND_LIMIT
            self._unconfirmed = []
            return
        self.state = TrackState.STILL
        corr = self._corr[0] if self._corr is not None else 1.0
        self._unconfirmed.append((w.g_mean, w.g_var * corr / w.m))
        while len(self._unconfirmed) > confirm:
            mean, var = self._unconfirmed.pop(0)
            if self.sink is not None:
                self.sink(mean, var)
            else:
                self.bias = self.bias + gain * (mean - self.bias)
            self.learned_windows += 1

    def status(self) -> dict[str, Any]:
        return {
            "state": self.state,
            "bias_rad_s": [round(float(b), 7) for b in self.bias],
            "windows": self.windows,
            "still_windows": self.still_windows,
            "learned_windows": self.learned_windows,
        }
