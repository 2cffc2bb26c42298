"""The ICM-42688-P's white noise: the datasheet's densities and the UI filter's bandwidth, the one
source of both for the simulator and for the ROS 2 covariances (docs/ros2.md "Covariances").

The front page's densities (low-noise mode) are taken as one-sided, as TDK's MPU6050 sheet shows
its own to be, and the UI filter code's bandwidth as the noise bandwidth (docs/chips/icm42688p.md
"Noise convention"). The anti-alias filter is not modelled: its shape is not published, and where
it is narrower than the UI filter (the default 585 Hz gyro AAF at ODR >= 4 kHz) the bandwidth
here is an upper bound."""

from __future__ import annotations

import math

from imud.chips.api import NoiseFigures
from imud.chips.icm42688p.registers import UI_FILTER_CODES
from imud.units import STANDARD_GRAVITY as G

ACCEL_NOISE_UG_RTHZ = 70.0  # DS-000347 v1.7 front page
GYRO_NOISE_DPS_RTHZ = 0.0028  # 2.8 mdps/rtHz, the same page
# UI filter code (GYRO_ACCEL_CONFIG0 nibble) -> divisor of max(400 Hz, ODR): its bandwidth in
# low-noise mode (docs/chips/icm42688p.md section 2.1); code 0 is ODR/2, the low-latency codes
# 14 and 15 narrow nothing below the output's Nyquist
UI_FILTER_DIVISOR = {1: 4, 2: 5, 3: 8, 4: 10, 5: 16, 6: 20, 7: 40}


def ui_bandwidth_hz(code: int, odr_hz: float) -> float:
    """The UI filter's bandwidth at a code and output rate. Below 400 Hz a code of 1-7 can be
    above the output's Nyquist: the filter runs at 400 Hz or more and the decimation to the
    output rate aliases its band (one sample's variance is still density^2 * this)."""
    div = UI_FILTER_DIVISOR.get(code)
    return max(400.0, odr_hz) / div if div else odr_hz / 2


def noise_figures(odr_hz: float, ui_filter: str) -> NoiseFigures:
    """At a configured rate and `ui_filter` (both sensors share it)."""
    bw = ui_bandwidth_hz(UI_FILTER_CODES[ui_filter], odr_hz)
    return NoiseFigures(
        accel_density=ACCEL_NOISE_UG_RTHZ * 1e-6 * G,
        accel_bandwidth_hz=bw,
        gyro_density=math.radians(GYRO_NOISE_DPS_RTHZ),
        gyro_bandwidth_hz=bw,
    )
