"""The STIM300's white noise: its random walks as one-sided densities and the configured filter's
bandwidth, the one source of them for the simulator and for the ROS 2 covariances (docs/ros2.md
"Covariances").

The datasheet (TS1524 rev.31, Tables 5-3 and 5-4) gives angle and velocity random walks: Allan
N, the Allan deviation's -1/2 line at 1 s (ARW deg/sqrt(h) / 60 = deg/s/sqrt(Hz)). A one-sided
density's Allan N is density / sqrt(2) (docs/timestamps.md), so the densities are sqrt(2) times
those. The filter's -3 dB frequency (`filter_hz`) is taken as the noise bandwidth, gyro and
accelerometer alike; a rate below 2000/s keeps every n-th filtered sample, which keeps the band."""

from __future__ import annotations

import math

from imud.chips.api import NoiseFigures
from imud.units import STANDARD_GRAVITY as G

ARW_DEG_RTH = 0.15  # gyro angle random walk, Table 5-3
VRW_M_S_RTH = {5: 0.024, 10: 0.024, 30: 0.04, 80: 0.15}  # per accelerometer variant, Table 5-4
GYRO_NOISE_DPS_RTHZ = ARW_DEG_RTH / 60 * math.sqrt(2)


def accel_noise_ug_rthz(range_g: int) -> float:
    """The one-sided density of an accelerometer variant (10 g: 0.024 m/s/sqrt(h) = 40.8
    ug/sqrt(Hz) of Allan N, 57.7 ug/sqrt(Hz) one-sided)."""
    return VRW_M_S_RTH[range_g] / 60 * math.sqrt(2) / G * 1e6


def noise_figures(filter_hz: int, accel_range_g: int) -> NoiseFigures:
    """At a configured filter and accelerometer variant."""
    bw = float(filter_hz)
    return NoiseFigures(
        accel_density=accel_noise_ug_rthz(accel_range_g) * 1e-6 * G,
        accel_bandwidth_hz=bw,
        gyro_density=math.radians(GYRO_NOISE_DPS_RTHZ),
        gyro_bandwidth_hz=bw,
    )
