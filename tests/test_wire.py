"""The batch wire format, version 2: round trips, byte layout, and decoder errors.

Layout (little-endian), as docs/wire-format.md specifies it: a 32-byte header
  0 magic "IMUD" | 4 version u8 (2) | 5 kind u8 | 6 name length u16 | 8 first_seq u64 |
  16 count u32 | 20 flags u32 | 24 lost_before u32 | 28 channel mask u32
then the UTF-8 device name zero-padded to a multiple of 8, then int64 t_ns[N], uint32
sample_flags[N], then one float32 array per channel in the mask, in bit order:
  bit 0 accel [N][3], 1 gyro [N][3], 2 temperature [N], 3 mag [N][3], 4 orientation [N][4],
  5 linear accel [N][3], 6 gravity [N][3], 7 delta angle [N][3], 8 delta velocity [N][3],
  9 inclination [N][3], 10 orientation covariance [N][6].
The literals below are that table, not imud's own constants.
"""

from __future__ import annotations

import struct

import numpy as np
import numpy.typing as npt
import pytest

from imud.channels import Channel, SampleFlag
from imud.wire import (
    FLAG_CALIBRATED,
    FLAG_RESYNC,
    KIND_TRUTH,
    Batch,
    WireError,
    decode,
    encode,
    peek,
)

# bit -> floats a sample
WIDTHS = {0: 3, 1: 3, 2: 1, 3: 3, 4: 4, 5: 3, 6: 3, 7: 3, 8: 3, 9: 3, 10: 6}
SIX_AXIS = {Channel.ACCEL: 3, Channel.GYRO: 3, Channel.TEMPERATURE: 1}


def padded(name_bytes: int) -> int:
    return (name_bytes + 7) // 8 * 8


def u(buf: bytes, offset: int, size: int) -> int:
    return int.from_bytes(buf[offset : offset + size], "little")


def data(n: int, channels: dict[Channel, int], seed: int = 0) -> tuple[
    npt.NDArray[np.int64], dict[Channel, npt.NDArray[np.float64]]
]:  # fmt: skip
    rng = np.random.default_rng(seed)
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 1_000_000 + rng.integers(0, 9, n)
    out = {c: rng.normal(0.0, 5.0, (n, w) if w > 1 else n) for c, w in channels.items()}
    return t, out


# --- round trips ---------------------------------------------------------------------------------


@pytest.mark.parametrize("name_len", range(1, 10))
def test_round_trip_name_lengths(name_len: int) -> None:
    name = "abcdefghi"[:name_len]
    t, ch = data(3, SIX_AXIS, seed=name_len)
    buf = encode(name, 42, t, ch)
    assert len(buf) == 32 + padded(name_len) + 3 * (8 + 4 + 12 + 12 + 4)
    b = decode(buf)
    assert b.device == name and b.first_seq == 42 and b.count == 3
    np.testing.assert_array_equal(b.t_ns, t)
    for c, arr in ch.items():
        np.testing.assert_array_equal(b.channels[c], arr.astype(np.float32))
    assert b.sample_flags.tolist() == [0, 0, 0]


def test_every_channel_round_trips_with_its_shape() -> None:
    every = {Channel(1 << bit): w for bit, w in WIDTHS.items()}
    t, ch = data(5, every, seed=3)
    ch[Channel.ORIENTATION] /= np.linalg.norm(ch[Channel.ORIENTATION], axis=1, keepdims=True)
    b = decode(encode("bno0", 0, t, ch))
    assert int(b.mask) == (1 << 11) - 1
    for c, arr in ch.items():
        assert b.channels[c].shape == arr.shape
        np.testing.assert_allclose(b.channels[c], arr, rtol=2.0**-24)


def test_only_the_channels_given_are_sent() -> None:
    t, ch = data(4, {Channel.GYRO: 3, Channel.DELTA_ANGLE: 3})
    buf = encode("adis0", 9, t, ch)
    assert u(buf, 28, 4) == (1 << 1) | (1 << 7)
    assert len(buf) == 32 + 8 + 4 * (8 + 4 + 12 + 12)
    b = decode(buf)
    assert set(b.channels) == {Channel.GYRO, Channel.DELTA_ANGLE}
    assert b.accel is None and b.temperature_c is None


def test_round_trip_empty_batch() -> None:
    buf = encode("imu0", 7, [], {Channel.ACCEL: np.zeros((0, 3)), Channel.TEMPERATURE: []})
    assert len(buf) == 32 + 8
    b = decode(buf)
    assert b.count == 0 and b.first_seq == 7
    assert b.channels[Channel.ACCEL].shape == (0, 3) and b.temperature_c is not None
    assert b.seq.shape == (0,) and b.sample_flags.shape == (0,)


def test_round_trip_500_samples_float32_precision() -> None:
    t, ch = data(500, SIX_AXIS, seed=5)
    b = decode(encode("imu-long_name", 10**12, t, ch, flags=FLAG_CALIBRATED))
    assert b.count == 500
    assert b.t_ns.dtype == np.int64 and b.channels[Channel.ACCEL].dtype == np.float32
    np.testing.assert_array_equal(b.t_ns, t)  # int64 ns: exact
    for c, arr in ch.items():  # float32: within half an ulp (relative 2**-24)
        np.testing.assert_allclose(b.channels[c], arr, rtol=2.0**-24, atol=0)
    assert not np.array_equal(b.channels[Channel.ACCEL].astype(np.float64), ch[Channel.ACCEL])
    np.testing.assert_array_equal(b.seq, 10**12 + np.arange(500))


def test_round_trip_header_fields_and_sample_flags() -> None:
    t, ch = data(3, SIX_AXIS)
    flags = FLAG_CALIBRATED | FLAG_RESYNC
    sf = np.array([0, 1 << 0, (1 << 16) | (1 << 24)], dtype=np.uint32)
    b = decode(encode("x", 2**63, t, ch, sf, kind=KIND_TRUTH, flags=flags, lost_before=123456))
    assert isinstance(b, Batch)
    assert (b.kind, b.flags, b.lost_before, b.first_seq) == (KIND_TRUTH, flags, 123456, 2**63)
    assert b.sample_flags.tolist() == sf.tolist()
    assert b.invalid(Channel.ACCEL).tolist() == [False, True, False]
    assert b.invalid(Channel.GYRO).tolist() == [False, False, False]
    assert b.flagged(SampleFlag.ACCEL_SATURATED).tolist() == [False, False, True]
    assert b.flagged(SampleFlag.CHIP_ALARM).tolist() == [False, False, True]


def test_nan_survives_for_invalid_values() -> None:
    t, ch = data(2, SIX_AXIS)
    ch[Channel.ACCEL][1] = np.nan
    b = decode(encode("x", 0, t, ch, [0, 1]))
    assert np.isnan(b.channels[Channel.ACCEL][1]).all()
    assert not np.isnan(b.channels[Channel.GYRO]).any()


def test_round_trip_non_ascii_name() -> None:
    name = "imü"  # 4 bytes in UTF-8: the length is in bytes
    buf = encode(name, 0, [1], {Channel.GYRO: [[0, 0, 0]]})
    assert u(buf, 6, 2) == 4
    assert decode(buf).device == name


def test_decode_from_memoryview_and_bytearray() -> None:
    t, ch = data(4, SIX_AXIS)
    buf = encode("imu0", 1, t, ch)
    for view in (bytearray(buf), memoryview(buf)):
        b = decode(view)  # type: ignore[arg-type]
        np.testing.assert_array_equal(b.t_ns, t)
        assert b.device == "imu0"


def test_encode_rejects_a_channel_of_the_wrong_size() -> None:
    with pytest.raises(WireError, match="accel"):
        encode("x", 0, [1, 2], {Channel.ACCEL: np.zeros((3, 3))})


# --- byte layout, from the spec ----------------------------------------------------------------


def test_header_fields_at_documented_offsets() -> None:
    t, ch = data(2, SIX_AXIS)
    buf = encode("imu0", 0x0102030405060708, t, ch, kind=1, flags=3, lost_before=77)
    assert buf[0:4] == b"IMUD"
    assert buf[4] == 2
    assert buf[5] == 1
    assert u(buf, 6, 2) == 4
    assert u(buf, 8, 8) == 0x0102030405060708
    assert u(buf, 16, 4) == 2
    assert u(buf, 20, 4) == 3
    assert u(buf, 24, 4) == 77
    assert u(buf, 28, 4) == 0b111


@pytest.mark.parametrize("name", ["a", "abcdefgh", "abcdefghi"])
def test_array_offsets(name: str) -> None:
    n = 3
    t, ch = data(n, SIX_AXIS)
    sf = np.array([5, 6, 7], dtype=np.uint32)
    buf = encode(name, 0, t, ch, sf)
    off = 32 + padded(len(name))
    assert off % 8 == 0
    assert buf[32 : 32 + len(name)] == name.encode()
    assert buf[32 + len(name) : off] == b"\0" * (off - 32 - len(name))
    assert struct.unpack_from(f"<{n}q", buf, off) == tuple(t)
    off += 8 * n
    assert struct.unpack_from(f"<{n}I", buf, off) == (5, 6, 7)
    off += 4 * n
    for c, w in SIX_AXIS.items():  # accel, gyro, temperature: bit order
        got = struct.unpack_from(f"<{n * w}f", buf, off)
        np.testing.assert_array_equal(got, ch[c].astype(np.float32).ravel())
        off += 4 * n * w
    assert off == len(buf)


def test_decode_hand_built_buffer() -> None:
    """A buffer built from the spec alone, without `encode`: one gyro + mag sample."""
    name = b"dev"
    head = struct.pack("<4sBBHQIIII", b"IMUD", 2, 0, len(name), 5, 1, 2, 3, (1 << 1) | (1 << 3))
    body = name + b"\0" * 5
    body += struct.pack("<q", 123456789) + struct.pack("<I", 1 << 17)
    body += struct.pack("<3f", 0.5, -0.25, 0.125) + struct.pack("<3f", 2e-5, -3e-5, 4e-5)
    b = decode(head + body)
    assert (b.device, b.first_seq, b.count, b.flags, b.lost_before) == ("dev", 5, 1, 2, 3)
    assert b.t_ns.tolist() == [123456789]
    assert b.gyro is not None and b.gyro.tolist() == [[0.5, -0.25, 0.125]]
    np.testing.assert_allclose(b.channels[Channel.MAG], [[2e-5, -3e-5, 4e-5]], rtol=1e-6)
    assert b.sample_flags.tolist() == [1 << 17]


# --- errors name what is wrong -------------------------------------------------------------------


def _good() -> bytes:
    t, ch = data(2, SIX_AXIS)
    return encode("imu0", 0, t, ch)


@pytest.mark.parametrize("size", [0, 1, 31])
def test_short_buffer(size: int) -> None:
    with pytest.raises(WireError, match="too short"):
        decode(_good()[:size])


def test_bad_magic() -> None:
    with pytest.raises(WireError, match="magic"):
        decode(b"XMUD" + _good()[4:])


@pytest.mark.parametrize("version", [0, 1, 3, 255])
def test_wrong_version_is_named(version: int) -> None:
    buf = bytearray(_good())
    buf[4] = version
    with pytest.raises(WireError, match=rf"wire version {version} at byte 4.*reads version 2"):
        decode(bytes(buf))


def test_unknown_channel_bit_is_rejected() -> None:
    buf = bytearray(_good())
    buf[28:32] = ((1 << 15) | 0b111).to_bytes(4, "little")
    with pytest.raises(WireError, match=r"channel mask .* at byte 28"):
        decode(bytes(buf))


def test_truncated_body() -> None:
    with pytest.raises(WireError, match=r"needs .* bytes"):
        decode(_good()[:-1])


def test_trailing_bytes() -> None:
    with pytest.raises(WireError, match=r"needs .* bytes"):
        decode(_good() + b"\0")


def test_count_larger_than_body() -> None:
    buf = bytearray(_good())
    buf[16:20] = (3).to_bytes(4, "little")
    with pytest.raises(WireError, match=r"needs .* bytes"):
        decode(bytes(buf))


def test_name_length_past_end() -> None:
    buf = bytearray(_good())
    buf[6:8] = (60000).to_bytes(2, "little")
    with pytest.raises(WireError):
        decode(bytes(buf))


def test_wire_error_is_value_error() -> None:
    assert issubclass(WireError, ValueError)


def test_invalid_utf8_name_is_wire_error() -> None:
    buf = bytearray(_good())
    buf[32] = 0xFF
    with pytest.raises(WireError, match="not UTF-8"):
        decode(bytes(buf))


@pytest.mark.parametrize(("name", "n"), [("a", 0), ("imu0", 1), ("seven77", 5), ("x" * 9, 300)])
def test_peek_reads_what_decode_reads(name: str, n: int) -> None:
    """The daemon follows each relayed stream with `peek` (header and stamps only): it must say
    what a full decode says."""
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 1_000_000
    buf = encode(name, 41, t, {Channel.GYRO: np.zeros((n, 3))}, lost_before=7)
    b = decode(buf)
    first, last = (int(b.t_ns[0]), int(b.t_ns[-1])) if n else (0, 0)
    assert peek(buf) == (b.first_seq, b.count, first, last, b.lost_before)
    assert peek(buf) == (41, n, first, last, 7)
    assert peek(memoryview(buf)) == peek(buf)
