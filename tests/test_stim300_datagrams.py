"""STIM300 datagrams, byte by byte: the CRC against hand-checked values, the layouts against the
datasheet's size table, and the driver reading crafted bytes from a real pseudo-terminal: values
and scale factors, STATUS flags, the counter, resynchronisation after damage with exact counts,
and the errors a wrong stream gives.

Expected values come from the datasheet (TS1524 rev.31; docs/chips/stim300.md) written here, and
CRCs from a bit-by-bit implementation of the CRC's definition written here (not the library the
driver uses)."""

from __future__ import annotations

import binascii
import os
import tty
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from imud.buses.serial import open_serial
from imud.channels import Channel, SampleFlag
from imud.chips.api import FifoRead, start_blocking
from imud.chips.stim300.config import Stim300Config
from imud.chips.stim300.datagram import crc32, layout
from imud.chips.stim300.driver import Stim300Driver
from imud.chips.stim300.registers import DatagramId
from imud.clock import MonotonicClock
from imud.config import parse_config
from imud.errors import DeviceIdentityError

G0 = 9.80665  # the datasheet's k0


def crc_by_definition(data: bytes) -> int:
    """CRC-32, polynomial x^32+x^26+x^23+x^22+x^16+x^12+x^11+x^10+x^8+x^7+x^5+x^4+x^2+x+1
    (0x04C11DB7), register preset to 0xFFFFFFFF, bytes MSB first, no reflection, no final XOR:
    one bit at a time, as the datasheet's section 5.5.7 defines it."""
    reg = 0xFFFFFFFF
    for byte in data:
        for bit in range(7, -1, -1):
            top = (reg >> 31) ^ ((byte >> bit) & 1)
            reg = (reg << 1) & 0xFFFFFFFF
            if top:
                reg ^= 0x04C11DB7
    return reg


def test_crc_check_value_of_the_catalogue() -> None:
    # CRC-32/MPEG-2's catalogue check value (the CRC of ASCII "123456789")
    assert crc_by_definition(b"123456789") == 0x0376E6E7
    assert crc32(b"12345678") == crc_by_definition(b"12345678")  # 8 bytes: no padding


def test_crc_pads_with_zero_bytes_to_whole_words() -> None:
    msg = bytes((i * 37 + 0xA7) & 0xFF for i in range(55))
    # 0xA7 has 55 bytes before its CRC: one dummy 0x00 byte for the calculation
    assert crc32(msg) == crc_by_definition(msg + b"\x00")
    assert crc32(msg) != crc_by_definition(msg)
    # 0x94 has 21: three dummy bytes
    assert crc32(msg[:21]) == crc_by_definition(msg[:21] + b"\x00\x00\x00")


def crc_via_zlib(data: bytes) -> int:
    """The same CRC from Python's reflected CRC-32 (zlib): bit-reverse every input byte and the
    result, and undo zlib's final XOR (CRC-32/MPEG-2 = CRC-32/BZIP2 without its final XOR)."""

    def rev(x: int, bits: int) -> int:
        return int(f"{x:0{bits}b}"[::-1], 2)

    return rev(binascii.crc32(bytes(rev(b, 8) for b in data)), 32) ^ 0xFFFFFFFF


# Datagrams written out byte by byte, their CRCs computed by hand with both methods above and
# written down: ID, clusters, counter, latency; the dummy zero bytes are not part of them.
HAND_CHECKED = [
    # 0x90: gyro x +1 deg/s (0x004000), y -1 deg/s (0xFFC000), z 0; counter 0x10; 300 us
    ("90 004000 ffc000 000000 00 10 012c", 0xD09B877E),
    # 0x91: gyro 0; accel z +1 g on a 10 g unit (2^19 = 0x080000); counter 0x20; 200 us
    ("91 000000 000000 000000 00 000000 000000 080000 00 20 00c8", 0x07376365),
    # 0x94: gyro z +1 deg/s; temperatures 25 degC (0x1900 = 6400 x 2^-8); counter 5; 400 us
    ("94 000000 000000 004000 00 1900 1900 1900 00 05 0190", 0x7C9FA6FF),
]


@pytest.mark.parametrize(("hexbytes", "crc"), HAND_CHECKED)
def test_crc_of_hand_checked_datagrams(hexbytes: str, crc: int) -> None:
    msg = bytes.fromhex(hexbytes)
    pad = bytes(-len(msg) % 4)
    assert crc_by_definition(msg + pad) == crc == crc_via_zlib(msg + pad)
    assert crc32(msg) == crc
    assert binascii.crc32(msg + pad) != crc  # Python's own CRC-32 is another CRC


@pytest.mark.parametrize(
    ("ident", "before_crc", "total"),
    [
        (0x90, 14, 18),
        (0x91, 24, 28),
        (0x92, 24, 28),
        (0x93, 34, 38),
        (0x94, 21, 25),
        (0xA5, 38, 42),
        (0xA6, 38, 42),
        (0xA7, 55, 59),
    ],
)
def test_datagram_sizes_match_the_datasheet_table(ident: int, before_crc: int, total: int) -> None:
    lay = layout(DatagramId(ident))
    assert (lay.crc, lay.size) == (before_crc, total)
    assert layout(DatagramId(ident), terminated=True).size == total + 2  # CR LF


# --- crafting datagrams, independently of the driver's layout code ----------------------------
def be24(v: int) -> bytes:
    return (v & 0xFFFFFF).to_bytes(3, "big")


def be16(v: int) -> bytes:
    return (v & 0xFFFF).to_bytes(2, "big")


def dg_a7(
    counter: int,
    gyro: tuple[int, int, int] = (0, 0, 0),
    acc: tuple[int, int, int] = (0, 0, 1 << 19),
    incl: tuple[int, int, int] = (0, 0, 1 << 22),
    temp: tuple[int, int, int] = (6400, 6400, 6400),
    status: int = 0,
    latency_us: int = 300,
) -> bytes:
    """A 0xA7 datagram: ID, gyro, acc, incl clusters (3x24-bit + STATUS), three temperature
    clusters (3x16-bit + STATUS), counter, latency, CRC (datasheet Table 5-20 order)."""
    body = bytes([0xA7])
    for cluster in (gyro, acc, incl):
        body += b"".join(be24(v) for v in cluster) + bytes([status])
    for _ in range(3):
        body += b"".join(be16(v) for v in temp) + bytes([status])
    body += bytes([counter & 0xFF]) + be16(latency_us)
    assert len(body) == 55
    return body + crc_by_definition(body + b"\x00").to_bytes(4, "big")


def dg_93(counter: int) -> bytes:
    body = bytes([0x93]) + bytes(30) + bytes([counter & 0xFF]) + be16(250)
    assert len(body) == 34
    return body + crc_by_definition(body + b"\x00\x00").to_bytes(4, "big")  # 2 dummy bytes


class Link:
    """A real pty: the test writes the unit's bytes into the master; the driver reads the slave
    through pyserial."""

    def __init__(self, baud: int = 1_843_200) -> None:
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.port = open_serial(os.ttyname(slave), baud)
        os.close(slave)

    def send(self, data: bytes) -> None:
        os.write(self.master, data)

    def close(self) -> None:
        self.port.close()
        os.close(self.master)


def cfg(**kw: Any) -> Stim300Config:
    d = {
        "name": "s",
        "chip": "stim300",
        "bus": {"kind": "serial", "port": "/dev/ttyUSB0", "baud": 1_843_200},
        **kw,
    }
    c: Stim300Config = parse_config({"device": [d]}).device[0]
    return c


@pytest.fixture
def link() -> Iterator[Link]:
    ln = Link()
    yield ln
    ln.close()


def read_all(driver: Stim300Driver) -> list[Any]:
    """Every batch the driver has for what was sent (a batch never spans a counter gap)."""
    import time

    time.sleep(0.05)  # the pty hands the bytes over
    out = [driver.read()]
    while driver._held:
        out.append(driver.read())
    return [b for b in out if b.n]


def started(link: Link, c: Stim300Config, first: list[bytes]) -> Stim300Driver:
    d = Stim300Driver(c, link.port, MonotonicClock())
    gen = d.start()
    next(gen)  # it flushed the input and waits for the stream
    link.send(b"".join(first))
    import time

    time.sleep(0.05)
    for _ in gen:
        pass
    return d


def test_values_scale_factors_and_status(link: Link) -> None:
    """1 deg/s = 2^14 LSB; 10 g variant: 1 g = 2^19 LSB; inclinometer 1 g = 2^22 LSB;
    temperature 2^-8 degC per LSB."""
    d = started(link, cfg(datagram="rate_acc_incl_temp", odr_hz=2000), [dg_a7(0), dg_a7(1)])
    link.send(
        dg_a7(2, gyro=(1 << 14, -(1 << 13), 100 << 14), acc=(1 << 19, -(2 << 19), 0),
              incl=(1 << 21, 0, -(1 << 22)), temp=(6528, 6528 + 256, 6528 - 256))
        + dg_a7(3, status=0x40)  # start-up: not valid yet
        + dg_a7(4, status=0x10 | 0x04)  # overload on Z: an alarm, still valid
    )  # fmt: skip
    batches = read_all(d)
    assert [b.n for b in batches] == [5]  # the two from start() are not dropped
    b = batches[0]
    gyro = b.channels[Channel.GYRO]
    g = gyro.data[2] * gyro.scale
    assert g == pytest.approx(np.radians([1.0, -0.5, 100.0]))
    acc = b.channels[Channel.ACCEL]
    assert acc.data[2] * acc.scale == pytest.approx([G0, -2 * G0, 0.0])
    inc = b.channels[Channel.INCLINATION]
    assert inc.data[2] * inc.scale == pytest.approx([0.5 * G0, 0.0, -G0])
    t = b.channels[Channel.TEMPERATURE]
    assert t.data[2] * t.scale == pytest.approx(25.5)  # 6528 / 256; the gyro cluster's mean
    # start-up invalidates every cluster of that sample; overload is an alarm only
    for ch in (Channel.GYRO, Channel.ACCEL, Channel.INCLINATION, Channel.TEMPERATURE):
        inv = b.channels[ch].invalid
        assert inv is not None and inv.tolist() == [False, False, False, True, False], ch
    assert b.alarm is not None and b.alarm.tolist() == [False, False, False, True, True]
    assert isinstance(b.timing, FifoRead)
    assert b.timing.counter is not None and b.timing.counter.values.tolist() == [0, 1, 2, 3, 4]
    st = d.chip_status()
    assert st["status_counts"] == {"Z": 1, "OVERLOAD": 1, "STARTUP": 1}
    assert SampleFlag.GYRO_INVALID == Channel.GYRO  # a hole in the pipeline's terms: all invalid


def test_gyro_saturation_is_flagged_at_480_dps(link: Link) -> None:
    d = started(link, cfg(odr_hz=2000), [dg_a7(0), dg_a7(1)])
    link.send(dg_a7(2, gyro=(480 << 14, 0, 0)))
    b = read_all(d)[0]
    gyro = b.channels[Channel.GYRO]
    assert gyro.full_scale == 480 * 2**14
    assert np.abs(gyro.data[2]).max() >= gyro.full_scale


def test_resync_after_damage_counts_exactly(link: Link) -> None:
    """Ten datagrams; 7 garbage bytes (one of them the ID byte) before #4; one bit flipped in
    #6; one byte dropped from #8. The driver publishes the eight intact ones, never a damaged
    one, resynchronises within a datagram each time, and splits batches at the counter gaps."""
    d = started(link, cfg(odr_hz=2000), [dg_a7(0), dg_a7(1)])
    frames = [dg_a7(c, gyro=(c, 0, 0)) for c in range(2, 12)]
    garbage = bytes([0x12, 0x34, 0xA7, 0x00, 0xFF, 0x55, 0x01])
    bad6 = bytearray(frames[6])
    bad6[20] ^= 0x08
    frames[6] = bytes(bad6)
    frames[8] = frames[8][:30] + frames[8][31:]
    stream = b"".join(frames[:4]) + garbage + b"".join(frames[4:])
    link.send(stream)
    batches = read_all(d)
    got = np.concatenate([b.channels[Channel.GYRO].data[:, 0] for b in batches]).tolist()
    assert got == [0, 0, 2, 3, 4, 5, 6, 7, 9, 11]  # counters 8 and 10 never published
    assert [b.timing.resync for b in batches] == [False, True, True]
    st = d.chip_status()
    assert d.counters.chip["crc_errors"] == 2  # #6 and #8 began with the ID where one was due
    assert st["resyncs"] == 3
    assert st["skipped_bytes"] == 7 + 59 + 58
    assert st["counter_gaps"] == 2
    assert d.counters.bad_transfers == 2


def test_a_datagram_split_across_reads_is_reassembled(link: Link) -> None:
    d = started(link, cfg(odr_hz=2000), [dg_a7(0), dg_a7(1)])
    read_all(d)
    x = dg_a7(2, gyro=(7, 8, 9))
    link.send(x[:17])
    assert read_all(d) == []
    link.send(x[17:])
    (b,) = read_all(d)
    assert b.channels[Channel.GYRO].data.tolist() == [[7, 8, 9]]
    assert not b.timing.resync


def test_counter_wraps_without_a_gap_and_steps_by_rate(link: Link) -> None:
    """At 500 samples/s the counter (of the unit's 2000 Hz samples) steps by 4 and wraps at 256."""
    d = started(link, cfg(odr_hz=500), [dg_a7(248), dg_a7(252)])
    link.send(dg_a7(0) + dg_a7(4) + dg_a7(12))  # 8 missing
    batches = read_all(d)
    assert [b.n for b in batches] == [4, 1]
    assert batches[1].timing.resync
    assert d.chip_status()["counter_gaps"] == 1


def test_brackets_move_back_by_latency_and_wire_time(link: Link) -> None:
    """The newest datagram's sample preceded its first byte by its latency field; its 59 bytes
    took 59 x 10 bits at 1 843 200 bit/s = 320.1 us on the line."""
    import time

    d = started(link, cfg(odr_hz=2000), [dg_a7(0), dg_a7(1)])
    read_all(d)
    link.send(dg_a7(2, latency_us=700))
    time.sleep(0.05)
    t0 = time.monotonic_ns()
    b = d.read()
    t1 = time.monotonic_ns()
    back = 700_000 + 59 * 10 * 1e9 / 1_843_200
    assert isinstance(b.timing, FifoRead)
    assert t0 - back - 1000 <= b.timing.t_before_ns <= b.timing.t_after_ns <= t1 - back + 1000


# --- start-up diagnosis -----------------------------------------------------------------------
def test_a_unit_sending_another_datagram_is_named_with_the_fix(link: Link) -> None:
    d = Stim300Driver(cfg(datagram="rate_acc_incl_temp"), link.port, MonotonicClock())
    gen = d.start()
    next(gen)
    link.send(b"".join(dg_93(c) for c in range(40)))
    with pytest.raises(DeviceIdentityError) as e:
        for _ in gen:
            pass
    assert "0x93" in str(e.value) and 'datagram = "rate_acc_incl"' in str(e.value)


def test_a_silent_port_says_what_to_check(link: Link) -> None:
    d = Stim300Driver(cfg(), link.port, MonotonicClock())
    with pytest.raises(DeviceIdentityError) as e:
        start_blocking(d, MonotonicClock())
    assert "no bytes" in str(e.value) and "RS422 wiring" in str(e.value)


def test_noise_at_the_wrong_baud_names_the_baud(link: Link) -> None:
    d = Stim300Driver(cfg(), link.port, MonotonicClock())
    gen = d.start()
    next(gen)
    link.send(bytes((i * 73 + 11) & 0xFF for i in range(600)).replace(b"\xa7", b"\x00"))
    with pytest.raises(DeviceIdentityError) as e:
        for _ in gen:
            pass
    assert "bus.baud" in str(e.value) and "no valid STIM300 datagram" in str(e.value)


def test_a_rate_other_than_configured_is_named(link: Link) -> None:
    d = Stim300Driver(cfg(odr_hz=2000), link.port, MonotonicClock())
    gen = d.start()
    next(gen)
    link.send(dg_a7(0) + dg_a7(2) + dg_a7(4))  # steps of 2: 1000 samples/s
    with pytest.raises(DeviceIdentityError) as e:
        for _ in gen:
            pass
    assert "1000 Hz" in str(e.value) and "odr_hz = 1000" in str(e.value)
