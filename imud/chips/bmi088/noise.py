"""The BMI088's white noise: its densities and each die's noise bandwidth, the one source of both
for the simulator and for the ROS 2 covariances (docs/ros2.md "Covariances").

The densities are one-sided (docs/chips/bmi088.md "Noise convention"). The gyro's noise bandwidth
is 1.22 times its filter's bandwidth, Bosch's own rule for its RMS (Bosch Sensortec community
forum, "Why the power spectral density (PSD) of BMI088 Gyro have strange peak point", 2020). The
accel's bandwidth per ODR and oversampling mode was not retrieved: its noise is taken white up to
its own Nyquist, ODR/2, whatever `accel_filter` says (an upper bound for osr2 and osr4)."""

from __future__ import annotations

import math

from imud.chips.api import NoiseFigures
from imud.units import STANDARD_GRAVITY as G

ACCEL_NOISE_UG_RTHZ = 175.0  # docs/chips/bmi088.md: not verified in the datasheet
GYRO_NOISE_DPS_RTHZ = 0.014  # docs/chips/bmi088.md: a secondary BMG160-class table agrees
ENBW_PER_BW = 1.22  # gyro: noise bandwidth over the GYRO_BANDWIDTH code's filter bandwidth


def gyro_bandwidth_hz(filter_hz: float) -> float:
    return ENBW_PER_BW * filter_hz


def accel_bandwidth_hz(accel_odr_hz: float) -> float:
    return accel_odr_hz / 2


def noise_figures(gyro_filter_hz: float, accel_odr_hz: float) -> NoiseFigures:
    """At a configured gyro filter and accel rate. The accel is published interpolated onto
    the gyro's sample times (imud.align); its bandwidth here is its own die's, at its rate."""
    return NoiseFigures(
        accel_density=ACCEL_NOISE_UG_RTHZ * 1e-6 * G,
        accel_bandwidth_hz=accel_bandwidth_hz(accel_odr_hz),
        gyro_density=math.radians(GYRO_NOISE_DPS_RTHZ),
        gyro_bandwidth_hz=gyro_bandwidth_hz(gyro_filter_hz),
    )
