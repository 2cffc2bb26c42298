"""The covariances of a device's ROS 2 messages, from its white noise (docs/ros2.md "Covariances").

A chip's spec states, for the device's configured settings, each sensor's one-sided noise density
D and the noise-equivalent bandwidth B of one sample (`imud.chips.api.NoiseFigures`), so one
sample's variance is

    var_1 = D^2 B.

A message is the mean of k consecutive samples (`imud.ros2.decimate`, k = ceil(odr / rate)),
whose variance depends on how alike neighbouring samples are. The chip's filter is modelled as a
first-order low-pass of that noise bandwidth (its 3 dB corner fc = 2 B / pi), whose samples at
the output rate correlate as rho(m) = exp(-2 pi fc m / odr), and then

    var_k = var_1 / k^2 * sum_{m=-(k-1)}^{k-1} (k - |m|) rho(|m|).

For k = 1 it is var_1; for a long mean (T = k / odr seconds) of a band well below the output's
Nyquist it tends to D^2 / (2 T), the one-sided density's low-frequency limit, whatever the filter.
A band near the Nyquist keeps some correlation between neighbours in this model where the chip's
samples have little: a long mean's variance comes out high, by (1 + e^-2) / (1 - e^-2) = 1.31 at
B = odr / 2 (a covariance on the safe side). A magnetometer slower than the published
rate repeats each reading for `mag_hold` samples: its correlation is the hold's overlap,
rho(m) = max(0, 1 - m / hold). Axes are taken independent and alike: a diagonal 3x3 matrix,
row-major, as sensor_msgs wants it.

A calibration file that carries measured noise (imud/calib/noise.py: per-axis densities from
its still data) replaces the datasheet's density, axis by axis; the chip's bandwidth and the
correlation model stay. A chip whose spec states no noise, and no measured noise, keeps REP-145's
"unknown": all zeros. Pure functions: the output
computes them once per device when it builds the device's publishers, never per message.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from imud.chips.api import NoiseFigures

F64 = npt.NDArray[np.float64]
UNKNOWN = np.zeros(9)  # REP-145: covariance not known


def sample_variance(density: float, bandwidth_hz: float) -> float:
    """One sample's variance: a one-sided density over its noise-equivalent bandwidth."""
    return density * density * bandwidth_hz


def first_order_correlation(bandwidth_hz: float, odr_hz: float, lags: npt.ArrayLike) -> F64:
    """rho(m) of a first-order low-pass of noise bandwidth B sampled at odr: its 3 dB corner is
    fc = 2 B / pi (a first-order filter's noise bandwidth is pi/2 times its corner)."""
    fc = 2.0 * bandwidth_hz / math.pi
    out: F64 = np.exp(-2.0 * math.pi * fc * np.abs(np.asarray(lags, dtype=np.float64)) / odr_hz)
    return out


def held_correlation(hold: int, lags: npt.ArrayLike) -> F64:
    """rho(m) of independent readings each repeated `hold` times, at a random phase."""
    out: F64 = np.clip(1.0 - np.abs(np.asarray(lags, dtype=np.float64)) / hold, 0.0, None)
    return out


def mean_variance(var_1: float, k: int, rho: npt.ArrayLike) -> float:
    """The variance of the mean of k consecutive samples of variance var_1 whose correlation at
    lag m is rho[m] (m = 0 .. k-1): var_1 / k^2 * sum over every pair of samples."""
    r = np.asarray(rho, dtype=np.float64)[:k]
    if k < 1 or r.shape[0] != k:
        raise ValueError(f"need rho at lags 0 .. {k - 1}, got {r.shape[0]} values")
    m = np.arange(k)
    pairs = np.where(m == 0, k, 2 * (k - m))  # lag 0 once per sample, every other lag both ways
    return var_1 / (k * k) * float(np.dot(pairs, r))


def diagonal(variance: float) -> F64:
    """A 3x3 diagonal covariance with `variance` on every axis, flat (9,) row-major."""
    out = np.zeros(9)
    out[[0, 4, 8]] = variance
    return out


@dataclass(frozen=True)
class Covariances:
    """What a device's messages carry, each a flat (9,) float64 array."""

    accel: F64
    gyro: F64
    mag: F64


def covariances(
    noise: NoiseFigures | None,
    odr_hz: float,
    k: int,
    measured: dict[str, F64] | None = None,
) -> Covariances:
    """A device's covariances for messages that average k samples of its odr_hz stream.
    `measured`: per sensor ("accel", "gyro"), the (3,) densities a calibration file measured
    (imud/calib/noise.py), used per axis in place of the datasheet's; their bandwidth is the
    chip's at its settings, or the output's Nyquist when its spec states none."""
    measured = measured or {}
    lags = np.arange(k)

    def sensor(name: str, density: float | None, bandwidth_hz: float | None) -> F64:
        axes = measured.get(name)
        if axes is None and density is None:
            return UNKNOWN
        b = bandwidth_hz if bandwidth_hz is not None else odr_hz / 2.0
        rho = first_order_correlation(b, odr_hz, lags)
        d = np.broadcast_to(np.asarray(density if axes is None else axes, dtype=np.float64), 3)
        out = np.zeros(9)
        out[[0, 4, 8]] = [mean_variance(sample_variance(float(x), b), k, rho) for x in d]
        return out

    mag = UNKNOWN
    if noise is not None and noise.mag_sigma_t is not None:
        rho = held_correlation(noise.mag_hold, lags)
        mag = diagonal(mean_variance(noise.mag_sigma_t**2, k, rho))
    if noise is None:
        return Covariances(sensor("accel", None, None), sensor("gyro", None, None), mag)
    return Covariances(
        accel=sensor("accel", noise.accel_density, noise.accel_bandwidth_hz),
        gyro=sensor("gyro", noise.gyro_density, noise.gyro_bandwidth_hz),
        mag=mag,
    )
