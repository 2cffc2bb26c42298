"""A sensor's white noise measured from the still parts of a calibration recording, for the
covariances of its ROS 2 messages (docs/ros2.md "Covariances", docs/calibration.md "noise").

Each still interval's mean comes with the covariance C of that mean from the data's own noise
(block averaging, imud/calib/still.py: right for coloured noise). For white noise of one-sided
density D a T-second mean has variance D^2 / (2 T), so each interval gives, per axis,

    D^2 = 2 T diag(M C M^T),

with M the calibration's matrix (the published output is M (raw - b), so its noise is M's image
of the raw noise). The intervals are pooled weighted by their length (a longer one has more
independent blocks). The convention is the one `imud.ros2.covariance` reads a datasheet density
in, and the one Allan deviation gives (sigma_A(tau)^2 = D^2 / (2 tau) for white noise). Slower
noise (bias instability, temperature) inside an interval raises the estimate: a still
interval's mean error is what it measures, never less.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from imud.calib.still import StillInterval

F64 = npt.NDArray[np.float64]
MIN_STILL_S = 10.0  # below this the pooled variance is too uncertain to replace a datasheet's


@dataclass(frozen=True)
class MeasuredNoise:
    density: F64  # (3,) one-sided, per axis of the corrected output, unit/sqrt(Hz)
    still_s: float  # total still time it came from
    intervals: int


def measured_density(
    intervals: Sequence[StillInterval],
    sensor: Literal["accel", "gyro"],
    rate_hz: float,
    matrix: F64 | None = None,
) -> MeasuredNoise | None:
    """The pooled white-noise density of `sensor` over `intervals`; None when they hold less
    than MIN_STILL_S seconds of still data (the reason is then the caller's to report)."""
    if rate_hz <= 0:
        return None
    m = np.eye(3) if matrix is None else np.asarray(matrix, dtype=np.float64)
    total = 0.0
    acc = np.zeros(3)
    for iv in intervals:
        t = iv.n / rate_hz
        c = iv.accel_cov if sensor == "accel" else iv.gyro_cov
        acc += t * (2.0 * t * np.diag(m @ c @ m.T))
        total += t
    if total < MIN_STILL_S or not np.all(np.isfinite(acc)) or not np.all(acc > 0):
        return None
    return MeasuredNoise(np.sqrt(acc / total), total, len(intervals))


def shortfall(intervals: Sequence[StillInterval], rate_hz: float) -> str:
    """Why `measured_density` gave nothing, in one sentence with the fix."""
    still = sum(iv.n for iv in intervals) / rate_hz if rate_hz > 0 else 0.0
    return (
        f"noise not measured: {still:.1f} s of still data, {MIN_STILL_S:g} s needed (hold the "
        "sensor still longer; its ROS 2 covariances keep the datasheet's figures)"
    )
