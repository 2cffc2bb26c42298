"""ICM-42688-P FIFO packets, scale factors and register plan, checked against datasheet facts.

Byte vectors are written out by hand from the packet layouts (big-endian, the reset
SENSOR_DATA_ENDIAN); nothing here is produced by an encoder from the code under test.
Packet 3 (16 B): [0] header, [1..6] accel X/Y/Z int16, [7..12] gyro X/Y/Z int16, [13] temp int8
(T = raw/2.07 + 25), [14..15] timestamp uint16. Packet 4 (20 B): [1..12] accel/gyro bits [19:4],
[13..14] temp int16 (T = raw/132.48 + 25), [15..16] timestamp, [17..19] X/Y/Z ext bytes with
accel[3:0] in the high nibble and gyro[3:0] in the low nibble.
Invalid values (docs/chips/icm42688p.md A.4, A.7 a): a sensor whose three axes all read -32768
(-524288 in 20-bit packets; Linux's rule) or whose header bit is clear has no data in that
packet, judged per sensor; the int8 temperature of packet 3 is invalid at -128 (TDK eMD), the int16
temperature of packet 4 at -32768. In packet 4 a clear HEADER_20 bit means no new 20-bit data.
Facts: docs/chips/icm42688p.md.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from imud.buses.spi import SpiDevice
from imud.channels import Channel
from imud.chips.api import FifoRead, start_blocking
from imud.chips.icm42688p.config import Icm42688pConfig
from imud.chips.icm42688p.driver import (
    PACKET3,
    PACKET4,
    Icm42688pDriver,
    accel_scale_ms2,
    decode_packets,
    gyro_scale_rads,
)
from imud.chips.icm42688p.sim import ACCEL_STARTUP_NS, GYRO_STARTUP_NS, Icm42688pSim
from imud.clock import VirtualClock
from imud.config import parse_config
from imud.errors import DeviceIdentityError, RegisterMismatch
from imud.sim.spi import SimSpiDev

G = 9.80665  # standard gravity, m/s^2

# --- packet 3 (16 bytes) -------------------------------------------------------------------------

# header 0x68 = ACCEL (bit 6) | GYRO (bit 5) | TMST_FSYNC 0b10 (ODR timestamp)
P3_A = bytes(
    [
        0x68,
        0x08, 0x00,  # accel x  +2048 (1 g at +-16 g)
        0xF8, 0x00,  # accel y  -2048
        0x00, 0x01,  # accel z  1
        0xFF, 0xFF,  # gyro x   -1
        0x7F, 0xFF,  # gyro y   32767
        0x80, 0x00,  # gyro z   -32768 (one axis only: not the invalid marker)
        0x15,        # temp     21 -> 21/2.07 + 25 degC
        0x12, 0x34,  # timestamp 0x1234 = 4660
    ]
)  # fmt: skip
P3_A_ACCEL = [2048, -2048, 1]
P3_A_GYRO = [-1, 32767, -32768]
P3_A_TEMP = 21 / 2.07 + 25.0
P3_A_TS = 0x1234

P3_B = bytes(
    [
        0x68,
        0x01, 0x02,  # accel x  258
        0xFE, 0xFF,  # accel y  -257
        0x7F, 0xFF,  # accel z  32767
        0x80, 0x01,  # gyro x   -32767
        0x00, 0x00,  # gyro y   0
        0x00, 0xFF,  # gyro z   255
        0xEC,        # temp     -20 -> -20/2.07 + 25 degC
        0xFF, 0xFE,  # timestamp 65534 (unsigned)
    ]
)  # fmt: skip
P3_B_ACCEL = [258, -257, 32767]
P3_B_GYRO = [-32767, 0, 255]
P3_B_TEMP = -20 / 2.07 + 25.0
P3_B_TS = 65534

FIFO_EMPTY = bytes([0x80] * 16)  # what a read past the end of the FIFO returns

ACCEL_INVALID = bytes([0x68, 0x80, 0x00, 0x80, 0x00, 0x80, 0x00]) + P3_A[7:]
GYRO_INVALID = P3_A[:7] + bytes([0x80, 0x00, 0x80, 0x00, 0x80, 0x00]) + P3_A[13:]


def test_packet_record_sizes() -> None:
    assert PACKET3.itemsize == 16
    assert PACKET4.itemsize == 20


def test_decode_one_packet3() -> None:
    p = decode_packets(P3_A, hires=False)
    assert p.n == 1
    assert p.accel.shape == (1, 3) and p.gyro.shape == (1, 3)
    assert p.accel.tolist() == [P3_A_ACCEL]
    assert p.gyro.tolist() == [P3_A_GYRO]
    assert p.temperature_c.tolist() == pytest.approx([P3_A_TEMP], abs=1e-9)
    assert p.temperature_c[0] == pytest.approx(35.1449, abs=1e-4)
    assert p.timestamp.tolist() == [P3_A_TS]
    assert _invalid(p) == [(False, False, False)]


def test_decode_negative_temperature_and_unsigned_timestamp() -> None:
    p = decode_packets(P3_B, hires=False)
    assert p.accel.tolist() == [P3_B_ACCEL]
    assert p.gyro.tolist() == [P3_B_GYRO]
    assert p.temperature_c[0] == pytest.approx(P3_B_TEMP, abs=1e-9)  # about 15.34 degC
    assert p.timestamp.tolist() == [P3_B_TS]  # not -2
    assert _invalid(p) == [(False, False, False)]


def test_decoded_counts_are_wide_ints() -> None:
    p = decode_packets(P3_A, hires=False)
    assert np.issubdtype(p.gyro.dtype, np.signedinteger) and p.gyro.dtype.itemsize >= 4
    assert int((-p.gyro)[0, 2]) == 32768  # -(-32768) must not wrap


def test_decode_several_packets_in_order() -> None:
    p = decode_packets(P3_A + P3_B + P3_A, hires=False)
    assert p.n == 3
    assert p.accel.tolist() == [P3_A_ACCEL, P3_B_ACCEL, P3_A_ACCEL]
    assert p.gyro.tolist() == [P3_A_GYRO, P3_B_GYRO, P3_A_GYRO]
    assert p.timestamp.tolist() == [P3_A_TS, P3_B_TS, P3_A_TS]
    assert p.temperature_c.tolist() == pytest.approx([P3_A_TEMP, P3_B_TEMP, P3_A_TEMP])
    assert _invalid(p) == [(False, False, False)] * 3


@pytest.mark.parametrize("extra", [1, 8, 15])
def test_trailing_partial_packet_ignored(extra: int) -> None:
    p = decode_packets(P3_A + P3_B[:extra], hires=False)
    assert p.n == 1
    assert p.accel.tolist() == [P3_A_ACCEL]


@pytest.mark.parametrize("data", [b"", P3_A[:15]])
def test_no_whole_packet_gives_empty_arrays(data: bytes) -> None:
    p = decode_packets(data, hires=False)
    assert p.n == 0
    assert p.accel.shape == (0, 3) and p.gyro.shape == (0, 3)
    assert p.accel_invalid.shape == p.gyro_invalid.shape == p.temperature_invalid.shape == (0,)


def test_fifo_empty_header_ends_decoding() -> None:
    # packets after a 0x80 header are not returned, even if they look valid
    p = decode_packets(P3_A + P3_B + FIFO_EMPTY + P3_A, hires=False)
    assert p.n == 2
    assert p.accel.tolist() == [P3_A_ACCEL, P3_B_ACCEL]
    assert p.timestamp.tolist() == [P3_A_TS, P3_B_TS]


def test_fifo_empty_header_with_other_bits_ends_decoding() -> None:
    # bit 7 alone decides: 0xE8 has accel/gyro/timestamp bits too, but the FIFO is empty
    p = decode_packets(P3_A + bytes([0xE8]) + P3_B[1:] + P3_B, hires=False)
    assert p.n == 1


def test_fifo_empty_first_gives_nothing() -> None:
    p = decode_packets(FIFO_EMPTY + P3_A, hires=False)
    assert p.n == 0
    assert p.accel.shape == (0, 3)


def _invalid(p: Any) -> list[tuple[bool, bool, bool]]:
    """Per packet: (accel invalid, gyro invalid, temperature invalid)."""
    return list(
        zip(
            p.accel_invalid.tolist(),
            p.gyro_invalid.tolist(),
            p.temperature_invalid.tolist(),
            strict=True,
        )
    )


@pytest.mark.parametrize(
    ("packet", "accel_bad", "gyro_bad"),
    [
        (ACCEL_INVALID, True, False),  # accel x/y/z all -32768: the gyro is still data
        (GYRO_INVALID, False, True),  # gyro x/y/z all -32768: the accel is still data
        (ACCEL_INVALID[:7] + GYRO_INVALID[7:], True, True),  # both: nothing but temperature
        (bytes([0x28]) + P3_A[1:], True, False),  # header without ACCEL (bit 6)
        (bytes([0x48]) + P3_A[1:], False, True),  # header without GYRO (bit 5)
        (bytes([0x08]) + P3_A[1:], True, True),  # neither
        (P3_A, False, False),  # gyro z alone is -32768: still a sample
        (bytes([0x68, 0x80, 0x00, 0x80, 0x00, 0x80, 0x01]) + P3_A[7:], False, False),  # z -32767
    ],
)
def test_packet3_validity_per_sensor(packet: bytes, accel_bad: bool, gyro_bad: bool) -> None:
    assert len(packet) == 16
    p = decode_packets(packet, hires=False)
    assert p.n == 1
    # the temperature byte (21) is valid whatever the motion sensors say
    assert _invalid(p) == [(accel_bad, gyro_bad, False)]


@pytest.mark.parametrize(
    ("raw8", "celsius"),
    [
        (-128, None),  # 0x80: TDK's INVALID_VALUE_FIFO_1B, no new temperature
        (-127, -127 / 2.07 + 25.0),  # the lowest real reading, about -36.35 degC
        (127, 127 / 2.07 + 25.0),  # the highest, about 86.35 degC
        (0, 25.0),
    ],
)
def test_packet3_temperature_invalid_only_at_minus_128(raw8: int, celsius: float | None) -> None:
    packet = P3_A[:13] + bytes([raw8 & 0xFF]) + P3_A[14:]
    p = decode_packets(packet, hires=False)
    assert _invalid(p) == [(False, False, celsius is None)]  # accel and gyro unaffected
    if celsius is not None:
        assert p.temperature_c[0] == pytest.approx(celsius, abs=1e-9)
    assert p.accel.tolist() == [P3_A_ACCEL] and p.gyro.tolist() == [P3_A_GYRO]


def test_invalid_packet_among_valid_ones() -> None:
    no_temp = P3_B[:13] + bytes([0x80]) + P3_B[14:]
    p = decode_packets(P3_A + ACCEL_INVALID + no_temp + GYRO_INVALID, hires=False)
    assert _invalid(p) == [
        (False, False, False),
        (True, False, False),
        (False, False, True),
        (False, True, False),
    ]
    assert p.accel[1].tolist() == [-32768, -32768, -32768]  # counts still decoded
    assert p.gyro[1].tolist() == P3_A_GYRO  # the other sensor of that packet is kept
    assert p.gyro[3].tolist() == [-32768, -32768, -32768]
    assert p.accel[3].tolist() == P3_A_ACCEL
    assert p.accel[2].tolist() == P3_B_ACCEL and p.gyro[2].tolist() == P3_B_GYRO
    assert p.timestamp.tolist() == [P3_A_TS, P3_A_TS, P3_B_TS, P3_A_TS]


# --- packet 4 (20 bytes, hires) ------------------------------------------------------------------

# header 0x78 = ACCEL | GYRO | HEADER_20 | ODR timestamp. 20-bit value = bits[19:4] << 4 | nibble
P4_A = bytes(
    [
        0x78,
        0x08, 0x00,  # accel x  [19:4] 0x0800, [3:0] 0x0 -> 0x08000 = 32768 (1 g at 16 g)
        0xFF, 0xFF,  # accel y  [19:4] 0xFFFF, [3:0] 0xF -> 0xFFFFF = -1
        0x12, 0x34,  # accel z  [19:4] 0x1234, [3:0] 0x5 -> 0x12345 = 74565
        0xB6, 0xC1,  # gyro x   [19:4] 0xB6C1, [3:0] 0xF -> 0xB6C1F = -300001
        0xFF, 0xFF,  # gyro y   [19:4] 0xFFFF, [3:0] 0xE -> 0xFFFFE = -2
        0x7F, 0xFF,  # gyro z   [19:4] 0x7FFF, [3:0] 0xF -> 0x7FFFF = 524287
        0x0A, 0x58,  # temp     int16 2648 -> 2648/132.48 + 25 degC
        0xAB, 0xCD,  # timestamp 43981
        0x0F,        # x ext: accel 0x0, gyro 0xF
        0xFE,        # y ext: accel 0xF, gyro 0xE
        0x5F,        # z ext: accel 0x5, gyro 0xF
    ]
)  # fmt: skip
P4_A_ACCEL = [32768, -1, 74565]
P4_A_GYRO = [-300001, -2, 524287]
P4_A_TEMP = 2648 / 132.48 + 25.0
P4_A_TS = 0xABCD

P4_B = bytes(
    [
        0x78,
        0x80, 0x00,  # accel x  [19:4] 0x8000, [3:0] 0x1 -> 0x80001 = -524287 (not the marker)
        0x00, 0x00,  # accel y  0
        0x00, 0x01,  # accel z  [19:4] 0x0001, [3:0] 0x0 -> 16
        0x80, 0x00,  # gyro x   [19:4] 0x8000, [3:0] 0x0 -> -524288 (one axis only)
        0x00, 0x00,  # gyro y   [3:0] 0x7 -> 7
        0xFF, 0xF0,  # gyro z   [19:4] 0xFFF0, [3:0] 0x0 -> -256
        0xFC, 0xB8,  # temp     int16 -840 -> -840/132.48 + 25 degC
        0x00, 0x07,  # timestamp 7
        0x10,        # x ext: accel 0x1, gyro 0x0
        0x07,        # y ext: accel 0x0, gyro 0x7
        0x00,        # z ext
    ]
)  # fmt: skip
P4_B_ACCEL = [-524287, 0, 16]
P4_B_GYRO = [-524288, 7, -256]
P4_B_TEMP = -840 / 132.48 + 25.0
P4_B_TS = 7

MARKER20 = bytes([0x80, 0x00] * 3)  # bits [19:4] of -524288 on three axes


def test_decode_one_packet4() -> None:
    p = decode_packets(P4_A, hires=True)
    assert p.n == 1
    assert p.accel.tolist() == [P4_A_ACCEL]
    assert p.gyro.tolist() == [P4_A_GYRO]
    assert p.temperature_c[0] == pytest.approx(P4_A_TEMP, abs=1e-9)  # about 44.99 degC
    assert p.timestamp.tolist() == [P4_A_TS]
    assert _invalid(p) == [(False, False, False)]


def test_packet4_sign_extension_and_nibbles() -> None:
    p = decode_packets(P4_B, hires=True)
    assert p.accel.tolist() == [P4_B_ACCEL]
    assert p.gyro.tolist() == [P4_B_GYRO]
    assert p.temperature_c[0] == pytest.approx(P4_B_TEMP, abs=1e-9)  # about 18.66 degC
    assert p.timestamp.tolist() == [P4_B_TS]
    assert _invalid(p) == [(False, False, False)]  # gyro x alone at -524288 is a reading


def test_packet4_values_span_20_bits() -> None:
    p = decode_packets(P4_A + P4_B, hires=True)
    assert int(p.gyro.max()) == 2**19 - 1
    assert int(p.gyro.min()) == -(2**19)
    assert np.issubdtype(p.accel.dtype, np.signedinteger) and p.accel.dtype.itemsize >= 4


def test_several_packet4_then_partial_then_empty() -> None:
    p = decode_packets(P4_A + P4_B + P4_A[:19], hires=True)
    assert p.accel.tolist() == [P4_A_ACCEL, P4_B_ACCEL]
    q = decode_packets(P4_B + bytes([0x80] * 20) + P4_A, hires=True)
    assert q.accel.tolist() == [P4_B_ACCEL]


@pytest.mark.parametrize(
    ("packet", "accel_bad", "gyro_bad"),
    [
        (P4_A[:1] + MARKER20 + P4_A[7:17] + bytes([0x0F, 0x0E, 0x0F]), True, False),  # accel
        (P4_A[:7] + MARKER20 + P4_A[13:17] + bytes([0xF0, 0xF0, 0x50]), False, True),  # gyro
        # bits [19:4] look like the marker but accel x's nibble is 1: -524287, a real value
        (P4_A[:1] + MARKER20 + P4_A[7:17] + bytes([0x1F, 0x0E, 0x0F]), False, False),
        (bytes([0x68]) + P4_A[1:], True, True),  # no HEADER_20: no new 20-bit data at all
        (bytes([0x38]) + P4_A[1:], True, False),  # no ACCEL
        (bytes([0x58]) + P4_A[1:], False, True),  # no GYRO
        (P4_A, False, False),
    ],
)  # fmt: skip
def test_packet4_validity_per_sensor(packet: bytes, accel_bad: bool, gyro_bad: bool) -> None:
    assert len(packet) == 20
    p = decode_packets(packet, hires=True)
    assert p.n == 1
    # the int16 temperature (2648) is valid whatever the motion sensors say
    assert _invalid(p) == [(accel_bad, gyro_bad, False)]


def test_packet4_16_bit_marker_is_a_reading() -> None:
    # bits [19:4] = 0xF800 with nibble 0 on every axis: -32768 in 20 bits, not the marker
    m16 = bytes([0xF8, 0x00] * 3)
    p = decode_packets(P4_A[:1] + m16 + m16 + P4_A[13:17] + bytes(3), hires=True)
    assert p.accel.tolist() == [[-32768] * 3] and p.gyro.tolist() == [[-32768] * 3]
    assert _invalid(p) == [(False, False, False)]


def test_packet4_marker_decodes_to_minus_524288() -> None:
    packet = P4_A[:1] + MARKER20 + MARKER20 + P4_A[13:17] + bytes(3)
    p = decode_packets(packet, hires=True)
    assert p.accel.tolist() == [[-524288] * 3]
    assert p.gyro.tolist() == [[-524288] * 3]
    assert _invalid(p) == [(True, True, False)]


@pytest.mark.parametrize(
    ("raw16", "celsius"),
    [
        (-32768, None),  # 0x8000: no temperature (TDK INVALID_VALUE_FIFO, PX4)
        (-128, -128 / 132.48 + 25.0),  # the int8 marker means nothing in an int16 field
        (-32767, -32767 / 132.48 + 25.0),
        (0, 25.0),
    ],
)
def test_packet4_temperature_invalid_only_at_minus_32768(raw16: int, celsius: float | None) -> None:
    packet = P4_A[:13] + (raw16 & 0xFFFF).to_bytes(2, "big") + P4_A[15:]
    p = decode_packets(packet, hires=True)
    assert _invalid(p) == [(False, False, celsius is None)]
    if celsius is not None:
        assert p.temperature_c[0] == pytest.approx(celsius, abs=1e-9)
    assert p.accel.tolist() == [P4_A_ACCEL] and p.gyro.tolist() == [P4_A_GYRO]


# --- scale factors -------------------------------------------------------------------------------


@pytest.mark.parametrize(("range_g", "lsb_per_g"), [(2, 16384), (4, 8192), (8, 4096), (16, 2048)])
def test_accel_scale_16_bit(range_g: int, lsb_per_g: int) -> None:
    assert math.isclose(accel_scale_ms2(range_g, False) * lsb_per_g, G, rel_tol=1e-12)


@pytest.mark.parametrize(
    ("range_dps", "lsb_per_dps"),
    [
        (2000, 16.384),
        (1000, 32.768),
        (500, 65.536),
        (250, 131.072),
        (125, 262.144),
        (62.5, 524.288),
        (31.25, 1048.576),
        (15.625, 2097.152),
    ],
)
def test_gyro_scale_16_bit(range_dps: float, lsb_per_dps: float) -> None:
    scale = gyro_scale_rads(range_dps, False)
    assert math.isclose(scale * lsb_per_dps, math.pi / 180.0, rel_tol=1e-12)  # rad/s per LSB


def test_gyro_scale_matches_linux_table() -> None:
    # Linux rad/s per LSB at 2000 deg/s: 0.001065264 (reference section 2.2)
    assert gyro_scale_rads(2000, False) == pytest.approx(0.001065264, rel=1e-6)


def test_accel_scale_hires() -> None:
    # 20-bit at 16 g: 2^19 / 16 = 32768 counts per g (PX4: 8192 LSB/g after dropping 2 bits)
    assert math.isclose(accel_scale_ms2(16, True) * 32768, G, rel_tol=1e-12)
    assert math.isclose(accel_scale_ms2(16, True) * 4 * 8192, G, rel_tol=1e-12)


def test_gyro_scale_hires() -> None:
    # 20-bit at 2000 deg/s: 2^19 / 2000 = 262.144 counts per deg/s (PX4: 131.072 after /2)
    scale = gyro_scale_rads(2000, True)
    assert math.isclose(scale * 262.144, math.radians(1.0), rel_tol=1e-12)
    assert math.isclose(scale * 2 * 131.072, math.radians(1.0), rel_tol=1e-12)


def test_decoded_packets_in_si_units() -> None:
    p = decode_packets(P3_A, hires=False)
    assert p.accel[0, 0] * accel_scale_ms2(16, False) == pytest.approx(G, rel=1e-12)
    h = decode_packets(P4_A, hires=True)
    assert h.accel[0, 0] * accel_scale_ms2(16, True) == pytest.approx(G, rel=1e-12)
    # gyro z 524287 at 2000 deg/s hires is just under full scale
    assert math.degrees(h.gyro[0, 2] * gyro_scale_rads(2000, True)) == pytest.approx(
        2000 * 524287 / 524288, rel=1e-12
    )


# --- register plan, through the simulator --------------------------------------------------------

# bank 0
INTF_CONFIG0, INTF_CONFIG1, FIFO_CONFIG, FIFO_CONFIG1 = 0x4C, 0x4D, 0x16, 0x5F
PWR_MGMT0, GYRO_CONFIG0, ACCEL_CONFIG0, GYRO_ACCEL_CONFIG0 = 0x4E, 0x4F, 0x50, 0x52
TMST_CONFIG, WHO_AM_I = 0x54, 0x75
# bank 1 (gyro AAF) and bank 2 (accel AAF)
GYRO_CONFIG_STATIC2, GYRO_CONFIG_STATIC3, GYRO_CONFIG_STATIC4, GYRO_CONFIG_STATIC5 = (
    0x0B,
    0x0C,
    0x0D,
    0x0E,
)
ACCEL_CONFIG_STATIC2, ACCEL_CONFIG_STATIC3, ACCEL_CONFIG_STATIC4 = 0x03, 0x04, 0x05


def make_cfg(fields: dict[str, Any] | None = None) -> Icm42688pConfig:
    raw = {
        "name": "icm0",
        "chip": "icm42688p",
        "bus": {"kind": "sim", "transport": "spi", "cs": 0, "speed_hz": 20_000_000},
        **(fields or {}),
    }
    cfg = parse_config({"device": [raw]}).device[0]
    assert isinstance(cfg, Icm42688pConfig)
    return cfg


class RecordingChip:
    """Passes bus traffic to the simulator, noting (time, 'r'/'w', register, bytes) for each."""

    def __init__(self, sim: Icm42688pSim, clock: VirtualClock) -> None:
        self.sim = sim
        self.clock = clock
        self.log: list[tuple[int, str, int, bytes]] = []

    def read(self, register: int, length: int) -> bytes:
        data = self.sim.read(register, length)
        self.log.append((self.clock.now_ns(), "r", register, data))
        return data

    def write(self, register: int, data: bytes) -> None:
        self.log.append((self.clock.now_ns(), "w", register, bytes(data)))
        self.sim.write(register, data)

    def spi_select(self) -> bool:
        return self.sim.spi_select()

    def drain_truth(self) -> dict[str, Any] | None:
        return self.sim.drain_truth()


def make_sim(cfg: Icm42688pConfig) -> tuple[Icm42688pSim, Icm42688pDriver, VirtualClock]:
    clock = VirtualClock()
    assert cfg.sim is not None
    sim = Icm42688pSim(cfg.sim, clock)
    driver = Icm42688pDriver(cfg, SpiDevice(SimSpiDev(sim)), clock)
    return sim, driver, clock


def started(cfg: Icm42688pConfig) -> tuple[Icm42688pSim, Icm42688pDriver, VirtualClock]:
    sim, driver, clock = make_sim(cfg)
    start_blocking(driver, clock)
    return sim, driver, clock


PLAN_CASES: list[tuple[dict[str, Any], dict[int, int], dict[int, int], dict[int, int]]] = [
    (
        # 500 deg/s = FS_SEL 2, 4 g = FS_SEL 2, 8 kHz = ODR code 3, ODR/10 = UI code 4
        {
            "gyro_range_dps": 500,
            "accel_range_g": 4,
            "odr_hz": 8000,
            "ui_filter": "odr/10",
            "gyro_aaf_hz": 258,
            "accel_aaf_hz": "off",
        },
        {
            GYRO_CONFIG0: 0x43,
            ACCEL_CONFIG0: 0x43,
            GYRO_ACCEL_CONFIG0: 0x44,
            FIFO_CONFIG1: 0x07,  # ACCEL | GYRO | TEMP
        },
        # 258 Hz row: DELT 6, DELTSQR 36, BITSHIFT 10. STATIC2: bits 7 and 5 are undocumented
        # and set at reset (0xA0), so they stay; GYRO_AAF_DIS (bit 1) 0: AAF on; the notch
        # (GYRO_NF_DIS, bit 0) is not ours and stays on, as at reset
        {
            GYRO_CONFIG_STATIC2: 0xA0,
            GYRO_CONFIG_STATIC3: 6,
            GYRO_CONFIG_STATIC4: 36,
            GYRO_CONFIG_STATIC5: 0xA0,
        },
        {},  # accel AAF off: checked separately (bit 0)
    ),
    (
        # hires: 2000 deg/s = FS 0, 16 g = FS 0, 1 kHz = code 6, low_latency = UI code 14
        {
            "hires": True,
            "odr_hz": 1000,
            "ui_filter": "low_latency",
            "gyro_aaf_hz": "off",
            "accel_aaf_hz": 1163,
        },
        {GYRO_CONFIG0: 0x06, ACCEL_CONFIG0: 0x06, GYRO_ACCEL_CONFIG0: 0xEE, FIFO_CONFIG1: 0x17},
        {},  # gyro AAF off: checked separately (bit 1)
        # 1163 Hz row: DELT 24, DELTSQR 576 = 0x240, BITSHIFT 6
        {ACCEL_CONFIG_STATIC2: 24 << 1, ACCEL_CONFIG_STATIC3: 0x40, ACCEL_CONFIG_STATIC4: 0x62},
    ),
    (
        # 15.625 deg/s = FS 7, 2 g = FS 3, 500 Hz = code 15, ODR/2 = UI code 0
        {
            "gyro_range_dps": 15.625,
            "accel_range_g": 2,
            "odr_hz": 500,
            "ui_filter": "odr/2",
            "gyro_aaf_hz": 42,
            "accel_aaf_hz": 3979,
        },
        {GYRO_CONFIG0: 0xEF, ACCEL_CONFIG0: 0x6F, GYRO_ACCEL_CONFIG0: 0x00, FIFO_CONFIG1: 0x07},
        # 42 Hz row: DELT 1, DELTSQR 1, BITSHIFT 15
        {GYRO_CONFIG_STATIC3: 1, GYRO_CONFIG_STATIC4: 1, GYRO_CONFIG_STATIC5: 0xF0},
        # 3979 Hz row: DELT 63, DELTSQR 3968 = 0xF80, BITSHIFT 3
        {ACCEL_CONFIG_STATIC2: 0x7E, ACCEL_CONFIG_STATIC3: 0x80, ACCEL_CONFIG_STATIC4: 0x3F},
    ),
]


@pytest.mark.parametrize(("fields", "bank0", "bank1", "bank2"), PLAN_CASES)
def test_register_plan(
    fields: dict[str, Any], bank0: dict[int, int], bank1: dict[int, int], bank2: dict[int, int]
) -> None:
    sim, _, _ = started(make_cfg(fields))
    b0, b1, b2 = sim.banks[0], sim.banks[1], sim.banks[2]
    assert {reg: b0[reg] for reg in bank0} == bank0
    assert {reg: b1[reg] for reg in bank1} == bank1
    assert {reg: b2[reg] for reg in bank2} == bank2
    # the same for every configuration
    assert b0[FIFO_CONFIG] == 0x80  # [7:6] = 0b10: stop-on-full
    assert b0[PWR_MGMT0] == 0x0F  # gyro LN (3 << 2) | accel LN (3)
    assert b0[INTF_CONFIG0] == 0x30  # count BE, data BE, count in bytes, invalid marker on
    assert b0[INTF_CONFIG1] == 0x51  # AFSR 0b01 (adaptive full scale off), PLL clock
    assert b0[TMST_CONFIG] & 0x01  # TMST_EN
    assert not b0[TMST_CONFIG] & 0x04  # not delta mode: an absolute counter mod 2^16
    # reset 0x23: reserved bit 5 kept, FSYNC time-stamping (bit 1) off, 1 us ticks (bit 3 clear)
    assert b0[TMST_CONFIG] == 0x21
    assert sim.bank == 0  # bank select left at 0


def test_gyro_258_and_accel_off() -> None:
    sim, _, _ = started(make_cfg({"gyro_aaf_hz": 258, "accel_aaf_hz": "off"}))
    assert not sim.banks[1][GYRO_CONFIG_STATIC2] & 0x02  # gyro AAF on
    assert sim.banks[2][ACCEL_CONFIG_STATIC2] & 0x01  # ACCEL_AAF_DIS
    assert sim.bank == 0


def test_gyro_aaf_off_sets_dis_bit() -> None:
    sim, _, _ = started(make_cfg({"gyro_aaf_hz": "off"}))
    assert sim.banks[1][GYRO_CONFIG_STATIC2] & 0x02  # GYRO_AAF_DIS
    # accel default: the 1163 Hz row (the chip's reset row), AAF on
    assert sim.banks[2][ACCEL_CONFIG_STATIC2] == 0x30


@pytest.mark.parametrize(
    ("odr_hz", "code"),
    [
        (32000, 1),
        (16000, 2),
        (8000, 3),
        (4000, 4),
        (2000, 5),
        (1000, 6),
        (200, 7),
        (100, 8),
        (50, 9),
        (25, 10),
        (12.5, 11),
        (500, 15),
    ],
)
def test_odr_codes(odr_hz: float, code: int) -> None:
    sim, _, _ = started(make_cfg({"odr_hz": odr_hz, "gyro_range_dps": 1000, "accel_range_g": 8}))
    assert sim.banks[0][GYRO_CONFIG0] == 1 << 5 | code  # FS_SEL 1 = 1000 deg/s
    assert sim.banks[0][ACCEL_CONFIG0] == 1 << 5 | code  # FS_SEL 1 = 8 g


def test_started_chip_delivers_valid_packets_at_1g() -> None:
    # 4 g: 8192 LSB/g; the default simulated device is still and level (+z up)
    _, driver, clock = started(make_cfg({"accel_range_g": 4, "odr_hz": 1000}))
    clock.advance(20_000_000)  # 20 ms at 1 kHz: about 20 packets
    batch = driver.read()
    assert 15 <= batch.n <= 25
    acc, gyr = batch.channels[Channel.ACCEL], batch.channels[Channel.GYRO]
    temp = batch.channels[Channel.TEMPERATURE]
    # started after the gyro's start-up: every sensor of every packet holds data
    assert acc.invalid is None and gyr.invalid is None and temp.invalid is None
    assert np.all(np.abs(acc.data[:, 2] - 8192) < 800)
    assert acc.scale == pytest.approx(4 * G / 32768)
    assert gyr.scale == pytest.approx(math.radians(2000) / 32768)  # default 2000 deg/s
    assert acc.full_scale == gyr.full_scale == 32767
    assert temp.data.tolist() == pytest.approx([25.0] * batch.n, abs=0.5)  # int8, 2.07 LSB/C
    assert isinstance(batch.timing, FifoRead)
    counter = batch.timing.counter
    assert counter is not None and counter.modulo == 1 << 16  # the 16-bit FIFO timestamp
    assert counter.values.shape == (batch.n,)
    # consecutive packets 1 ms apart: 937.5 ticks of 32/30 us (docs/chips/icm42688p.md 3.3)
    steps = np.diff(counter.values) % (1 << 16)
    assert np.all((steps == 937) | (steps == 938))


def test_started_chip_hires_counts_at_1g() -> None:
    # hires 16 g: 32768 counts per g
    _, driver, clock = started(make_cfg({"hires": True, "odr_hz": 1000}))
    clock.advance(20_000_000)
    batch = driver.read()
    assert batch.n > 10
    acc, gyr = batch.channels[Channel.ACCEL], batch.channels[Channel.GYRO]
    assert acc.invalid is None and gyr.invalid is None
    assert np.all(np.abs(acc.data[:, 2] - 32768) < 3300)
    assert np.all(acc.data % 4 == 0)  # 18-bit effective accel: the low two bits read 0
    assert acc.scale == pytest.approx(16 * G / 2**19)
    assert gyr.scale == pytest.approx(math.radians(2000) / 2**19)
    assert acc.full_scale == gyr.full_scale == 2**19 - 1


def test_start_up_marks_each_sensor_invalid_on_its_own() -> None:
    """Sensors just turned on deliver the invalid marker until their start-up time is over;
    the accel starts sooner than the gyro, so for a while a packet has accel data and no gyro
    data. Each sensor's mask says so, and the packets with neither count as invalid packets."""
    odr = 1000.0
    sim, driver, clock = started(make_cfg({"odr_hz": odr}))
    driver.read()  # drain what came since the start
    sim.advance()
    sim.on_since_ns = clock.now_ns()  # both sensors restart now (as after a glitch)
    clock.advance(int(1.5 * GYRO_STARTUP_NS))
    batch = driver.read()
    acc, gyr = batch.channels[Channel.ACCEL], batch.channels[Channel.GYRO]
    temp = batch.channels[Channel.TEMPERATURE]
    assert acc.invalid is not None and gyr.invalid is not None
    n_acc, n_gyr = int(acc.invalid.sum()), int(gyr.invalid.sum())
    # the simulated start-up times at 1 kHz, give or take the sample grid's phase
    assert abs(n_acc - ACCEL_STARTUP_NS * odr / 1e9) <= 1
    assert abs(n_gyr - GYRO_STARTUP_NS * odr / 1e9) <= 1
    # the first packets after the restart, not scattered ones
    assert acc.invalid.tolist() == [True] * n_acc + [False] * (batch.n - n_acc)
    assert gyr.invalid.tolist() == [True] * n_gyr + [False] * (batch.n - n_gyr)
    # packets with accel data and no gyro data: the accel reads 1 g (2048 LSB/g at 16 g)
    only_gyro_bad = gyr.invalid & ~acc.invalid
    assert only_gyro_bad.sum() == n_gyr - n_acc > 0
    assert np.all(np.abs(acc.data[only_gyro_bad, 2] - 2048) < 200)
    assert np.all(gyr.data[only_gyro_bad] == -32768)  # the marker, masked, not data
    assert temp.invalid is None  # the temperature sensor did not restart
    assert driver.invalid_packets == n_acc  # no motion data at all in those


def test_plan_rechecks_every_configured_register_of_every_bank() -> None:
    _, driver, _ = started(make_cfg())
    checked = {(s.bank, s.register) for s in driver.plan.settings}
    bank0 = (INTF_CONFIG0, INTF_CONFIG1, FIFO_CONFIG, FIFO_CONFIG1, PWR_MGMT0, GYRO_CONFIG0,
             ACCEL_CONFIG0, GYRO_ACCEL_CONFIG0, TMST_CONFIG)  # fmt: skip
    assert {(0, r) for r in bank0} <= checked
    gyro_aaf = (GYRO_CONFIG_STATIC2, GYRO_CONFIG_STATIC3, GYRO_CONFIG_STATIC4, GYRO_CONFIG_STATIC5)
    assert {(1, r) for r in gyro_aaf} <= checked
    accel_aaf = (ACCEL_CONFIG_STATIC2, ACCEL_CONFIG_STATIC3, ACCEL_CONFIG_STATIC4)
    assert {(2, r) for r in accel_aaf} <= checked


@pytest.mark.parametrize(
    ("bank", "register", "corrupt", "where"),
    [
        (1, GYRO_CONFIG_STATIC3, 6, "bank 1 register 0x0c"),  # gyro AAF DELT 13 -> 6
        (1, GYRO_CONFIG_STATIC2, 0xA2, "bank 1 register 0x0b"),  # GYRO_AAF_DIS set
        (2, ACCEL_CONFIG_STATIC4, 0x80, "bank 2 register 0x05"),  # accel AAF BITSHIFT 6 -> 8
    ],
)
def test_corrupted_aaf_register_is_detected_by_the_periodic_check(
    bank: int, register: int, corrupt: int, where: str
) -> None:
    """One configured register is re-checked every 100 ms, round robin over all banks: a
    corrupted anti-alias filter register in bank 1 or 2 is found within one round."""
    sim, driver, clock = started(make_cfg())
    rounds = len(driver.plan.settings)
    for _ in range(rounds + 2):  # a whole clean round first: no false alarm
        clock.advance(100_000_001)
        driver.read()
    assert driver.counters.bad_registers == 0
    sim.banks[bank][register] = corrupt  # behind the driver's back
    with pytest.raises(RegisterMismatch) as info:
        for _ in range(rounds + 1):
            clock.advance(100_000_001)
            driver.read()
    assert where in str(info.value)
    assert driver.counters.bad_registers == 1
    assert sim.bank == 0  # bank 0 selected again: the FIFO reads that follow still work


class HoldsReservedBits:
    """A chip whose registers hold bits imud does not configure (reserved, or reset values of
    fields not ours) from its soft reset on: the simulator plus bits OR-ed in at reset."""

    def __init__(self, sim: Icm42688pSim, held: dict[tuple[int, int], int]) -> None:
        self.sim, self.held = sim, held

    def read(self, register: int, length: int) -> bytes:
        return self.sim.read(register, length)

    def write(self, register: int, data: bytes) -> None:
        reset = register == 0x11 and self.sim.bank == 0 and data[0] & 0x01  # SOFT_RESET_CONFIG
        self.sim.write(register, data)
        if reset:
            for (bank, reg), bits in self.held.items():
                self.sim.banks[bank][reg] |= bits

    def spi_select(self) -> bool:
        return self.sim.spi_select()

    def drain_truth(self) -> Any:
        return self.sim.drain_truth()


def test_reserved_bits_the_chip_holds_survive_configuration() -> None:
    """Configuration is read-modify-write: bits outside imud's fields keep what the chip holds,
    and the periodic check does not take them for a corrupted register."""
    held = {
        (0, GYRO_CONFIG0): 0x10,  # bit 4: between FS_SEL [7:5] and ODR [3:0]
        (0, ACCEL_CONFIG0): 0x10,
        (0, PWR_MGMT0): 0xC0,  # above TEMP_DIS (5), IDLE (4) and the two mode fields
        (1, GYRO_CONFIG_STATIC3): 0xC0,  # above GYRO_AAF_DELT [5:0]
        (2, ACCEL_CONFIG_STATIC2): 0x80,  # above ACCEL_AAF_DELT [6:1]
    }
    cfg = make_cfg()  # 2000 deg/s, 16 g, 1 kHz, UI filter ODR/4, AAF rows 585 / 1163 Hz
    clock = VirtualClock()
    assert cfg.sim is not None
    sim = Icm42688pSim(cfg.sim, clock)
    driver = Icm42688pDriver(cfg, SpiDevice(SimSpiDev(HoldsReservedBits(sim, held))), clock)
    start_blocking(driver, clock)
    b0, b1, b2 = sim.banks[0], sim.banks[1], sim.banks[2]
    assert b0[GYRO_CONFIG0] == 0x10 | 0x06  # FS_SEL 0 (2000 deg/s), ODR code 6 (1 kHz)
    assert b0[ACCEL_CONFIG0] == 0x10 | 0x06  # FS_SEL 0 (16 g), ODR code 6
    assert b0[PWR_MGMT0] == 0xC0 | 0x0F  # gyro and accel low-noise
    assert b1[GYRO_CONFIG_STATIC3] == 0xC0 | 13  # 585 Hz row: DELT 13
    assert b2[ACCEL_CONFIG_STATIC2] == 0x80 | 24 << 1  # 1163 Hz row: DELT 24, AAF on
    # and the undocumented bits set at reset (docs/chips/icm42688p.md, Status)
    assert b0[TMST_CONFIG] & 0x20 and b0[INTF_CONFIG1] & 0x10
    assert b1[GYRO_CONFIG_STATIC2] & 0xA0 == 0xA0
    for _ in range(len(driver.plan.settings) + 2):  # a whole round of the periodic check
        clock.advance(100_000_001)
        assert driver.read().n > 0
    assert driver.counters.bad_registers == 0


def test_wrong_who_am_i_raises_identity_error() -> None:
    sim, driver, clock = make_sim(make_cfg())
    sim.banks[0][WHO_AM_I] = 0x40  # an ICM-42600
    with pytest.raises(DeviceIdentityError) as info:
        start_blocking(driver, clock)
    msg = str(info.value)
    assert "0x40" in msg  # what it read
    assert "0x47" in msg  # what an ICM-42688-P answers
    assert sim.banks[0][PWR_MGMT0] == 0x00  # nothing turned on
    assert sim.banks[0][FIFO_CONFIG] == 0x00  # nothing configured


def test_stale_bank_selected_still_identifies() -> None:
    # a bank left selected by a previous run: WHO_AM_I must be read from bank 0
    sim, driver, clock = make_sim(make_cfg())
    sim.bank = 2
    start_blocking(driver, clock)
    assert sim.banks[0][PWR_MGMT0] == 0x0F
    assert sim.bank == 0


def test_no_register_write_within_200us_of_power_on() -> None:
    cfg = make_cfg()
    clock = VirtualClock()
    assert cfg.sim is not None
    rec = RecordingChip(Icm42688pSim(cfg.sim, clock), clock)
    driver = Icm42688pDriver(cfg, SpiDevice(SimSpiDev(rec)), clock)
    start_blocking(driver, clock)
    writes = [(t, reg, data) for t, op, reg, data in rec.log if op == "w"]
    on = [i for i, (_, reg, data) in enumerate(writes) if reg == PWR_MGMT0 and data[0] & 0x0F]
    assert on, "PWR_MGMT0 never turned a sensor on"
    t_on = writes[on[-1]][0]
    later = [t - t_on for t, _, _ in writes[on[-1] + 1 :]]
    assert all(dt >= 200_000 for dt in later), later
