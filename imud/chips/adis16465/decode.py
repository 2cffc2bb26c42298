"""ADIS16465 decoding, driver side: the burst frame, its checksum, 32-bit outputs, and counts to
SI units (docs/chips/adis16465.md). Every scale is the datasheet's figure, written here."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from imud.chips.adis16465.registers import (
    BURST_CHECKSUM_BYTES,
    RANG_MDL_CODES,
    RANG_MDL_RANGE,
    RANG_MDL_READS_ONE,
    Register,
)
from imud.units import STANDARD_GRAVITY

# Datasheet scale factors (16-bit outputs) and ranges of the 32-bit delta outputs
GYRO_LSB_PER_DPS = {1: 160, 2: 40, 3: 10}  # ADIS16465-1/-2/-3
ACCEL_LSB_PER_G = 4000  # all models: 0.25 mg
TEMP_C_PER_LSB = 0.1  # 0 = 0 degC
DELTA_ANGLE_RANGE_DEG = {1: 360, 2: 720, 3: 2160}  # +-range over 2^31 counts (32-bit)
DELTA_VELOCITY_RANGE_MS = 100  # +-100 m/s over 2^31 counts
FULL_SCALE_16 = 32767  # the 16-bit register's largest code

# DIAG_STAT, X/Y/Z_GYRO_OUT, X/Y/Z_ACCL_OUT, TEMP_OUT, DATA_CNTR, checksum: big-endian words
BURST = struct.Struct(">H6hhHH")
assert BURST.size == BURST_CHECKSUM_BYTES + 2


def gyro_scale_rads(model: int) -> float:
    """rad/s per LSB of a 16-bit gyro output."""
    return math.radians(1.0 / GYRO_LSB_PER_DPS[model])


def accel_scale_ms2() -> float:
    return STANDARD_GRAVITY / ACCEL_LSB_PER_G


def delta_angle_scale_rad(model: int) -> float:
    """rad per LSB of a 32-bit delta angle (X/Y/Z_DELTANG_OUT:_LOW)."""
    return math.radians(DELTA_ANGLE_RANGE_DEG[model]) / 2**31


def delta_velocity_scale_ms() -> float:
    """m/s per LSB of a 32-bit delta velocity (X/Y/Z_DELTVEL_OUT:_LOW)."""
    return DELTA_VELOCITY_RANGE_MS / 2**31


def checksum(response: bytes) -> int:
    """The burst's checksum: the unsigned sum of the 18 bytes of response words 0-8 (DIAG_STAT
    ... DATA_CNTR), kept to 16 bits."""
    return sum(response[:BURST_CHECKSUM_BYTES]) & 0xFFFF


@dataclass(frozen=True, slots=True)
class Burst:
    diag_stat: int
    gyro: tuple[int, int, int]  # counts
    accel: tuple[int, int, int]
    temp: int
    data_cntr: int
    checksum: int  # as sent by the chip


def decode_burst(response: bytes) -> Burst:
    """The 20 bytes after the burst's command word. Raises ValueError if the checksum fails."""
    diag, gx, gy, gz, ax, ay, az, temp, cntr, chk = BURST.unpack(response)
    got = checksum(response)
    if got != chk:
        raise ValueError(f"checksum word 0x{chk:04x}, the data bytes sum to 0x{got:04x}")
    return Burst(diag, (gx, gy, gz), (ax, ay, az), temp, cntr, chk)


def join32(out: int, low: int) -> int:
    """A 32-bit two's-complement output from its _OUT (high) and _LOW words."""
    v = (out << 16) | low
    return v - (1 << 32) if v & 0x8000_0000 else v


def model_from_rang_mdl(value: int) -> int | None:
    """Which ADIS16465 model RANG_MDL identifies (1, 2 or 3), or None for no known code (its
    bits [1:0] always read 11; all ones is a floating MISO line)."""
    if value & RANG_MDL_READS_ONE != RANG_MDL_READS_ONE or value == 0xFFFF:
        return None
    code = RANG_MDL_RANGE.get(value)
    for model, c in RANG_MDL_CODES.items():
        if c == code:
            return model
    return None


# Read after a new burst, pipelined (each 16-bit frame clocks out the answer to the one before):
# the low words of gyro and accel when DEC_RATE or FILT_CTRL puts bits in them; the six 32-bit
# delta outputs, high word then low word; then DATA_CNTR again, since a new sample meanwhile
# would mix two samples' words; and one more frame to clock out the last answer.
LOW_REGISTERS = (
    Register.X_GYRO_LOW, Register.Y_GYRO_LOW, Register.Z_GYRO_LOW,
    Register.X_ACCL_LOW, Register.Y_ACCL_LOW, Register.Z_ACCL_LOW,
)  # fmt: skip
DELTA_REGISTERS = (
    Register.X_DELTANG_OUT, Register.X_DELTANG_LOW,
    Register.Y_DELTANG_OUT, Register.Y_DELTANG_LOW,
    Register.Z_DELTANG_OUT, Register.Z_DELTANG_LOW,
    Register.X_DELTVEL_OUT, Register.X_DELTVEL_LOW,
    Register.Y_DELTVEL_OUT, Register.Y_DELTVEL_LOW,
    Register.Z_DELTVEL_OUT, Register.Z_DELTVEL_LOW,
)  # fmt: skip
MIDPOINT_LOW = 0x8000  # a low word not read: the middle of what the high word leaves open


def sample_frames(lows: bool, deltas: bool) -> int:
    """16-bit register frames read after each new sample (each one a register read)."""
    n = (len(LOW_REGISTERS) if lows else 0) + (len(DELTA_REGISTERS) if deltas else 0)
    return n + 2 if n else 0  # DATA_CNTR again, and the frame that clocks it out
