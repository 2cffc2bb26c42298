"""The orientation stage of a device's pipeline: its filter (imud.orient.ekf) fed the calibrated
batches, bridged across lost samples, taught by the gyro-bias tracker's still windows, and the
tracker's bias made the filter's (one estimate, not two)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from imud.calib.track import GyroBiasTracker
from imud.channels import Channel
from imud.orient.ekf import NoiseModel, OrientationFilter, OrientState
from imud.settings import GyroBiasTracking, Orientation

F64 = npt.NDArray[np.float64]

BRIDGE_MAX_S = 1.0  # lost samples up to this long are bridged with the next sample's rate
# a chip whose datasheet states no noise: a consumer MEMS part's (MPU6050-class) figures
DEFAULT_GYRO_DENSITY = math.radians(0.01)  # rad/s/sqrt(Hz)
DEFAULT_ACCEL_DENSITY = 4e-3  # m/s^2/sqrt(Hz)


def noise_model(
    gyro_density: float | None,
    accel_density: float | None,
    mag_sigma: float | None,
    bias_walk: float,
) -> NoiseModel:
    """The filter's noise from a datasheet's one-sided densities (their low-frequency two-sided
    level is density / sqrt(2), what integration and averaging see)."""
    g = DEFAULT_GYRO_DENSITY if gyro_density is None else gyro_density
    a = DEFAULT_ACCEL_DENSITY if accel_density is None else accel_density
    return NoiseModel(g / math.sqrt(2.0), a / math.sqrt(2.0), bias_walk, mag_sigma)


class OrientationStage:
    """One device's orientation. `tracker` is the pipeline's gyro-bias tracker when gyro-bias
    tracking is on (its still windows teach the filter and the published gyro is corrected by
    the filter's bias); without it the stage keeps a tracker of its own for the stillness
    tests alone."""

    def __init__(
        self,
        settings: Orientation,
        noise: NoiseModel,
        tracker: GyroBiasTracker | None,
        stillness: GyroBiasTracking | None = None,
    ) -> None:
        self.settings = settings
        self.noise = noise
        self.filter = self._new_filter()
        self.shared = tracker is not None
        # without tracking: the tracker's stillness tests, with the device's settings for them
        own = GyroBiasTracker(stillness if stillness is not None else GyroBiasTracking())
        self.tracker = tracker if tracker is not None else own
        self.tracker.sink = self._zero_rate
        self.restarts = 0

    def _new_filter(self) -> OrientationFilter:
        s = self.settings
        return OrientationFilter(
            self.noise,
            update_hz=s.update_hz,
            bias_sigma=s.gyro_bias_sigma_rad_s,
            use_mag=s.magnetometer,
            declination_rad=math.radians(s.declination_deg),
            init_s=s.start_s,
            linear_max=s.linear_accel_max_m_s2,
        )

    def _zero_rate(self, mean: F64, var: F64) -> None:
        self.filter.zero_rate(mean, var)

    def reset_bias(self) -> None:
        """A new calibration: the bias learned was relative to the old one."""
        self.filter.reset_bias(self.settings.gyro_bias_sigma_rad_s)

    def run(
        self, channels: dict[Channel, F64], period_s: float, lost_before: int
    ) -> dict[Channel, F64]:
        """`channels` (calibrated, not yet corrected by the tracked bias) with the orientation and
        its covariance added; NaN where the filter has not started."""
        gyro = channels.get(Channel.GYRO)
        if gyro is None or gyro.shape[0] == 0:
            return channels
        accel = channels.get(Channel.ACCEL)
        mag = channels.get(Channel.MAG)
        f = self.filter
        if lost_before and f.state is not OrientState.INITIALISING:
            if lost_before * period_s > BRIDGE_MAX_S:
                # too long to bridge: the platform may have turned any way meanwhile
                self.filter = f = self._new_filter()
                self.restarts += 1
            else:
                f.step(np.repeat(gyro[:1], lost_before, axis=0), None, period_s)
        q, cov = f.step(gyro, accel, period_s, None if mag is None else mag)
        if not self.shared:
            self.tracker.observe(gyro, accel, period_s)  # its stillness tests alone
        else:
            # the published gyro is corrected by the filter's bias: the tracker's is the same
            self.tracker.bias = f.b.copy()
        out = dict(channels)
        out[Channel.ORIENTATION] = q
        out[Channel.ORIENTATION_COVARIANCE] = cov
        return out

    def status(self) -> dict[str, Any]:
        f = self.filter
        c = f.counters
        return {
            "state": f.state,
            "bias_rad_s": [round(float(b), 7) for b in f.b],
            "heading": "magnetic" if f.heading_known else "relative to the start",
            "linear_accel_sigma_m_s2": round(math.sqrt(f.linear_var), 4),
            "accel_updates": c.accel_updates,
            "accel_rejected": c.accel_rejected,
            "mag_updates": c.mag_updates,
            "mag_rejected": c.mag_rejected,
            "still_updates": c.zero_rate_updates,
            "restarts": self.restarts,
        }
