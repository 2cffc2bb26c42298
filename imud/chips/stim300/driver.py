"""STIM300 normal-mode stream driver (docs/chips/stim300.md).

The unit streams one datagram per sample: the driver reads whatever bytes have arrived, finds the
datagrams in them by identifier and CRC (`datagram.Framer`), and hands the pipeline counts with
host-time brackets moved back to the sample instant by the datagram's own latency field and its
time on the wire. The 8-bit sample counter (it counts the unit's 2000 Hz samples) makes a gap
countable exactly: a batch never spans one, so the pipeline sees each gap with the counter.
"""

from __future__ import annotations

import contextlib
import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from imud.buses.serial import SerialPort
from imud.channels import Channel
from imud.chips.api import ChipCounter, DriverCounters, FifoRead, RawBatch, RawChannel
from imud.chips.stim300.config import BITS_PER_CHAR, Stim300Config
from imud.chips.stim300.datagram import Framer, find_any, int16, int24, layout, uint16
from imud.chips.stim300.registers import (
    ACCEL_LSB_G,
    COUNTER_MODULO,
    FIRST_DATAGRAM_MAX_NS,
    GYRO_LSB_DPS,
    GYRO_SATURATION_DPS,
    INCL_LSB_G,
    INCL_RANGE_G,
    TEMP_LSB_C,
    DatagramId,
    Status,
)
from imud.clock import Clock
from imud.errors import BusError, DeviceIdentityError, RegisterMismatch
from imud.units import STANDARD_GRAVITY

HOST_BUFFER_BYTES = 4096  # Linux's tty receive buffer: what a stalled reader can lose beyond
POLL_NS = 5_000_000
START_TIMEOUT_NS = FIRST_DATAGRAM_MAX_NS + 1_200_000_000  # first datagram, with margin
START_STEP_NS = 20_000_000
READ_MAX = 1 << 16
# how far the unit's sample clock may run fast (the rev.31 datasheet states no accuracy for it;
# the sample clock's fit rejects a period off by more): a batch that is not the newest is placed
# at least this many of the fastest periods before the datagrams that came after it
CLOCK_TOLERANCE = 0.1
# the sample's data are not valid: its cluster's values become NaN (the rest is an alarm only)
_INVALID = int(Status.STARTUP | Status.SYSTEM_INTEGRITY | Status.CHANNEL_ERROR)
_STARTUP = int(Status.STARTUP)
_BITS = [(b.name or str(int(b)), int(b)) for b in Status]


@dataclass(slots=True)
class Segment:
    """Datagrams with consecutive counters; `gap_before`: the counter jumped before the first."""

    rows: npt.NDArray[np.uint8]
    gap_before: bool


# The gyro's group delay per filter -3 dB frequency (TS1524 rev.31, Table 5-3; docs/chips/
# stim300.md). The simulator keeps its own copy: it models the unit, not this driver.
GYRO_GROUP_DELAY_S = {262: 2.2e-3, 131: 3.7e-3, 66: 6.7e-3, 33: 12.7e-3, 16: 24.7e-3}


class Stim300Driver:
    def __init__(self, cfg: Stim300Config, port: SerialPort, clock: Clock) -> None:
        self.cfg = cfg
        self.port = port
        self.clock = clock
        self.lay = layout(cfg.datagram_id, cfg.line_termination)
        self.framer = Framer(self.lay)
        self.nominal_period_ns = 1e9 / cfg.odr_hz
        # the gyro's group delay at the unit's filter (docs/timestamps.md): stamps move back by it
        self.group_delay_ns = round(GYRO_GROUP_DELAY_S[cfg.filter_hz] * 1e9)
        self.fifo_capacity = HOST_BUFFER_BYTES // self.lay.size
        span = self.fifo_capacity * self.nominal_period_ns
        self.poll_interval_ns = int(min(POLL_NS, span / 4))
        self.next_poll_ns: int | None = None  # a FIFO: polled at its interval
        self.counters = DriverCounters(chip={"crc_errors": 0})
        self.step = cfg.counter_step
        baud = port.baudrate
        self.wire_ns = self.lay.size * BITS_PER_CHAR * 1e9 / baud  # a datagram on the line
        self._held: list[Segment] = []
        self._last_counter: int | None = None
        self._newest_latency_ns = 0  # the latency field of the newest datagram taken in
        self._latency_max_ns = 0  # the largest latency field seen: bounds the next datagram's
        self.status_counts = dict.fromkeys((name for name, _ in _BITS), 0)
        self.status_seen = 0
        self.counter_gaps = 0
        self.latency_max_us = 0
        self.bytes_read = 0
        self._streamed = False  # a datagram past start-up came since the start
        self._reset_seen = False  # then one with the start-up bit again: the unit restarted

    # --- start ------------------------------------------------------------------------------
    def start(self) -> Iterator[int]:
        """Nothing to configure: wait for the stream, check it is what the config says."""
        if not self.port.is_open:  # closed after a failed read: the adapter may be back
            try:
                self.port.open()
            except Exception as e:
                raise BusError(0, f"cannot reopen {self.port.port}: {e}") from e
        try:
            self.port.reset_input_buffer()
        except Exception as e:
            self._close()
            raise BusError(0, f"{self.port.port}: {e}") from e
        self.framer = Framer(self.lay, self.framer.stats)  # counts run on over restarts
        self._held, self._last_counter = [], None
        self._streamed = self._reset_seen = False
        seen = b""
        t_end = self.clock.now_ns() + START_TIMEOUT_NS
        rows = np.zeros((0, self.lay.size), dtype=np.uint8)
        while True:
            data = self._read_port()
            seen = (seen + data)[-4 * HOST_BUFFER_BYTES :]
            rows = np.concatenate([rows, self.framer.feed(data)])
            if len(rows) >= 2 or self.clock.now_ns() > t_end:
                break
            yield START_STEP_NS
        if len(rows) == 0:
            raise DeviceIdentityError(self._no_stream(seen))
        c = rows[:, self.lay.counter].astype(np.int64)
        step = int(c[1] - c[0]) % COUNTER_MODULO if len(c) >= 2 else self.step
        if step != self.step:
            rate = 2000 / step if step else math.inf
            raise DeviceIdentityError(
                f"the STIM300's sample counter steps by {step} per datagram, i.e. it samples at "
                f"{rate:g} Hz; the config says odr_hz = {self.cfg.odr_hz:g} (counter step "
                f"{self.step}): set odr_hz = {rate:g}"
            )
        self._take(rows)  # published with the first read: nothing received is dropped

    def _no_stream(self, seen: bytes) -> str:
        where = f"{self.port.port} at {self.port.baudrate} baud"
        want = f"0x{self.lay.ident:02X} ({self.cfg.datagram})"
        if not seen:
            return (
                f"no bytes from the STIM300 on {where} in {START_TIMEOUT_NS / 1e9:g} s: check its "
                "power, the RS422 wiring (TX+/TX- to the adapter's RX+/RX-) and the port"
            )
        other = find_any(seen, self.cfg.line_termination)
        if other is not None:
            name = DatagramId(other).name.lower()
            return (
                f"the STIM300 on {where} sends 0x{other:02X} ({name}) datagrams, the config "
                f'says {want}: set datagram = "{name}"'
            )
        if find_any(seen, not self.cfg.line_termination) is not None:
            return (
                f"the STIM300 on {where} sends datagrams "
                f"{'without' if self.cfg.line_termination else 'with'} CR LF: set "
                f"line_termination = {str(not self.cfg.line_termination).lower()}"
            )
        return (
            f"{len(seen)} bytes arrived on {where} but no valid STIM300 datagram: check bus.baud "
            f"(the unit's bit rate) and that the unit is in normal mode; first bytes: "
            f"{seen[:16].hex(' ')}"
        )

    # --- read -------------------------------------------------------------------------------
    def _read_port(self) -> bytes:
        """What has arrived, read at its size: pyserial allocates the whole size asked for and
        shrinks it after, and 64 KiB a read left the bus process's heap growing (+10.6 MB in a
        30-minute soak, docs/reliability.md); asked only what is waiting, it stays flat."""
        try:
            data = self.port.read(max(1, min(READ_MAX, self.port.in_waiting)))
        except OSError as e:  # pyserial's SerialException is one: the device is gone
            self._close()  # the next start reopens it
            raise BusError(e.errno or 0, f"read {self.port.port}: {e}") from e
        self.bytes_read += len(data)
        return bytes(data)

    def _take(self, rows: npt.NDArray[np.uint8]) -> None:
        """Split new datagrams where the counter jumps; queue them."""
        if not len(rows) or self._reset_seen:
            return  # nothing, or what a unit that restarted sends before it is started again
        c = rows[:, self.lay.counter].astype(np.int64)
        startup = (rows[:, self.lay.gyro_status] & _STARTUP) != 0
        # valid data came before each datagram (in an earlier read, or earlier in this one)
        streamed = self._streamed | (np.cumsum(~startup) - ~startup > 0)
        if bool((startup & streamed).any()):
            # the start-up bit after valid data, with the counter jumping: the unit reset itself
            # (a power glitch) and counts from 0 again. Keep what came before, restart the stream
            prev = np.concatenate([[c[0] - self.step if self._last_counter is None
                                    else self._last_counter], c[:-1]])  # fmt: skip
            jumped = startup & streamed & ((c - prev) % COUNTER_MODULO != self.step)
            if bool(jumped.any()):
                self._reset_seen = True
                k = int(np.argmax(jumped))
                rows, startup, c = rows[:k], startup[:k], c[:k]
                if not len(rows):
                    return
        self._streamed = self._streamed or not bool(startup.all())
        lat = uint16(rows, self.lay.latency)
        self._newest_latency_ns = int(lat[-1]) * 1000
        self._latency_max_ns = max(self._latency_max_ns, int(lat.max()) * 1000)
        self.latency_max_us = self._latency_max_ns // 1000
        prev = np.empty_like(c)
        prev[1:] = c[:-1]
        prev[0] = c[0] - self.step if self._last_counter is None else self._last_counter
        jump = np.flatnonzero((c - prev) % COUNTER_MODULO != self.step)
        self._last_counter = int(c[-1])
        self.counter_gaps += len(jump)
        cuts = [0, *[int(j) for j in jump if j > 0], len(rows)]
        for i, (a, b) in enumerate(itertools.pairwise(cuts)):
            gap = bool(i > 0 or (len(jump) and jump[0] == 0))
            self._held.append(Segment(rows[a:b], gap))

    def read(self) -> RawBatch:
        if self._reset_seen and not self._held:
            raise RegisterMismatch(
                0,
                "the STIM300 sends its start-up status bit again after valid data: it reset "
                "itself (power glitch?); restart the stream",
            )
        t0 = self.clock.now_ns()
        data = self._read_port()
        t1 = self.clock.now_ns()
        self._take(self.framer.feed(data))
        self.counters.bad_transfers = self.counters.chip["crc_errors"] = (
            self.framer.stats.crc_errors
        )
        # A datagram's sample came its latency field and its time on the wire before its last
        # byte, which was here by t1: the newest sample was latched no later than t1 less the
        # newest datagram's latency and wire time. The next one, not here by t0, was latched
        # after t0 less its own latency, unknown yet: the largest seen stands in for it, so the
        # bracket is a hard bound whatever the next latency (not if the host delivers bytes
        # late: a USB adapter's latency timer, which no datagram field shows). Unless a damaged
        # datagram may have come after the newest valid one by t0 (the framer holds what cannot
        # be a clean beginning): then the next sample was latched and its datagram lost, and
        # t_before bounds nothing (the read has no phase, as a full FIFO's)
        wire = round(self.wire_ns)
        t_before = t0 - wire - self._latency_max_ns
        t_after = t1 - wire - self._newest_latency_ns
        phase = not self.framer.damaged_tail
        if not self._held:
            empty = np.zeros((0, self.lay.size), np.uint8)
            return self._batch(empty, t_before, t_after, False, phase=phase)
        seg = self._held.pop(0)
        # merge queued segments that continue this one (a batch may not span a counter gap)
        while self._held and not self._held[0].gap_before:
            seg = Segment(np.concatenate([seg.rows, self._held.pop(0).rows]), seg.gap_before)
        # later samples wait behind a gap: this batch is not the newest. Each datagram after it
        # is a later sample, a period or more after the one before: its newest sample came at
        # least that many (fastest) periods before the newest datagram's, which keeps its upper
        # bound within a few samples of it however late the read (the count of a gap before it
        # needs the host to place it to within half a counter wrap, 64 ms)
        following = sum(len(s.rows) for s in self._held)
        shift = math.ceil(following * self.nominal_period_ns * (1.0 - CLOCK_TOLERANCE))
        return self._batch(seg.rows, t_before - shift, t_after - shift, seg.gap_before,
                           phase=phase and not following)  # fmt: skip

    def _batch(
        self,
        rows: npt.NDArray[np.uint8],
        t_before: int,
        t_after: int,
        gap: bool,
        phase: bool = True,
    ) -> RawBatch:
        lay, n = self.lay, len(rows)
        counter = ChipCounter(rows[:, lay.counter].astype(np.int64), COUNTER_MODULO)
        timing = FifoRead(int(t_before), int(t_after), resync=gap, fifo_full=not phase,
                          counter=counter)  # fmt: skip
        gyro_status = rows[:, lay.gyro_status].astype(np.int64)
        statuses = [gyro_status]
        deg = math.pi / 180.0
        channels = {
            Channel.GYRO: RawChannel(
                int24(rows, lay.gyro),
                GYRO_LSB_DPS * deg,
                GYRO_SATURATION_DPS / GYRO_LSB_DPS,
                _invalid(gyro_status),
            )
        }
        if lay.acc is not None and lay.acc_status is not None:
            lsb = ACCEL_LSB_G[self.cfg.accel_range_g]
            st = rows[:, lay.acc_status].astype(np.int64)
            statuses.append(st)
            channels[Channel.ACCEL] = RawChannel(
                int24(rows, lay.acc), lsb * STANDARD_GRAVITY,
                self.cfg.accel_range_g / lsb, _invalid(st),
            )  # fmt: skip
        if lay.incl is not None and lay.incl_status is not None:
            st = rows[:, lay.incl_status].astype(np.int64)
            statuses.append(st)
            channels[Channel.INCLINATION] = RawChannel(
                int24(rows, lay.incl), INCL_LSB_G * STANDARD_GRAVITY,
                INCL_RANGE_G / INCL_LSB_G, _invalid(st),
            )  # fmt: skip
        if lay.temps:
            # the gyro cluster's three sensors, averaged: the chip temperature of wire format v2
            t = int16(rows, lay.temps[0]).mean(axis=1)
            for at in lay.temps:
                statuses.append(rows[:, at + 6].astype(np.int64))
            st = rows[:, lay.temps[0] + 6].astype(np.int64)
            channels[Channel.TEMPERATURE] = RawChannel(t, TEMP_LSB_C, None, _invalid(st))
        status = np.bitwise_or.reduce(np.stack(statuses), axis=0) if n else gyro_status
        alarm = status != 0
        if n and bool(alarm.any()):
            self._count_status(status)
        return RawBatch(n, channels, timing, alarm if bool(alarm.any()) else None)

    def _count_status(self, status: npt.NDArray[np.int64]) -> None:
        for name, bit in _BITS:
            self.status_counts[name] += int(np.count_nonzero(status & bit))
        self.status_seen |= int(np.bitwise_or.reduce(status))

    def _close(self) -> None:
        with contextlib.suppress(Exception):  # best effort: the port may be gone already
            self.port.close()

    def stop(self) -> None:
        self._close()

    def chip_status(self) -> dict[str, Any]:
        s = self.framer.stats
        return {
            "datagram": f"0x{self.lay.ident:02X} {self.cfg.datagram}",
            "datagrams": s.datagrams,
            "resyncs": s.resyncs,
            "skipped_bytes": s.skipped_bytes,
            "counter_gaps": self.counter_gaps,
            "status_bits": [name for name, bit in _BITS if self.status_seen & bit],
            "status_counts": {k: v for k, v in self.status_counts.items() if v},
            "latency_max_us": self.latency_max_us,
        }


def _invalid(status: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_] | None:
    bad = (status & _INVALID) != 0
    return bad if bool(bad.any()) else None
