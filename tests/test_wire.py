"""The batch wire format, version 1: round trips, byte layout, and decoder errors.

Layout (little-endian), from the `imud.wire` docstring: a 32-byte header
  0 magic "IMUD" | 4 version u8 | 5 kind u8 | 6 name length u16 | 8 first_seq u64 |
  16 count u32 | 20 flags u32 | 24 lost_before u32 | 28 reserved u32
then the UTF-8 device name zero-padded to a multiple of 8, then int64 t_ns[N],
float32 accel[N][3], float32 gyro[N][3], float32 temperature[N].
"""

from __future__ import annotations

import struct

import numpy as np
import numpy.typing as npt
import pytest

from imud.wire import (
    FLAG_CALIBRATED,
    FLAG_RESYNC,
    KIND_SAMPLES,
    KIND_TRUTH,
    Batch,
    WireError,
    decode,
    encode,
)

Arrays = tuple[
    npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]
]


def arrays(n: int, seed: int = 0) -> Arrays:
    rng = np.random.default_rng(seed)
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 1_000_000 + rng.integers(0, 9, n)
    accel = rng.normal(0.0, 9.81, (n, 3))
    gyro = rng.normal(0.0, 1.0, (n, 3))
    temp = 25.0 + rng.normal(0.0, 0.1, n)
    return t, accel, gyro, temp


def padded(name_bytes: int) -> int:
    return (name_bytes + 7) // 8 * 8


def u(buf: bytes, offset: int, size: int) -> int:
    return int.from_bytes(buf[offset : offset + size], "little")


# --- round trips ---------------------------------------------------------------------------------


@pytest.mark.parametrize("name_len", range(1, 10))
def test_round_trip_name_lengths(name_len: int) -> None:
    name = "abcdefghi"[:name_len]
    t, a, g, temp = arrays(3, seed=name_len)
    buf = encode(name, 42, t, a, g, temp)
    assert len(buf) == 32 + padded(name_len) + 3 * (8 + 12 + 12 + 4)
    b = decode(buf)
    assert b.device == name
    assert b.first_seq == 42
    assert b.count == 3
    np.testing.assert_array_equal(b.t_ns, t)
    np.testing.assert_array_equal(b.accel, a.astype(np.float32))
    np.testing.assert_array_equal(b.gyro, g.astype(np.float32))
    np.testing.assert_array_equal(b.temperature_c, temp.astype(np.float32))


def test_round_trip_empty_batch() -> None:
    buf = encode("imu0", 7, [], np.zeros((0, 3)), np.zeros((0, 3)), [])
    assert len(buf) == 32 + 8
    b = decode(buf)
    assert b.count == 0
    assert b.first_seq == 7
    assert b.accel.shape == (0, 3) and b.gyro.shape == (0, 3)
    assert b.t_ns.shape == (0,) and b.temperature_c.shape == (0,)
    assert b.seq.shape == (0,)


def test_round_trip_500_samples_float32_precision() -> None:
    t, a, g, temp = arrays(500, seed=5)
    b = decode(encode("imu-long_name", 10**12, t, a, g, temp, flags=FLAG_CALIBRATED))
    assert b.count == 500
    assert b.t_ns.dtype == np.int64 and b.accel.dtype == np.float32
    np.testing.assert_array_equal(b.t_ns, t)  # int64 ns: exact
    # float32: the nearest float32, so within half an ulp (relative 2**-24) of the input
    np.testing.assert_allclose(b.accel, a, rtol=2.0**-24, atol=0)
    np.testing.assert_allclose(b.gyro, g, rtol=2.0**-24, atol=0)
    np.testing.assert_allclose(b.temperature_c, temp, rtol=2.0**-24, atol=0)
    assert not np.array_equal(b.accel.astype(np.float64), a)  # really float32 on the wire
    np.testing.assert_array_equal(b.seq, 10**12 + np.arange(500))


def test_round_trip_header_fields() -> None:
    t, a, g, temp = arrays(2)
    flags = FLAG_CALIBRATED | FLAG_RESYNC
    b = decode(encode("x", 2**63, t, a, g, temp, kind=KIND_TRUTH, flags=flags, lost_before=123456))
    assert isinstance(b, Batch)
    assert b.kind == KIND_TRUTH
    assert b.flags == flags
    assert b.lost_before == 123456
    assert b.first_seq == 2**63


def test_round_trip_non_ascii_name() -> None:
    name = "imü"  # 4 bytes in UTF-8: the length is in bytes
    buf = encode(name, 0, [1], [[0, 0, 0]], [[0, 0, 0]], [0])
    assert u(buf, 6, 2) == 4
    assert decode(buf).device == name


def test_decode_from_memoryview_and_bytearray() -> None:
    t, a, g, temp = arrays(4)
    buf = encode("imu0", 1, t, a, g, temp)
    for view in (bytearray(buf), memoryview(buf)):
        b = decode(view)  # type: ignore[arg-type]
        np.testing.assert_array_equal(b.t_ns, t)
        assert b.device == "imu0"


# --- byte layout ---------------------------------------------------------------------------------


def test_header_fields_at_documented_offsets() -> None:
    t, a, g, temp = arrays(5)
    buf = encode(
        "imu0x",
        0x0102030405060708,
        t,
        a,
        g,
        temp,
        kind=KIND_TRUTH,
        flags=0xA5A50003,
        lost_before=0x0BADBEEF,
    )
    assert buf[0:4] == b"IMUD"
    assert buf[4] == 1  # version
    assert buf[5] == KIND_TRUTH == 1
    assert u(buf, 6, 2) == 5  # name length in bytes
    assert buf[8:16] == bytes([8, 7, 6, 5, 4, 3, 2, 1])  # first_seq, little-endian u64
    assert u(buf, 16, 4) == 5  # count
    assert u(buf, 20, 4) == 0xA5A50003  # flags
    assert u(buf, 24, 4) == 0x0BADBEEF  # lost_before
    assert u(buf, 28, 4) == 0  # reserved
    assert buf[32:37] == b"imu0x"
    assert buf[37:40] == b"\0\0\0"  # padded to 8


def test_samples_kind_is_zero() -> None:
    buf = encode("a", 0, [], np.zeros((0, 3)), np.zeros((0, 3)), [])
    assert buf[5] == KIND_SAMPLES == 0


@pytest.mark.parametrize("name", ["a", "abcdefgh", "abcdefghi"])
def test_array_offsets(name: str) -> None:
    n = 3
    t = np.array([10, -20, 2**62], dtype=np.int64)
    a = np.arange(9, dtype=np.float64).reshape(3, 3) + 0.5
    g = -np.arange(9, dtype=np.float64).reshape(3, 3) - 0.25
    temp = np.array([20.0, 21.5, -40.0])
    buf = encode(name, 0, t, a, g, temp)
    off = 32 + padded(len(name))
    assert struct.unpack_from("<3q", buf, off) == (10, -20, 2**62)
    off += 8 * n
    assert struct.unpack_from("<9f", buf, off) == tuple(a.ravel())  # row-major: x,y,z per sample
    off += 12 * n
    assert struct.unpack_from("<9f", buf, off) == tuple(g.ravel())
    off += 12 * n
    assert struct.unpack_from("<3f", buf, off) == (20.0, 21.5, -40.0)
    assert off + 4 * n == len(buf)


def test_decode_hand_built_buffer() -> None:
    """A buffer assembled field by field from the documented layout, without `encode`."""
    name = b"hand"
    head = (
        b"IMUD"
        + bytes([1, 0])
        + len(name).to_bytes(2, "little")
        + (99).to_bytes(8, "little")
        + (2).to_bytes(4, "little")
        + (2).to_bytes(4, "little")  # flags: resync
        + (5).to_bytes(4, "little")  # lost_before
        + bytes(4)
    )
    body = (
        name
        + bytes(4)
        + struct.pack("<2q", 1000, 2000)
        + struct.pack("<6f", 0.0, 0.0, 9.75, 1.0, 2.0, 3.0)
        + struct.pack("<6f", 0.125, -0.125, 0.0, 0.0, 0.0, 0.5)
        + struct.pack("<2f", 24.5, 24.75)
    )
    b = decode(head + body)
    assert b.device == "hand"
    assert (b.kind, b.first_seq, b.count, b.flags, b.lost_before) == (0, 99, 2, FLAG_RESYNC, 5)
    assert b.t_ns.tolist() == [1000, 2000]
    assert b.accel.tolist() == [[0.0, 0.0, 9.75], [1.0, 2.0, 3.0]]
    assert b.gyro.tolist() == [[0.125, -0.125, 0.0], [0.0, 0.0, 0.5]]
    assert b.temperature_c.tolist() == [24.5, 24.75]
    assert b.seq.tolist() == [99, 100]


# --- errors --------------------------------------------------------------------------------------


def good() -> bytes:
    t, a, g, temp = arrays(2)
    return encode("imu0", 0, t, a, g, temp)


@pytest.mark.parametrize("length", [0, 1, 31])
def test_short_buffer(length: int) -> None:
    with pytest.raises(WireError, match=rf"too short: {length} bytes.*header.*32"):
        decode(good()[:length])


def test_bad_magic() -> None:
    buf = b"IMUX" + good()[4:]
    with pytest.raises(WireError, match=r"bad magic b'IMUX' at byte 0, expected b'IMUD'"):
        decode(buf)


@pytest.mark.parametrize("version", [0, 2, 255])
def test_wrong_version(version: int) -> None:
    buf = bytearray(good())
    buf[4] = version
    with pytest.raises(WireError, match=rf"version {version} at byte 4.*reads 1"):
        decode(bytes(buf))


def test_truncated_body() -> None:
    buf = good()
    need = 32 + 8 + 2 * 36
    assert len(buf) == need
    with pytest.raises(WireError, match=rf"2 samples needs {need} bytes, got {need - 1}"):
        decode(buf[:-1])


def test_trailing_bytes() -> None:
    buf = good() + b"\0"
    with pytest.raises(WireError, match=r"needs 112 bytes, got 113"):
        decode(buf)


def test_count_larger_than_body() -> None:
    buf = bytearray(good())
    buf[16:20] = (3).to_bytes(4, "little")
    with pytest.raises(WireError, match=r"3 samples needs 148 bytes, got 112"):
        decode(bytes(buf))


def test_name_length_past_end() -> None:
    buf = bytearray(good())
    buf[6:8] = (0xFFFF).to_bytes(2, "little")
    with pytest.raises(WireError, match=r"got 112"):
        decode(bytes(buf))


def test_wire_error_is_value_error() -> None:
    assert issubclass(WireError, ValueError)


def test_invalid_utf8_name_is_wire_error() -> None:
    buf = bytearray(good())
    buf[32] = 0xFF  # first byte of "imu0"
    with pytest.raises(WireError):
        decode(bytes(buf))
