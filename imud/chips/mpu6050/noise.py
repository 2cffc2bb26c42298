"""The MPU6050's white noise: the datasheet's densities and the DLPF's bandwidths, the one source
of both for the simulator and for the ROS 2 covariances (docs/ros2.md "Covariances").

The densities are one-sided (PS §6.1 gives 0.005 deg/s/rtHz and 0.05 deg/s RMS at the 100 Hz
DLPF: 0.005 * sqrt(100) = 0.05), and the DLPF table's bandwidth is taken as the noise bandwidth
(docs/chips/mpu6050.md "Noise convention")."""

from __future__ import annotations

import math

from imud.chips.api import NoiseFigures
from imud.chips.mpu6050.registers import DLPF_BANDWIDTHS_HZ
from imud.units import STANDARD_GRAVITY as G

ACCEL_NOISE_UG_RTHZ = 400.0  # PS-MPU-6000A-00 rev 3.4 §6.2, at 10 Hz, AFS_SEL = 0
GYRO_NOISE_DPS_RTHZ = 0.005  # §6.1, at 10 Hz, FS_SEL = 0
# The DLPF's bandwidth per DLPF_CFG 0..6 (RM-MPU-6000A-00 rev 4.2 §4.3, register 26 table):
# the accel's at Fs 1 kHz, and the gyro's (the config's `dlpf_hz`)
ACCEL_DLPF_HZ = (260.0, 184.0, 94.0, 44.0, 21.0, 10.0, 5.0)
GYRO_DLPF_HZ = (256.0, 188.0, 98.0, 42.0, 20.0, 10.0, 5.0)


def dlpf_cfg(dlpf_hz: int) -> int:
    """DLPF_CFG of a configured gyro bandwidth."""
    return DLPF_BANDWIDTHS_HZ.index(dlpf_hz)


def noise_figures(dlpf_hz: int) -> NoiseFigures:
    """Each sensor's density over its DLPF bandwidth at a configured `dlpf_hz` (the DLPF filters
    before SMPLRT_DIV decimates, so a lower output rate keeps the band: the noise aliases)."""
    i = dlpf_cfg(dlpf_hz)
    return NoiseFigures(
        accel_density=ACCEL_NOISE_UG_RTHZ * 1e-6 * G,
        accel_bandwidth_hz=ACCEL_DLPF_HZ[i],
        gyro_density=math.radians(GYRO_NOISE_DPS_RTHZ),
        gyro_bandwidth_hz=GYRO_DLPF_HZ[i],
    )
