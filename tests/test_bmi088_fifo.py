"""BMI088 FIFO and register decoding from byte vectors written out from the datasheet layouts
(docs/chips/bmi088.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imud.chips.bmi088 import decode as d
from imud.chips.bmi088 import registers as R

G = 9.80665


def accel_frame(x: int, y: int, z: int, tag: int = 0) -> bytes:
    """Header 0x84 (+ interrupt tag bits), then X, Y, Z as little-endian int16."""
    out = bytes([0x84 | tag])
    for v in (x, y, z):
        out += (v & 0xFFFF).to_bytes(2, "little")
    return out


def test_accel_frames_decode_little_endian_with_tags_masked() -> None:
    data = accel_frame(1, -1, 32767) + accel_frame(-32768, 256, -2, tag=0x03)
    f = d.decode_accel_fifo(data)
    assert f.accel.tolist() == [[1, -1, 32767], [-32768, 256, -2]]
    assert f.corrupt_at is None and not f.over_read and f.skipped_before == []


def test_hand_written_bytes_match_the_layout() -> None:
    # 0x84, X = 0x1234 (LSB first), Y = 0xFFFE (-2), Z = 0x8000 (-32768)
    f = d.decode_accel_fifo(bytes([0x84, 0x34, 0x12, 0xFE, 0xFF, 0x00, 0x80]))
    assert f.accel.tolist() == [[0x1234, -2, -32768]]


def test_control_frames_between_runs() -> None:
    data = (
        accel_frame(1, 2, 3)
        + bytes([0x40, 5])  # skip frame: 5 frames lost
        + accel_frame(4, 5, 6)
        + accel_frame(7, 8, 9)
        + bytes([0x48, 0x00])  # FIFO input config changed
        + bytes([0x50, 0x01])  # sample drop
        + accel_frame(10, 11, 12)
        + bytes([0x44, 0x10, 0x20, 0x30])  # sensortime 0x302010
        + bytes([0x80, 0x00, 0x00])  # over-read: the FIFO is empty
    )
    f = d.decode_accel_fifo(data)
    assert f.accel[:, 0].tolist() == [1, 4, 7, 10]
    assert f.skipped_before == [(1, 5)]
    assert f.sensortime == 0x302010
    assert f.over_read and f.corrupt_at is None
    assert f.sensortime * R.SENSORTIME_S_PER_LSB == pytest.approx(0x302010 * 39.0625e-6)


def test_unknown_header_stops_and_says_where() -> None:
    data = accel_frame(1, 2, 3) + bytes([0x13, 0, 0, 0]) + accel_frame(4, 5, 6)
    f = d.decode_accel_fifo(data)
    assert f.accel.tolist() == [[1, 2, 3]] and f.corrupt_at == 7


def test_truncated_frames_are_left_for_the_next_read() -> None:
    f = d.decode_accel_fifo(accel_frame(1, 2, 3) + accel_frame(4, 5, 6)[:4])
    assert f.accel.tolist() == [[1, 2, 3]] and f.corrupt_at is None
    f = d.decode_accel_fifo(accel_frame(1, 2, 3) + bytes([0x44, 0x01]))
    assert f.sensortime is None and f.corrupt_at is None


def test_long_run_of_frames_decodes_exactly() -> None:
    rng = np.random.default_rng(0)
    vals = rng.integers(-32768, 32767, (150, 3))
    data = b"".join(accel_frame(*map(int, v)) for v in vals)
    assert np.array_equal(d.decode_accel_fifo(data).accel, vals)


def test_gyro_frames() -> None:
    # X = 0x0102, Y = -1, Z = 0x7FFF, little-endian, no header
    data = bytes([0x02, 0x01, 0xFF, 0xFF, 0xFF, 0x7F]) * 2 + bytes([0x01, 0x02])
    g = d.decode_gyro_fifo(data)
    assert g.tolist() == [[0x0102, -1, 32767]] * 2  # the partial frame is ignored


def test_fifo_length_is_14_bit_little_endian() -> None:
    assert d.fifo_length(0x34, 0x12) == 0x1234
    assert d.fifo_length(0xFF, 0xFF) == 0x3FFF  # the top two bits are not part of the count


# DS section 5.3.7: u11 = TEMP_MSB * 8 + TEMP_LSB / 32, two's complement, 0.125 C/LSB, 0 at 23 C
@pytest.mark.parametrize(("msb", "lsb", "celsius"), [
    (0x00, 0x00, 23.0),  # 0 -> 23 C
    (0x01, 0x20, 23.0 + 9 * 0.125),  # u11 = 8 + 1 = 9
    (0x7F, 0xE0, 23.0 + 1023 * 0.125),  # largest positive
    (0x3E, 0x00, 85.0),  # the datasheet's worked examples
    (0x00, 0x60, 23.375),
    (0xC1, 0x00, -40.0),
    (0xFF, 0xE0, 23.0 - 0.125),  # u11 = 2047 -> -1
    (0x81, 0x00, 23.0 - 1016 * 0.125),  # u11 = 1032 -> -1016: the lowest code not invalid
    (0x00, 0x1F, 23.0),  # only TEMP_LSB[7:5] carry data
])  # fmt: skip
def test_temperature(msb: int, lsb: int, celsius: float) -> None:
    assert d.temperature_c(msb, lsb) == pytest.approx(celsius)


@pytest.mark.parametrize("lsb", [0x00, 0x20, 0xE0])
def test_temperature_msb_0x80_is_invalid(lsb: int) -> None:
    # the datasheet's table: TEMP_MSB 0x80 (TEMP_LSB not given) -> "Invalid"
    assert math.isnan(d.temperature_c(0x80, lsb))


def test_scales() -> None:
    # 3 g full scale: 10922.7 LSB/g; 24 g: 1365.3 LSB/g
    assert 1 / (d.accel_scale_ms2(3) / G) == pytest.approx(10922.67, rel=1e-5)
    assert 1 / (d.accel_scale_ms2(24) / G) == pytest.approx(1365.33, rel=1e-5)
    # gyro: 16.384 LSB/(deg/s) at 2000, 262.144 at 125
    assert math.radians(1) / d.gyro_scale_rads(2000) == pytest.approx(16.384)
    assert math.radians(1) / d.gyro_scale_rads(125) == pytest.approx(262.144)
