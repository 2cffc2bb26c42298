"""BMI088 decoding, driver side: counts to SI, the temperature register, the FIFO frames of both
dies (docs/chips/bmi088.md).

The accel die's 1024-byte FIFO holds framed data (a header byte per frame), little-endian int16
axes; the gyro die's FIFO holds 100 headerless 6-byte frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from imud.chips.bmi088.registers import (
    ACC_FIFO_FRAME_BYTES,
    ACC_FIFO_HEADER_MASK,
    ACC_FRAME_BYTES,
    FIFO_LENGTH_1_BITS,
    GYRO_FRAME_BYTES,
    TEMP_INVALID_MSB,
    AccFifoHeader,
)
from imud.compiled import load
from imud.units import STANDARD_GRAVITY

_HDR_ACCEL = int(AccFifoHeader.ACCEL)
_HDR_SKIP = int(AccFifoHeader.SKIP)
_HDR_SENSORTIME = int(AccFifoHeader.SENSORTIME)
_HDR_OVER_READ = int(AccFifoHeader.OVER_READ)
_FRAME_LENGTH = {int(h): n for h, n in ACC_FIFO_FRAME_BYTES.items()}
_fifo = load("imud.chips.bmi088._fifo")  # the accel walk in one call, when built


def accel_scale_ms2(range_g: int) -> float:
    """m/s^2 per LSB: full scale 3 * 2^range g over 32768."""
    return range_g * STANDARD_GRAVITY / 32768.0


def gyro_scale_rads(range_dps: int) -> float:
    return math.radians(range_dps) / 32768.0


def temperature_c(msb: int, lsb: int) -> float:
    """TEMP_MSB/TEMP_LSB: an 11-bit two's-complement value, 0.125 C per LSB, 0 at 23 C.
    TEMP_MSB 0x80 means no valid reading, whatever TEMP_LSB holds (DS 5.3.7): NaN."""
    if msb == TEMP_INVALID_MSB:
        return math.nan
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
    n_max = (len(buf) - start) // ACC_FRAME_BYTES
    if n_max == 0:
        return np.zeros((0, 3), dtype=np.int32), start
    frames = buf[start : start + ACC_FRAME_BYTES * n_max].reshape(n_max, ACC_FRAME_BYTES)
    not_accel = np.flatnonzero((frames[:, 0] & ACC_FIFO_HEADER_MASK) != _HDR_ACCEL)
    n = int(not_accel[0]) if not_accel.size else n_max
    payload = np.ascontiguousarray(frames[:n, 1:7])
    return payload.view("<i2").reshape(n, 3).astype(np.int32), start + ACC_FRAME_BYTES * n


def decode_accel_fifo(data: bytes) -> AccelFifo:
    """Walk the accel FIFO: in one call of the compiled kernel when it was built (the same
    results), else `decode_accel_fifo_numpy`."""
    if _fifo is None:
        return decode_accel_fifo_numpy(data)
    accel = np.empty((len(data) // ACC_FRAME_BYTES, 3), dtype=np.int32)
    n, skipped, sensortime, over_read, corrupt_at = _fifo.decode_accel(data, accel)
    return AccelFifo(accel[:n], skipped, sensortime, over_read, corrupt_at)


def decode_accel_fifo_numpy(data: bytes) -> AccelFifo:
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
        hdr = int(buf[pos]) & ACC_FIFO_HEADER_MASK
        if hdr == _HDR_OVER_READ or int(buf[pos]) == _HDR_OVER_READ:
            out.over_read = True
            break
        size = _FRAME_LENGTH.get(hdr)
        if size is None or hdr == _HDR_ACCEL:  # unknown, or an accel frame cut short
            if hdr != _HDR_ACCEL:
                out.corrupt_at = pos
            break
        if pos + size > len(buf):
            break  # a control frame cut off by the read length
        if hdr == _HDR_SKIP:
            out.skipped_before.append((count, int(buf[pos + 1])))
        elif hdr == _HDR_SENSORTIME:
            b = buf[pos + 1 : pos + 4]
            out.sensortime = int(b[0]) | int(b[1]) << 8 | int(b[2]) << 16
        pos += size
    if runs:
        out.accel = np.concatenate(runs)
    return out


def fifo_length(lsb: int, msb: int) -> int:
    """FIFO_LENGTH_0/1: a 14-bit little-endian byte count."""
    return (FIFO_LENGTH_1_BITS.get(msb) << 8) | lsb


def decode_gyro_fifo(data: bytes) -> npt.NDArray[np.int32]:
    """Whole 6-byte gyro frames (X, Y, Z little-endian int16) to (N, 3) counts."""
    n = len(data) // GYRO_FRAME_BYTES
    return np.frombuffer(data, dtype="<i2", count=3 * n).reshape(n, 3).astype(np.int32)
