"""Bosch BMI088 register facts and FIFO decoding, for both dies.

Facts from /work/shared/reference/chips-invensense-bosch.md section 3 (Bosch's BMI08x API, PX4 and
ArduPilot drivers): the accel die's 1024-byte FIFO holds framed data (a header byte per frame),
little-endian int16 axes; the gyro die's FIFO holds 100 headerless 6-byte frames.

This module is the decode layer only; the driver, config model and simulator build on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

STANDARD_GRAVITY = 9.80665

# Accel die
ACC_CHIP_ID = 0x00
ACC_CHIP_ID_VALUE = 0x1E
ACC_STATUS = 0x03
ACC_DATA = 0x12  # X LSB .. Z MSB, little-endian
SENSORTIME_0 = 0x18
TEMP_MSB = 0x22
FIFO_LENGTH_0 = 0x24
ACC_FIFO_DATA = 0x26
ACC_CONF = 0x40
ACC_RANGE = 0x41
ACC_FIFO_CONFIG_0 = 0x48
ACC_FIFO_CONFIG_1 = 0x49
ACC_PWR_CONF = 0x7C
ACC_PWR_CTRL = 0x7D
ACC_SOFTRESET = 0x7E  # 0xB6 resets, 0xB0 flushes the FIFO
SOFTRESET_CMD = 0xB6
ACC_FIFO_FLUSH_CMD = 0xB0
ACC_FIFO_SIZE = 1024
SENSORTIME_S_PER_LSB = 39.0625e-6  # 24-bit counter
# Gyro die
GYR_CHIP_ID = 0x00
GYR_CHIP_ID_VALUE = 0x0F
GYR_DATA = 0x02  # X LSB .. Z MSB, little-endian
GYR_FIFO_STATUS = 0x0E  # bit7 overrun, [6:0] frames
GYR_RANGE = 0x0F
GYR_BANDWIDTH = 0x10
GYR_LPM1 = 0x11
GYR_SOFTRESET = 0x14
GYR_INT_CTRL = 0x15
GYR_FIFO_CONFIG_0 = 0x3D  # watermark; writing it clears the FIFO
GYR_FIFO_CONFIG_1 = 0x3E  # mode; writing it clears the overrun flag
GYR_FIFO_DATA = 0x3F
GYR_FIFO_FRAMES = 100
GYR_FRAME = 6

# Accel FIFO frame headers (bits 1:0 are interrupt tags, masked off) and their lengths
HDR_ACCEL = 0x84
HDR_SKIP = 0x40
HDR_SENSORTIME = 0x44
HDR_INPUT_CONFIG = 0x48
HDR_DROP = 0x50
HDR_OVER_READ = 0x80
FRAME_LENGTH = {HDR_ACCEL: 7, HDR_SKIP: 2, HDR_SENSORTIME: 4, HDR_INPUT_CONFIG: 2, HDR_DROP: 2}

ACCEL_RANGES_G = (3, 6, 12, 24)  # ACC_RANGE 0..3
GYRO_RANGES_DPS = (2000, 1000, 500, 250, 125)  # GYRO_RANGE 0..4


def accel_scale_ms2(range_g: int) -> float:
    """m/s^2 per LSB: full scale 3 * 2^range g over 32768."""
    return range_g * STANDARD_GRAVITY / 32768.0


def gyro_scale_rads(range_dps: int) -> float:
    return math.radians(range_dps) / 32768.0


def temperature_c(msb: int, lsb: int) -> float:
    """TEMP_MSB/TEMP_LSB: an 11-bit two's-complement value, 0.125 C per LSB, 0 at 23 C."""
    u11 = (msb << 3) | (lsb >> 5)
    s11 = u11 - 2048 if u11 > 1023 else u11
    return s11 * 0.125 + 23.0


@dataclass(slots=True)
class AccelFifo:
    """The accel frames of one FIFO read, in order, and what the control frames said."""

    accel: npt.NDArray[np.int32]  # (N, 3) counts
    skipped_before: list[tuple[int, int]] = field(default_factory=list)  # (frame index, count)
    sensortime: int | None = None  # 24-bit, ticks of 39.0625 us
    over_read: bool = False  # the read went past the last frame (normal at the end)
    corrupt_at: int | None = None  # byte offset of an unknown header: stop, and flush


def _accel_run(buf: npt.NDArray[np.uint8], start: int) -> tuple[npt.NDArray[np.int32], int]:
    """The longest run of whole 7-byte accel frames from `start`, decoded with one view."""
    n_max = (len(buf) - start) // 7
    if n_max == 0:
        return np.zeros((0, 3), dtype=np.int32), start
    frames = buf[start : start + 7 * n_max].reshape(n_max, 7)
    not_accel = np.flatnonzero((frames[:, 0] & 0xFC) != HDR_ACCEL)
    n = int(not_accel[0]) if not_accel.size else n_max
    payload = np.ascontiguousarray(frames[:n, 1:7])
    return payload.view("<i2").reshape(n, 3).astype(np.int32), start + 7 * n


def decode_accel_fifo(data: bytes) -> AccelFifo:
    """Walk the accel FIFO: vectorised over runs of data frames, one step per control frame."""
    buf = np.frombuffer(data, dtype=np.uint8)
    runs: list[npt.NDArray[np.int32]] = []
    out = AccelFifo(np.zeros((0, 3), dtype=np.int32))
    count = 0
    pos = 0
    while pos < len(buf):
        run, pos = _accel_run(buf, pos)
        if len(run):
            runs.append(run)
            count += len(run)
        if pos >= len(buf):
            break
        hdr = int(buf[pos]) & 0xFC
        if hdr == HDR_OVER_READ or int(buf[pos]) == HDR_OVER_READ:
            out.over_read = True
            break
        size = FRAME_LENGTH.get(hdr)
        if size is None or hdr == HDR_ACCEL:  # unknown, or an accel frame cut short
            if hdr != HDR_ACCEL:
                out.corrupt_at = pos
            break
        if pos + size > len(buf):
            break  # a control frame cut off by the read length
        if hdr == HDR_SKIP:
            out.skipped_before.append((count, int(buf[pos + 1])))
        elif hdr == HDR_SENSORTIME:
            b = buf[pos + 1 : pos + 4]
            out.sensortime = int(b[0]) | int(b[1]) << 8 | int(b[2]) << 16
        pos += size
    if runs:
        out.accel = np.concatenate(runs)
    return out


def fifo_length(lsb: int, msb: int) -> int:
    """FIFO_LENGTH_0/1: a 14-bit little-endian byte count."""
    return ((msb & 0x3F) << 8) | lsb


def decode_gyro_fifo(data: bytes) -> npt.NDArray[np.int32]:
    """Whole 6-byte gyro frames (X, Y, Z little-endian int16) to (N, 3) counts."""
    n = len(data) // GYR_FRAME
    return np.frombuffer(data, dtype="<i2", count=3 * n).reshape(n, 3).astype(np.int32)
