"""Every decoder fed garbage, with hypothesis (issue 10): the FIFO parsers, the burst frame, the
serial datagram framer, the UART protocol and the wire format never crash on bytes off a bus or
a network. They return a valid result, raise the error the caller handles (`WireError`, a
`BusError` the device runner counts and retries, a ValueError on a failed checksum), or count a
bad frame; and what a valid encoding says, they decode exactly.

Runs derandomized with few examples, so the suite stays fast and deterministic;
`bench/fuzz_long.py` runs the same properties with many more (IMUD_FUZZ_EXAMPLES=N)."""

from __future__ import annotations

import os
import struct
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from imud import wire
from imud.channels import ORDER, Channel
from imud.chips.adis16465 import decode as adis
from imud.chips.api import RawBatch
from imud.chips.bmi088 import decode as bmi
from imud.chips.bmi088.registers import AccFifoHeader
from imud.chips.icm42688p import registers as icm_r
from imud.chips.icm42688p.driver import PACKET3, PACKET4, decode_packets, timestamp_breaks
from imud.chips.mpu6050.driver import decode_fifo, decode_status_block
from imud.chips.stim300.datagram import Framer, crc32, layout, valid
from imud.chips.stim300.registers import CRC_BYTES, TERMINATION, DatagramId
from imud.clock import VirtualClock
from imud.config import parse_config
from imud.errors import BusError, DeviceIdentityError

# --- settings shared with tests/test_fuzz_loaders.py and bench/fuzz_long.py ------------------

LONG_EXAMPLES = int(os.environ.get("IMUD_FUZZ_EXAMPLES", "0") or 0)


def fuzz(examples: int) -> settings:
    """The suite's settings (`examples`, derandomized: CI is deterministic), or the long run's
    when IMUD_FUZZ_EXAMPLES is set (that many examples each, a fresh random seed)."""
    if LONG_EXAMPLES:
        return settings(
            max_examples=LONG_EXAMPLES,
            deadline=None,
            derandomize=False,
            database=None,
            suppress_health_check=list(HealthCheck),
            print_blob=True,
        )
    return settings(
        max_examples=examples,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )


# What the device runner handles from a driver (imud/device.py `_EXPECTED`): anything else is
# an "unexpected" error, i.e. a bug
RUNNER_HANDLES = (BusError, DeviceIdentityError, OSError)


def check_batch(b: RawBatch) -> None:
    """A driver's batch is consistent: every channel has a row per sample."""
    while b is not None:
        assert b.n >= 0
        for ch, rc in b.channels.items():
            assert rc.data.shape[0] == b.n, (ch, rc.data.shape, b.n)
            if rc.invalid is not None:
                assert rc.invalid.shape == (b.n,), ch
        if b.alarm is not None:
            assert b.alarm.shape == (b.n,)
        b = b.then  # type: ignore[assignment]


def poll(driver: Any, polls: int, between: Callable[[], object] | None = None) -> list[RawBatch]:
    """`polls` reads, as the runner does them: a handled error ends a read, not the run.
    `between`, before each read: e.g. time passing."""
    out = []
    for _ in range(polls):
        if between is not None:
            between()
        try:
            b = driver.read()
        except RUNNER_HANDLES:
            continue
        check_batch(b)
        out.append(b)
    return out


class GarbageRegisters:
    """A register device (I2C or SPI) whose every read answers bytes hypothesis chooses, of
    the length asked (a bus transfer never returns another length)."""

    address = 0x68

    def __init__(self, data: st.DataObject, bias: Callable[[int, int], st.SearchStrategy[bytes]]):
        self.data, self.bias = data, bias

    def read(self, register: int, length: int) -> bytes:
        out: bytes = self.data.draw(self.bias(register, length))
        return out

    def read_u8(self, register: int) -> int:
        return self.read(register, 1)[0]

    def write_u8(self, register: int, value: int) -> None:
        pass

    def write(self, register: int, data: bytes) -> None:
        pass


def exactly(n: int) -> st.SearchStrategy[bytes]:
    return st.binary(min_size=n, max_size=n)


def any_bytes(register: int, length: int) -> st.SearchStrategy[bytes]:
    return st.one_of(exactly(length), st.just(bytes(length)), st.just(b"\xff" * length))


def device_cfg(chip: str, **fields: Any) -> Any:
    bus: dict[str, Any] = {"kind": "sim", "bus": "b0", "address": 0x68}
    if chip in ("icm42688p", "bmi088"):
        bus = {"kind": "sim", "bus": "s0", "transport": "spi", "cs": 0}
    d = {"name": "f0", "chip": chip, "bus": bus, **fields}
    if chip == "bmi088":
        d.setdefault("gyro_bus", {"kind": "sim", "bus": "s0", "transport": "spi", "cs": 1})
    return parse_config({"device": [d]}).device[0]


# --- MPU6050 ---------------------------------------------------------------------------------


@fuzz(60)
@given(st.binary(max_size=1100))
def test_mpu6050_fifo_garbage_decodes_to_whole_samples(data: bytes) -> None:
    accel, gyro = decode_fifo(data)
    n = len(data) // 12
    assert accel.shape == gyro.shape == (n, 3)
    assert accel.dtype == np.int32 and int(np.abs(accel).max(initial=0)) <= 32768


@fuzz(40)
@given(
    st.lists(st.lists(st.integers(-32768, 32767), min_size=6, max_size=6), max_size=85),
    st.binary(max_size=11),
)
def test_mpu6050_fifo_round_trips(words: list[list[int]], tail: bytes) -> None:
    """Whole samples decode exactly; a partial sample at the end (a read that raced the
    chip) is left for the next read."""
    raw = np.asarray(words, dtype=">i2").reshape(-1, 6)
    accel, gyro = decode_fifo(raw.tobytes() + tail)
    assert accel.tolist() == raw[:, :3].tolist() and gyro.tolist() == raw[:, 3:].tolist()


@fuzz(50)
@given(st.binary(max_size=20))
def test_mpu6050_status_block_is_9_bytes_or_a_bus_error(block: bytes) -> None:
    try:
        status, temp = decode_status_block(block)
    except BusError as e:
        assert len(block) != 9 and str(len(block)) in str(e)
        return
    assert status == block[0] and -32768 <= temp <= 32767


@fuzz(25)
@given(st.data())
def test_mpu6050_driver_survives_a_garbage_bus(data: st.DataObject) -> None:
    from imud.chips.mpu6050.driver import Mpu6050Driver

    driver = Mpu6050Driver(device_cfg("mpu6050"), GarbageRegisters(data, any_bytes), VirtualClock())
    poll(driver, 4)


# --- ICM-42688-P (read only: crashes are reported, not fixed here) ---------------------------


@fuzz(60)
@given(st.binary(max_size=2100), st.booleans())
def test_icm42688p_packets_from_garbage(data: bytes, hires: bool) -> None:
    p = decode_packets(data, hires)
    size = 20 if hires else 16
    assert 0 <= p.n <= len(data) // size
    for a in (p.accel_invalid, p.gyro_invalid, p.temperature_invalid):
        assert a.shape == (p.n,)
    assert p.accel.shape == p.gyro.shape == (p.n, 3) and p.timestamp.shape == (p.n,)
    assert not p.clean or not (p.accel_invalid.any() or p.gyro_invalid.any())
    if p.n:
        assert p.part(0, p.n).n == p.n


@st.composite
def icm_packets(draw: st.DrawFn, hires: bool) -> tuple[bytes, np.ndarray, np.ndarray, list[int]]:
    """Valid packets: accel and gyro present, values above the invalid marker, a timestamp."""
    n = draw(st.integers(0, 40))
    lo, hi = (-(2**19) + 1, 2**19 - 1) if hires else (-32767, 32767)
    vals = draw(st.lists(st.integers(lo, hi), min_size=6 * n, max_size=6 * n))
    ts = draw(st.lists(st.integers(0, 0xFFFF), min_size=n, max_size=n))
    v = np.asarray(vals, dtype=np.int64).reshape(n, 6)
    rec = np.zeros(n, dtype=PACKET4 if hires else PACKET3)
    hdr = int(icm_r.Header.ACCEL | icm_r.Header.GYRO)
    rec["hdr"] = hdr | (int(icm_r.Header.HIRES_20) if hires else 0)
    if hires:
        rec["accel"], rec["gyro"] = v[:, :3] >> 4, v[:, 3:] >> 4
        rec["ext"] = ((v[:, :3] & 0xF) << 4) | (v[:, 3:] & 0xF)
        rec["temp"] = 100
    else:
        rec["accel"], rec["gyro"] = v[:, :3], v[:, 3:]
        rec["temp"] = 10
    rec["ts"] = ts
    return rec.tobytes(), v[:, :3], v[:, 3:], ts


@fuzz(20)
@given(st.data(), st.booleans())
def test_icm42688p_valid_packets_round_trip(data: st.DataObject, hires: bool) -> None:
    raw, accel, gyro, ts = data.draw(icm_packets(hires))
    p = decode_packets(raw, hires)
    assert p.n == len(ts)
    assert p.accel.tolist() == accel.tolist() and p.gyro.tolist() == gyro.tolist()
    assert p.timestamp.tolist() == ts
    assert not (p.accel_invalid.any() or p.gyro_invalid.any() or p.temperature_invalid.any())


@fuzz(40)
@given(
    st.lists(st.integers(0, 0xFFFF), max_size=200),
    st.floats(0.01, 1e6, allow_nan=False),
)
def test_icm42688p_timestamp_breaks_are_indices(ticks: list[int], per_sample: float) -> None:
    breaks = timestamp_breaks(np.asarray(ticks, dtype=np.int64), per_sample)
    assert breaks == sorted(set(breaks)) and all(0 < b < len(ticks) for b in breaks)


def icm_bus(register: int, length: int) -> st.SearchStrategy[bytes]:
    if length == 3:  # INT_STATUS, FIFO_COUNTH/L: counts a FIFO could hold, and garbage
        return st.one_of(
            exactly(3),
            st.builds(lambda s, c: bytes([s]) + c.to_bytes(2, "big"), st.integers(0, 255),
                      st.integers(0, 2100)),
        )  # fmt: skip
    return any_bytes(register, length)


@fuzz(25)
@given(st.data(), st.booleans())
def test_icm42688p_driver_survives_a_garbage_bus(data: st.DataObject, hires: bool) -> None:
    from imud.chips.icm42688p.driver import Icm42688pDriver

    fields = {"hires": True, "gyro_range_dps": 2000, "accel_range_g": 16} if hires else {}
    cfg = device_cfg("icm42688p", **fields)
    poll(Icm42688pDriver(cfg, GarbageRegisters(data, icm_bus), VirtualClock()), 4)


# --- BMI088 ----------------------------------------------------------------------------------

H = AccFifoHeader


@fuzz(80)
@given(st.binary(max_size=1100))
def test_bmi088_accel_fifo_from_garbage(data: bytes) -> None:
    f = bmi.decode_accel_fifo(data)
    n = f.accel.shape[0]
    assert f.accel.shape == (n, 3) and 7 * n <= len(data)
    assert f.corrupt_at is None or 0 <= f.corrupt_at < len(data)
    assert all(0 <= at <= n and 0 <= c <= 255 for at, c in f.skipped_before)
    assert f.sensortime is None or 0 <= f.sensortime < 1 << 24


@st.composite
def accel_frames(draw: st.DrawFn) -> tuple[bytes, list[list[int]], list[tuple[int, int]], int]:
    """A FIFO as the chip writes it: accel, skip, sensortime and config frames, then over-read
    bytes (0x80) to the end of the read."""
    out, accel, skips = bytearray(), [], []
    sensortime = None
    for _ in range(draw(st.integers(0, 30))):
        kind = draw(st.sampled_from(["accel"] * 4 + ["skip", "time", "config", "drop"]))
        if kind == "accel":
            xyz = draw(st.lists(st.integers(-32768, 32767), min_size=3, max_size=3))
            out += bytes([H.ACCEL | draw(st.integers(0, 3))]) + struct.pack("<3h", *xyz)
            accel.append(xyz)
        elif kind == "skip":
            c = draw(st.integers(0, 255))
            out += bytes([H.SKIP, c])
            skips.append((len(accel), c))
        elif kind == "time":
            sensortime = draw(st.integers(0, (1 << 24) - 1))
            out += bytes([H.SENSORTIME]) + sensortime.to_bytes(3, "little")
        else:
            header = H.INPUT_CONFIG if kind == "config" else H.SAMPLE_DROP
            out += bytes([header, draw(st.integers(0, 255))])
    out += b"\x80" * draw(st.integers(0, 8))
    return bytes(out), accel, skips, sensortime


@fuzz(40)
@given(accel_frames())
def test_bmi088_accel_fifo_round_trips(fifo: tuple[bytes, list[list[int]], Any, Any]) -> None:
    data, accel, skips, sensortime = fifo
    f = bmi.decode_accel_fifo(data)
    assert f.accel.tolist() == accel and f.skipped_before == skips
    assert f.sensortime == sensortime and f.corrupt_at is None


@fuzz(40)
@given(st.binary(max_size=620))
def test_bmi088_gyro_fifo_from_garbage(data: bytes) -> None:
    g = bmi.decode_gyro_fifo(data)
    assert g.shape == (len(data) // 6, 3)
    whole = len(data) // 6 * 6
    assert g.tolist() == np.frombuffer(data[:whole], "<i2").reshape(-1, 3).tolist()


@fuzz(40)
@given(st.integers(0, 255), st.integers(0, 255))
def test_bmi088_registers_decode_any_byte(a: int, b: int) -> None:
    t = bmi.temperature_c(a, b)
    assert np.isnan(t) or -105 <= t <= 151
    assert 0 <= bmi.fifo_length(a, b) < 1 << 14


def bmi_bus(register: int, length: int) -> st.SearchStrategy[bytes]:
    if length == 4:  # TEMP_MSB/LSB, FIFO_LENGTH_0/1: lengths a FIFO could hold, and garbage
        return st.one_of(
            exactly(4),
            st.builds(lambda t, n: t + n.to_bytes(2, "little"), exactly(2), st.integers(0, 1100)),
        )
    if length > 4:
        fifo = accel_frames().map(lambda f: (f[0] + bytes(length))[:length])
        return st.one_of(exactly(length), fifo)
    return any_bytes(register, length)


@fuzz(20)
@given(st.data())
def test_bmi088_driver_survives_a_garbage_bus(data: st.DataObject) -> None:
    from imud.chips.bmi088.driver import Bmi088Driver

    cfg = device_cfg("bmi088", odr_hz=400, accel_odr_hz=400)
    clock = VirtualClock()
    driver = Bmi088Driver(
        cfg, GarbageRegisters(data, bmi_bus), GarbageRegisters(data, bmi_bus), clock
    )
    poll(driver, 4, lambda: clock.advance(data.draw(st.integers(0, 50_000_000))))


# --- ADIS16465 -------------------------------------------------------------------------------


@fuzz(60)
@given(exactly(20))
def test_adis16465_burst_from_garbage(frame: bytes) -> None:
    try:
        b = adis.decode_burst(frame)
    except ValueError as e:
        assert "checksum" in str(e)
        assert adis.checksum(frame) != int.from_bytes(frame[18:20], "big")
        return
    assert b.checksum == sum(frame[:18]) & 0xFFFF


@fuzz(40)
@given(
    st.integers(0, 0xFFFF),
    st.lists(st.integers(-32768, 32767), min_size=7, max_size=7),
    st.integers(0, 0xFFFF),
    st.integers(0, 17),
    st.integers(1, 255),
)
def test_adis16465_burst_round_trips_and_a_flipped_byte_fails(
    diag: int, values: list[int], cntr: int, at: int, flip: int
) -> None:
    body = struct.pack(">H6hhH", diag, *values, cntr)
    frame = body + (sum(body) & 0xFFFF).to_bytes(2, "big")
    b = adis.decode_burst(frame)
    assert (b.diag_stat, [*b.gyro, *b.accel, b.temp], b.data_cntr) == (diag, values, cntr)
    bad = bytearray(frame)
    bad[at] ^= flip  # a single corrupted byte changes the sum by less than 256: always caught
    with pytest.raises(ValueError, match="checksum"):
        adis.decode_burst(bytes(bad))


class GarbageSpi:
    """spidev's xfer2: the answer has the length of the frame sent, its bytes hypothesis's."""

    def __init__(self, data: st.DataObject) -> None:
        self.data = data

    def xfer2(self, tx: list[int], speed_hz: int = 0) -> list[int]:
        n = len(tx)
        if n == 22:  # the burst: garbage, or a frame whose checksum holds
            frame = self.data.draw(
                st.one_of(
                    exactly(20),
                    exactly(18).map(lambda b: b + (sum(b) & 0xFFFF).to_bytes(2, "big")),
                )
            )
            return [0, 0, *frame]
        return list(self.data.draw(exactly(n)))

    def close(self) -> None:
        pass


@fuzz(25)
@given(st.data(), st.booleans())
def test_adis16465_driver_survives_garbage_answers(data: st.DataObject, deltas: bool) -> None:
    from imud.chips.adis16465.config import Adis16465Config
    from imud.chips.adis16465.driver import Adis16465Driver

    cfg = Adis16465Config.model_validate(
        {"chip": "adis16465", "name": "a", "model": 2, "deltas": deltas,
         "bus": {"kind": "spi", "path": "/dev/spidev0.0", "speed_hz": 2_000_000}}
    )  # fmt: skip
    driver = Adis16465Driver(cfg, GarbageSpi(data), VirtualClock())
    refused = 0
    for _ in range(4):
        try:
            check_batch(driver.read())
        except BusError as e:
            refused += "burst checksum" in str(e) or "burst read all ones" in str(e)
    # every frame dropped is counted, and only those
    assert driver.counters.chip["checksum_errors"] == refused


# --- STIM300 datagram framer -----------------------------------------------------------------


@st.composite
def datagram(draw: st.DrawFn, ident: DatagramId, terminated: bool) -> bytes:
    lay = layout(ident, terminated)
    body = bytes([ident]) + draw(exactly(lay.crc - 1))
    out = body + crc32(body).to_bytes(CRC_BYTES, "big")
    return out + (TERMINATION if terminated else b"")


@st.composite
def stim_stream(draw: st.DrawFn) -> tuple[DatagramId, bool, list[bytes], list[bytes]]:
    """(type, CR LF?, the valid datagrams in order, the stream as reads split it): datagrams
    with garbage, cut and damaged datagrams between them."""
    ident = draw(st.sampled_from(list(DatagramId)))
    term = draw(st.booleans())
    good: list[bytes] = []
    stream = bytearray()
    for _ in range(draw(st.integers(0, 12))):
        kind = draw(st.sampled_from(["good", "good", "good", "noise", "cut", "damaged"]))
        d = draw(datagram(ident, term))
        if kind == "good":
            good.append(d)
            stream += d
        elif kind == "noise":
            stream += draw(st.binary(max_size=60))
        elif kind == "cut":
            stream += d[: draw(st.integers(1, len(d) - 1))]
        else:
            bad = bytearray(d)
            at = draw(st.integers(0, layout(ident, term).crc + CRC_BYTES - 1))
            bad[at] ^= draw(st.integers(1, 255))
            stream += bad
    cuts = sorted(draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    parts = [bytes(stream[a:b]) for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]
    return ident, term, good, parts


@fuzz(50)
@given(stim_stream())
def test_stim300_framer_finds_every_valid_datagram_however_reads_split(
    s: tuple[DatagramId, bool, list[bytes], list[bytes]],
) -> None:
    ident, term, good, parts = s
    lay = layout(ident, term)
    framer = Framer(lay)
    rows = [r.tobytes() for p in parts for r in framer.feed(p)]
    # a damaged datagram's CRC fails, noise is skipped: every valid one is found, in order
    # (a CRC that holds by chance on garbage is a 2^-32 event)
    assert rows == good
    assert all(valid(lay, r) for r in rows)
    s_ = framer.stats
    total = sum(map(len, parts))
    assert s_.datagrams * lay.size + s_.skipped_bytes + framer.pending == total
    one = Framer(lay)  # the same stream in one read: the same datagrams and counts (bytes
    assert [r.tobytes() for r in one.feed(b"".join(parts))] == rows  # held or skipped: the same)
    o = one.stats
    assert (o.datagrams, o.crc_errors, o.resyncs) == (s_.datagrams, s_.crc_errors, s_.resyncs)
    assert o.skipped_bytes + one.pending == s_.skipped_bytes + framer.pending


@fuzz(50)
@given(
    st.sampled_from(list(DatagramId)), st.booleans(), st.lists(st.binary(max_size=80), max_size=10)
)
def test_stim300_framer_on_noise(ident: DatagramId, term: bool, reads: list[bytes]) -> None:
    lay = layout(ident, term)
    framer = Framer(lay)
    for r in reads:
        out = framer.feed(r)
        assert out.shape[1] == lay.size and all(valid(lay, x.tobytes()) for x in out)
    assert framer.pending < lay.size or framer._buf[:1] == bytes([ident])


class ChunkPort:
    """A serial port whose reads return the chunks given, then nothing."""

    port = "/dev/fuzz"
    baudrate = 1_843_200
    timeout = 0.0
    is_open = True

    def __init__(self, chunks: list[bytes]) -> None:
        self.chunks = list(chunks)

    @property
    def in_waiting(self) -> int:
        return len(self.chunks[0]) if self.chunks else 0

    def read(self, size: int = 1) -> bytes:
        return self.chunks.pop(0) if self.chunks else b""

    def write(self, data: bytes, /) -> int:
        return len(data)

    def reset_input_buffer(self) -> None:
        pass

    def open(self) -> None:
        pass

    def close(self) -> None:
        pass


@fuzz(25)
@given(st.data())
def test_stim300_driver_decodes_any_valid_datagram(data: st.DataObject) -> None:
    """Whatever the status, counter, latency and values in a datagram whose CRC holds, the
    driver's batches are consistent; garbage between them costs only what it covers."""
    from imud.chips.stim300.driver import Stim300Driver

    ident, term, good, parts = data.draw(stim_stream())
    cfg = device_cfg(
        "stim300",
        bus={"kind": "serial", "port": "/dev/ttyUSB0", "baud": 1_843_200},
        datagram=ident.name.lower(),
        line_termination=term,
    )
    driver = Stim300Driver(cfg, ChunkPort(parts), VirtualClock())
    got = sum(b.n for b in poll(driver, len(parts) + len(good) + 1))
    # a datagram with the start-up bit after one without it, its counter not the next one, is
    # a unit that restarted (docs/chips/stim300.md): the stream stops there until the runner
    # restarts the driver
    restart = restart_at(ident, good, driver.step)
    assert got == (restart if restart is not None else len(good))


def restart_at(ident: Any, good: list[bytes], step: int) -> int | None:
    """Index of the first datagram that says the unit restarted, from the bytes themselves:
    the gyro status byte's start-up bit (0x40) set after a datagram without it, and its 8-bit
    counter not the step after the previous one's (TS1524 section 9.3 layout)."""
    from imud.chips.stim300.datagram import layout

    lay = layout(ident)
    streamed, prev = False, None
    for i, raw in enumerate(good):
        startup = bool(raw[lay.gyro_status] & 0x40)
        counter = raw[lay.counter]
        if streamed and startup and prev is not None and (counter - prev) % 256 != step:
            return i
        streamed = streamed or not startup
        prev = counter
    return None


# --- BNO055 UART protocol --------------------------------------------------------------------


class GarbagePort:
    """A UART whose answer to each request is bytes hypothesis chooses: noise, a well-formed
    read answer (BB len data), a status answer (EE code), or nothing."""

    port = "/dev/fuzz"
    baudrate = 115_200
    is_open = True

    def __init__(self, data: st.DataObject, clock: VirtualClock) -> None:
        self.data, self.clock = data, clock
        self.timeout: float | None = 0.0
        self.inbox = bytearray()
        self.asked = False

    @property
    def in_waiting(self) -> int:
        return len(self.inbox)

    def write(self, data: bytes, /) -> int:
        self.asked = True
        return len(data)

    def read(self, size: int = 1) -> bytes:
        if self.asked:
            self.asked = False
            self.inbox += self.data.draw(
                st.one_of(
                    st.binary(max_size=140),
                    st.builds(lambda d: bytes([0xBB, len(d)]) + d, st.binary(max_size=128)),
                    st.builds(lambda c: bytes([0xEE, c]), st.integers(0, 255)),
                )
            )
        got = bytes(self.inbox[:size])
        del self.inbox[:size]
        self.clock.advance(int((self.timeout or 0) * 1e9) if len(got) < size else 1000)
        return got

    def reset_input_buffer(self) -> None:
        self.inbox.clear()

    def open(self) -> None:
        pass

    def close(self) -> None:
        pass


@fuzz(40)
@given(st.data(), st.integers(0, 0x7F), st.integers(1, 128), st.booleans())
def test_bno055_uart_answers_data_or_a_uart_error(
    data: st.DataObject, register: int, length: int, write: bool
) -> None:
    from imud.chips.api import DriverCounters
    from imud.chips.bno055.uart import Bno055Uart, UartError

    clock = VirtualClock()
    uart = Bno055Uart(GarbagePort(data, clock), clock, DriverCounters(), tries=3)
    try:
        if write:
            uart.write(register, bytes(length))
        else:
            got = uart.read(register, length)
            assert len(got) == length
    except UartError as e:
        assert f"0x{register:02x}" in str(e)
    s = uart.stats
    assert 1 <= s.requests <= 3 and s.retries == s.requests - 1


def bno_bus(register: int, length: int) -> st.SearchStrategy[bytes]:
    if length == 46:  # the data burst, sometimes short (a UART answer cut off)
        return st.one_of(exactly(46), st.binary(max_size=46))
    return any_bytes(register, length)


@fuzz(25)
@given(st.data(), st.sampled_from(["ndof", "imu", "amg"]))
def test_bno055_driver_survives_garbage_bursts(data: st.DataObject, mode: str) -> None:
    from imud.chips.bno055.driver import Bno055Driver

    cfg = device_cfg("bno055", mode=mode, save_offsets=False, bus={"kind": "sim", "address": 0x28})
    clock = VirtualClock()
    driver = Bno055Driver(cfg, GarbageRegisters(data, bno_bus), clock)
    poll(driver, 4, lambda: clock.advance(data.draw(st.integers(0, 300_000_000))))


# --- the wire format -------------------------------------------------------------------------


@fuzz(80)
@given(st.binary(max_size=400))
def test_wire_decode_of_garbage_is_a_batch_or_a_wire_error(buf: bytes) -> None:
    from imud import client

    try:
        b = client.decode(buf)
    except wire.WireError:
        return
    assert b.t_ns.shape == b.sample_flags.shape == (b.count,)


@st.composite
def batches(draw: st.DrawFn) -> dict[str, Any]:
    n = draw(st.integers(0, 20))
    chans = draw(st.lists(st.sampled_from([c for c, _, _ in ORDER]), unique=True, max_size=6))
    width = {c: w for c, _, w in ORDER}
    f32 = st.floats(width=32, allow_nan=True, allow_infinity=True)
    return {
        "device": draw(st.text(max_size=20)),
        "first_seq": draw(st.integers(0, 2**64 - 1)),
        "t_ns": draw(st.lists(st.integers(-(2**63), 2**63 - 1), min_size=n, max_size=n)),
        "channels": {
            c: draw(st.lists(f32, min_size=n * width[c], max_size=n * width[c])) for c in chans
        },
        "sample_flags": draw(st.lists(st.integers(0, 2**32 - 1), min_size=n, max_size=n)),
        "kind": draw(st.integers(0, 255)),
        "flags": draw(st.integers(0, 2**32 - 1)),
        "lost_before": draw(st.integers(0, 2**32 - 1)),
    }


@fuzz(25)
@given(batches())
def test_wire_round_trips(b: dict[str, Any]) -> None:
    buf = wire.encode(
        b["device"], b["first_seq"], np.asarray(b["t_ns"], dtype=np.int64),
        {c: np.asarray(v, dtype=np.float32) for c, v in b["channels"].items()},
        np.asarray(b["sample_flags"], dtype=np.uint32),
        kind=b["kind"], flags=b["flags"], lost_before=b["lost_before"],
    )  # fmt: skip
    got = wire.decode(buf)
    assert (got.device, got.kind, got.first_seq, got.flags, got.lost_before) == (
        b["device"], b["kind"], b["first_seq"], b["flags"], b["lost_before"],
    )  # fmt: skip
    assert got.t_ns.tolist() == b["t_ns"] and got.sample_flags.tolist() == b["sample_flags"]
    assert set(got.channels) == set(b["channels"])
    for c, v in b["channels"].items():
        want = np.asarray(v, dtype=np.float32)
        assert np.array_equal(got.channels[c].ravel().view(np.uint32), want.view(np.uint32))


@fuzz(60)
@given(batches(), st.data())
def test_wire_damaged_batch_is_a_batch_or_a_wire_error(
    b: dict[str, Any], data: st.DataObject
) -> None:
    buf = bytearray(wire.encode(
        b["device"], b["first_seq"], np.asarray(b["t_ns"], dtype=np.int64),
        {c: np.asarray(v, dtype=np.float32) for c, v in b["channels"].items()},
    ))  # fmt: skip
    how = data.draw(st.sampled_from(["flip", "cut", "grow", "header"]))
    if how == "flip":
        at = data.draw(st.integers(0, len(buf) - 1))
        buf[at] ^= data.draw(st.integers(1, 255))
    elif how == "cut":
        del buf[data.draw(st.integers(0, len(buf) - 1)) :]
    elif how == "grow":
        buf += data.draw(st.binary(min_size=1, max_size=40))
    else:  # any header field, the rest as it was
        fields = list(wire.HEADER.unpack_from(buf))
        i = data.draw(st.integers(1, 8))
        fields[i] = data.draw(st.integers(0, [0, 255, 255, 0xFFFF, 2**64 - 1, *[2**32 - 1] * 4][i]))
        buf[: wire.HEADER.size] = wire.HEADER.pack(*fields)
    try:
        got = wire.decode(bytes(buf))
    except wire.WireError as e:
        assert "byte" in str(e) or "bytes" in str(e)
        return
    assert got.t_ns.shape == (got.count,)
    assert Channel(got.mask) == got.mask
