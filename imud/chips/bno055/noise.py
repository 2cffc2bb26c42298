"""The BNO055's white noise: its sensors' densities, the filters its fusion modes lock, and its
magnetometer's per-sample noise, the one source of them for the simulator and for the ROS 2
covariances (docs/ros2.md "Covariances").

The BNO055's sheet gives no noise densities: these are its accelerometer's and gyroscope's class
(BMA280 / BMG160-like, docs/chips/bno055.md), taken as one-sided. In the fusion modes the chip
locks its filters at accel 62.5 Hz and gyro 32 Hz (LX-BNO), taken as the noise bandwidths; the
accel's is above the 100 Hz output's Nyquist, so the output aliases it (one sample's variance is
still density^2 * 62.5 Hz). The magnetometer's 0.3 uT per sample is its sensor's (BMM150-class)
low-noise figure, not a BNO055 datasheet value; it updates at 20 Hz and the 100 Hz output holds
each reading for five samples."""

from __future__ import annotations

import math

from imud.chips.api import NoiseFigures
from imud.chips.bno055.registers import FUSION_MAG_RATE_HZ, FUSION_RATE_HZ
from imud.units import STANDARD_GRAVITY as G

ACCEL_NOISE_UG_RTHZ = 150.0
GYRO_NOISE_DPS_RTHZ = 0.014
ACCEL_FUSION_LPF_HZ, GYRO_FUSION_LPF_HZ = 62.5, 32.0
MAG_NOISE_UT = 0.3  # rms, per sample and axis
MAG_HOLD = round(FUSION_RATE_HZ / FUSION_MAG_RATE_HZ)  # output samples a mag reading lasts


def noise_figures() -> NoiseFigures:
    """The same in every mode imud runs: the fusion modes lock these filters, and in AMG they
    are the chip's power-on defaults, which imud keeps."""
    return NoiseFigures(
        accel_density=ACCEL_NOISE_UG_RTHZ * 1e-6 * G,
        accel_bandwidth_hz=ACCEL_FUSION_LPF_HZ,
        gyro_density=math.radians(GYRO_NOISE_DPS_RTHZ),
        gyro_bandwidth_hz=GYRO_FUSION_LPF_HZ,
        mag_sigma_t=MAG_NOISE_UT * 1e-6,
        mag_hold=MAG_HOLD,
    )
