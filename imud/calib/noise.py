"""A sensor's white noise measured in the still parts of a calibration recording, for the
covariances of its ROS 2 messages (docs/ros2.md "Covariances", docs/calibration.md "noise").

A ROS message averages a few milliseconds of samples, so what its covariance needs is the white
noise at short averaging times, not the error of a still pose's mean (which also holds the
sensor's slow wander: on imu_tk's real Xsens recording the z accelerometer's 50 s mean is 2.7
times noisier than its white noise says). So each still interval is cut into blocks of
TAU_S seconds and the two-sample (Allan) variance of consecutive block means is taken,

    AVAR(tau) = < (m_{i+1} - m_i)^2 > / 2,

pooled over every interval (differences never span two intervals). For white noise of one-sided
density D, AVAR(tau) = D^2 / (2 tau), so D = sqrt(2 tau AVAR(tau)): the convention
`imud.ros2.covariance` reads a datasheet density in. tau is long against any MEMS output
filter's correlation time (a 100 ms block of a 5 Hz filter's output still holds a little of it,
the slowest any chip here offers) and short against temperature and bias wander. The samples are
first mapped through the calibration's matrix: the published output's noise is its image.

One tau and one formula, written out here: allantools (the tests check against it) would bring
SciPy, matplotlib, numpydoc and pytest into the daemon's install.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from imud.calib.recording import Recording
from imud.calib.still import StillInterval

F64 = npt.NDArray[np.float64]
TAU_S = 0.1  # the averaging time of the two-sample variance
MIN_BLOCK = 2  # samples per block at the least (a slow recording)
MIN_DIFFERENCES = 100  # ~14 % on the variance; fewer: keep the datasheet's figure


@dataclass(frozen=True)
class MeasuredNoise:
    density: F64  # (3,) one-sided, per axis of the corrected output, unit/sqrt(Hz)
    tau_s: float  # the averaging time it was measured at
    differences: int  # how many block-mean differences it pools
    still_s: float  # the still time it came from


def measured_density(
    rec: Recording,
    intervals: Sequence[StillInterval],
    sensor: Literal["accel", "gyro"],
    matrix: F64 | None = None,
) -> MeasuredNoise | None:
    """The white-noise density of `sensor` over the still `intervals` of `rec`; None when they
    hold fewer than MIN_DIFFERENCES block differences (`shortfall` says so)."""
    rate = rec.rate_hz
    if rate <= 0:
        return None
    block = max(MIN_BLOCK, round(TAU_S * rate))
    m = np.eye(3) if matrix is None else np.asarray(matrix, dtype=np.float64)
    data = rec.accel if sensor == "accel" else rec.gyro
    squares = np.zeros(3)
    count = 0
    for iv in intervals:
        blocks = (iv.end - iv.start) // block
        if blocks < 2:
            continue
        x = data[iv.start : iv.start + blocks * block] @ m.T
        means = x.reshape(blocks, block, 3).mean(axis=1)
        d = np.diff(means, axis=0)
        squares += np.einsum("nk,nk->k", d, d)
        count += blocks - 1
    if count < MIN_DIFFERENCES:
        return None
    tau = block / rate
    avar = squares / (2.0 * count)
    if not np.all(np.isfinite(avar)) or not np.all(avar > 0):
        return None
    still = sum(iv.n for iv in intervals) / rate
    return MeasuredNoise(np.sqrt(2.0 * tau * avar), tau, count, still)


def shortfall(intervals: Sequence[StillInterval], rate_hz: float) -> str:
    """Why `measured_density` gave nothing, in one sentence with the fix."""
    still = sum(iv.n for iv in intervals) / rate_hz if rate_hz > 0 else 0.0
    need = MIN_DIFFERENCES * TAU_S
    return (
        f"noise not measured: {still:.1f} s of still data, about {need:g} s needed (hold the "
        "sensor still longer; its ROS 2 covariances keep the datasheet's figures)"
    )
