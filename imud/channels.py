"""What a sample can carry: the channels of wire format v2, their shapes and SI units, and the
per-sample flags.

One table serves the chip interface (a chip declares which channels it produces), the pipeline
(which channels are scaled, calibrated, checked for saturation) and the wire format (a batch's
channel mask says which arrays follow, in bit order). Keeping it in one place is what lets a new
chip add a channel without touching the daemon.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntFlag


class Channel(IntFlag):
    """Bit of a batch's channel mask; arrays follow on the wire in this (bit) order."""

    ACCEL = 1 << 0  # specific force, m/s^2, (N, 3)
    GYRO = 1 << 1  # angular rate, rad/s, (N, 3)
    TEMPERATURE = 1 << 2  # chip temperature, deg C, (N,)
    MAG = 1 << 3  # magnetic field, T, (N, 3)
    ORIENTATION = 1 << 4  # unit quaternion w, x, y, z: body -> world (ENU), (N, 4)
    LINEAR_ACCEL = 1 << 5  # acceleration without gravity, m/s^2, (N, 3)
    GRAVITY = 1 << 6  # gravity in the body frame, m/s^2, (N, 3)
    DELTA_ANGLE = 1 << 7  # rotation since the previous sample, rad, (N, 3)
    DELTA_VELOCITY = 1 << 8  # velocity change since the previous sample, m/s, (N, 3)
    INCLINATION = 1 << 9  # inclinometer specific force, m/s^2, (N, 3)
    # the orientation's error covariance, world frame: xx, xy, xz, yy, yz, zz, rad^2, (N, 6)
    ORIENTATION_COVARIANCE = 1 << 10


@dataclass(frozen=True, slots=True)
class ChannelInfo:
    key: str  # name in JSON, the CLI and `Batch` attributes
    width: int  # values per sample; 1 means a flat (N,) array
    unit: str


CHANNELS: dict[Channel, ChannelInfo] = {
    Channel.ACCEL: ChannelInfo("accel", 3, "m/s^2"),
    Channel.GYRO: ChannelInfo("gyro", 3, "rad/s"),
    Channel.TEMPERATURE: ChannelInfo("temperature_c", 1, "degC"),
    Channel.MAG: ChannelInfo("mag", 3, "T"),
    Channel.ORIENTATION: ChannelInfo("orientation", 4, "1"),
    Channel.LINEAR_ACCEL: ChannelInfo("linear_accel", 3, "m/s^2"),
    Channel.GRAVITY: ChannelInfo("gravity", 3, "m/s^2"),
    Channel.DELTA_ANGLE: ChannelInfo("delta_angle", 3, "rad"),
    Channel.DELTA_VELOCITY: ChannelInfo("delta_velocity", 3, "m/s"),
    Channel.INCLINATION: ChannelInfo("inclination", 3, "m/s^2"),
    Channel.ORIENTATION_COVARIANCE: ChannelInfo("orientation_covariance", 6, "rad^2"),
}
assert list(CHANNELS) == sorted(CHANNELS), "wire order is bit order"
# (channel, its bit as a plain int, width) in wire order: hot paths test bits on ints, since an
# operator on an IntFlag builds a new enum member each time
ORDER: list[tuple[Channel, int, int]] = [(c, int(c), i.width) for c, i in CHANNELS.items()]


def channels_in(mask: int) -> list[Channel]:
    """The channels of a mask, in wire (bit) order."""
    mask = int(mask)
    return [c for c, bit, _ in ORDER if mask & bit]


class SampleFlag(IntFlag):
    """Per-sample flags (uint32 on the wire).

    Bits 0-15: the chip marked that channel's value invalid in this sample (bit = the channel's
    own bit); its values are NaN while the sample's other channels are published as usual.
    Bits 16-23: a sensor's raw reading was at full scale (saturated). Bit 24: the chip raised an
    alarm for this sample (its own status word said so). Bit 25: the calibration's temperature
    correction was clamped at the edge of the span it was fitted on (the chip was hotter or
    colder than any calibration data)."""

    ACCEL_INVALID = Channel.ACCEL
    GYRO_INVALID = Channel.GYRO
    TEMPERATURE_INVALID = Channel.TEMPERATURE
    MAG_INVALID = Channel.MAG
    ORIENTATION_INVALID = Channel.ORIENTATION
    LINEAR_ACCEL_INVALID = Channel.LINEAR_ACCEL
    GRAVITY_INVALID = Channel.GRAVITY
    DELTA_ANGLE_INVALID = Channel.DELTA_ANGLE
    DELTA_VELOCITY_INVALID = Channel.DELTA_VELOCITY
    INCLINATION_INVALID = Channel.INCLINATION
    ORIENTATION_COVARIANCE_INVALID = Channel.ORIENTATION_COVARIANCE
    ACCEL_SATURATED = 1 << 16
    GYRO_SATURATED = 1 << 17
    MAG_SATURATED = 1 << 18
    INCLINATION_SATURATED = 1 << 19
    CHIP_ALARM = 1 << 24
    TEMPERATURE_OUTSIDE_CALIBRATION = 1 << 25


INVALID_MASK = 0xFFFF
SATURATED: dict[Channel, SampleFlag] = {
    Channel.ACCEL: SampleFlag.ACCEL_SATURATED,
    Channel.GYRO: SampleFlag.GYRO_SATURATED,
    Channel.MAG: SampleFlag.MAG_SATURATED,
    Channel.INCLINATION: SampleFlag.INCLINATION_SATURATED,
}
