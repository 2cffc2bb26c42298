"""ICM-42688-P FIFO packet driver (docs/chips/icm42688p.md).

The FIFO runs in stop-on-full mode, so a full FIFO keeps whole, valid packets: imud reads them,
and counts the samples the chip dropped meanwhile. Each packet's 16-bit timestamp counts on the
chip's own clock, which makes the samples in a gap countable exactly. A sensor the chip marks
invalid in a packet (its three axes at the invalid value) becomes NaN with a flag, while the
packet's other sensors are still published.
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

from imud.buses.registers import RegisterDevice
from imud.channels import Channel
from imud.chips.api import ChipCounter, DriverCounters, RawBatch, RawChannel
from imud.chips.bits import BitField
from imud.chips.fifotiming import FifoTiming, fifo_poll_interval_ns
from imud.chips.icm42688p import registers as R
from imud.chips.icm42688p.config import Icm42688pConfig
from imud.chips.regplan import RegisterChecker, RegisterPlan, RegisterSetting
from imud.clock import Clock
from imud.compiled import load
from imud.errors import BusError, DeviceIdentityError
from imud.units import STANDARD_GRAVITY

_WHOLE = BitField(0xFF)
_HDR_EMPTY = int(R.Header.MSG)
_HDR_ACCEL = int(R.Header.ACCEL)
_HDR_GYRO = int(R.Header.GYRO)
_HDR_20 = int(R.Header.HIRES_20)
_FIFO_FULL = int(R.IntStatus.FIFO_FULL_INT)
_and, _min = np.bitwise_and.reduce, np.minimum.reduce
_fifo = load("imud.chips.icm42688p._fifo")  # decode_fifo's one-call kernel, when built


def gyro_scale_rads(range_dps: float, hires: bool) -> float:
    return math.radians(range_dps) / (2**19 if hires else 2**15)


def accel_scale_ms2(range_g: float, hires: bool) -> float:
    return range_g * STANDARD_GRAVITY / (2**19 if hires else 2**15)


@dataclass(slots=True)
class Packets:
    """Decoded FIFO packets (counts), in FIFO order, up to the first 'FIFO empty' header."""

    accel: npt.NDArray[np.int32]
    gyro: npt.NDArray[np.int32]
    temperature_c: npt.NDArray[np.float64]
    timestamp: npt.NDArray[np.int64]  # 16-bit FIFO timestamp field
    accel_invalid: npt.NDArray[np.bool_]  # absent from the packet, or the invalid marker
    gyro_invalid: npt.NDArray[np.bool_]
    temperature_invalid: npt.NDArray[np.bool_]
    clean: bool = False  # known to have no invalid value (the masks are all False)

    @property
    def n(self) -> int:
        return int(self.accel.shape[0])

    def part(self, a: int, b: int) -> Packets:
        return Packets(
            self.accel[a:b],
            self.gyro[a:b],
            self.temperature_c[a:b],
            self.timestamp[a:b],
            self.accel_invalid[a:b],
            self.gyro_invalid[a:b],
            self.temperature_invalid[a:b],
            self.clean,
        )


def timestamp_breaks(ticks: npt.NDArray[np.int64], ticks_per_sample: float) -> list[int]:
    """Where consecutive FIFO packets are not consecutive samples: the chip dropped samples
    while its FIFO was full, and resumed when a read made room, all between two of our reads.
    The packets after the break start a new run (indices into the batch)."""
    if ticks.size < 2 or 2.5 * ticks_per_sample >= R.TIMESTAMP_MODULO:
        return []  # a sample apart is most of a wrap: the counter cannot show a missing one
    steps = np.diff(ticks) % R.TIMESTAMP_MODULO
    return [int(i) + 1 for i in np.flatnonzero(steps > 1.5 * ticks_per_sample)]


# One FIFO packet as a NumPy record: decoding a batch is one zero-copy view, not a loop
PACKET3 = np.dtype([("hdr", "u1"), ("accel", ">i2", 3), ("gyro", ">i2", 3), ("temp", "i1"),
                    ("ts", ">u2")])  # fmt: skip
PACKET4 = np.dtype([("hdr", "u1"), ("accel", ">i2", 3), ("gyro", ">i2", 3), ("temp", ">i2"),
                    ("ts", ">u2"), ("ext", "u1", 3)])  # fmt: skip
assert PACKET3.itemsize == R.PACKET3_BYTES and PACKET4.itemsize == R.PACKET4_BYTES


def decode_packets(data: bytes, hires: bool) -> Packets:
    """FIFO bytes (big-endian packets 3 or 4) to counts, up to the first 'FIFO empty' header."""
    dt = PACKET4 if hires else PACKET3
    rec = np.frombuffer(data, dtype=dt, count=len(data) // dt.itemsize)
    empty = np.flatnonzero(rec["hdr"] & _HDR_EMPTY)
    if empty.size:
        rec = rec[: empty[0]]
    hdr = rec["hdr"]
    accel = rec["accel"].astype(np.int32)
    gyro = rec["gyro"].astype(np.int32)
    if hires:
        ext = rec["ext"].astype(np.int32)
        accel = (accel << 4) | (ext >> 4)
        gyro = (gyro << 4) | (ext & 0x0F)
        marker = R.INVALID_20
        temp = rec["temp"] / 132.48 + 25.0
        temp_bad = rec["temp"] == R.INVALID_16
        no_20 = (hdr & _HDR_20) == 0  # no new valid 20-bit data in this packet
    else:
        marker = R.INVALID_16
        temp = rec["temp"] / 2.07 + 25.0
        temp_bad = rec["temp"] == R.INVALID_TEMP_8
        no_20 = np.zeros(hdr.shape, dtype=bool)
    ts = rec["ts"].astype(np.int64)
    n = hdr.shape[0]
    need = _HDR_ACCEL | _HDR_GYRO | (_HDR_20 if hires else 0)
    clean = (  # the usual batch: four reductions say every value is valid
        n
        and _and(hdr) & need == need
        and _min(accel, None) > marker
        and _min(gyro, None) > marker
        and not temp_bad.any()
    )
    if clean:
        none = np.zeros(n, dtype=bool)
        return Packets(accel, gyro, temp, ts, none, none, none, clean=True)
    accel_bad = ((hdr & _HDR_ACCEL) == 0) | (accel == marker).all(axis=1) | no_20
    gyro_bad = ((hdr & _HDR_GYRO) == 0) | (gyro == marker).all(axis=1) | no_20
    return Packets(accel, gyro, temp, ts, accel_bad, gyro_bad, temp_bad)


def decode_fifo(data: bytes, hires: bool, ticks_per_sample: float) -> tuple[Packets, list[int]]:
    """`decode_packets` and the `timestamp_breaks` of what it decoded: in one call of the
    compiled kernel when it was built (the same results), else those two."""
    if _fifo is None:
        p = decode_packets(data, hires)
        return p, timestamp_breaks(p.timestamp, ticks_per_sample)
    cap = len(data) // (R.PACKET4_BYTES if hires else R.PACKET3_BYTES)
    accel = np.empty((cap, 3), dtype=np.int32)
    gyro = np.empty((cap, 3), dtype=np.int32)
    temp = np.empty(cap, dtype=np.float64)
    ts = np.empty(cap, dtype=np.int64)
    bad = np.empty((3, cap), dtype=bool)
    # timestamp_breaks' rule: more than 1.5 samples' ticks, unless a sample is most of a wrap
    over = 1.5 * ticks_per_sample if 2.5 * ticks_per_sample < R.TIMESTAMP_MODULO else 0.0
    n, clean, breaks = _fifo.decode(data, hires, over, accel, gyro, temp, ts, bad)
    if n < cap:  # a 'FIFO empty' header: what came before it
        accel, gyro, temp, ts, bad = accel[:n], gyro[:n], temp[:n], ts[:n], bad[:, :n]
    # (clean: the masks are all False)
    return Packets(accel, gyro, temp, ts, bad[0], bad[1], bad[2], clean=clean), breaks


BANK_TRIES = 3  # writes of REG_BANK_SEL, each read back, before a bank select fails
_BANK_SEL = 0x07  # REG_BANK_SEL [2:0]: the bank, 0..4 (docs/chips/icm42688p.md)


def register_plan(c: Icm42688pConfig) -> list[RegisterSetting]:
    """Every configured register of banks 0, 1 and 2, the power-on (PWR_MGMT0) last."""
    fs = RegisterSetting.fields
    B0, B1, B2 = R.Bank0, R.Bank1, R.Bank2
    odr = R.ODR_CODES[float(c.odr_hz)]
    ui = R.UI_FILTER_CODES[c.ui_filter]
    C1 = R.FifoConfig1
    fifo1 = C1.ACCEL_EN | C1.GYRO_EN | C1.TEMP_EN
    hires = C1.HIRES_EN if c.hires else 0
    T = R.TmstConfig
    plan = [
        RegisterSetting(
            B0.INTF_CONFIG0,
            set_bits=R.IntfConfig0.FIFO_COUNT_ENDIAN | R.IntfConfig0.SENSOR_DATA_ENDIAN,
            clear_bits=R.IntfConfig0.FIFO_COUNT_REC | R.IntfConfig0.FIFO_HOLD_LAST_DATA_EN,
        ),
        fs(B0.INTF_CONFIG1, (R.INTF_CONFIG1_AFSR, R.AFSR_OFF)),
        fs(B0.FIFO_CONFIG, (R.FIFO_MODE, R.FIFO_MODE_STOP_ON_FULL)),
        RegisterSetting(
            B0.FIFO_CONFIG1,
            set_bits=fifo1 | hires,
            clear_bits=C1.TMST_FSYNC_EN | (0 if c.hires else C1.HIRES_EN),
        ),
        RegisterSetting(
            B0.TMST_CONFIG,
            set_bits=T.TMST_EN,
            clear_bits=T.TMST_RES | T.TMST_DELTA_EN | T.TMST_FSYNC_EN,
        ),
        fs(
            B0.GYRO_CONFIG0,
            (R.GYRO_FS_SEL, R.GYRO_RANGES_DPS.index(float(c.gyro_range_dps))),
            (R.GYRO_ODR, odr),
        ),
        fs(
            B0.ACCEL_CONFIG0,
            (R.ACCEL_FS_SEL, R.ACCEL_RANGES_G.index(c.accel_range_g)),
            (R.ACCEL_ODR, odr),
        ),
        fs(B0.GYRO_ACCEL_CONFIG0, (R.ACCEL_UI_FILT_BW, ui), (R.GYRO_UI_FILT_BW, ui)),
    ]
    g, a = c.gyro_aaf_hz, c.accel_aaf_hz
    if g == "off":
        plan.append(
            RegisterSetting(
                B1.GYRO_CONFIG_STATIC2, set_bits=R.GyroConfigStatic2.GYRO_AAF_DIS, bank=1
            )
        )
    else:
        d, sq, sh = R.AAF_TABLE[int(g)]
        plan += [
            RegisterSetting(
                B1.GYRO_CONFIG_STATIC2, clear_bits=R.GyroConfigStatic2.GYRO_AAF_DIS, bank=1
            ),
            fs(B1.GYRO_CONFIG_STATIC3, (R.GYRO_AAF_DELT, d), bank=1),
            fs(B1.GYRO_CONFIG_STATIC4, (R.GYRO_AAF_DELTSQR_LO, sq & 0xFF), bank=1),
            fs(
                B1.GYRO_CONFIG_STATIC5,
                (R.GYRO_AAF_BITSHIFT, sh),
                (R.GYRO_AAF_DELTSQR_HI, sq >> 8),
                bank=1,
            ),
        ]
    if a == "off":
        plan.append(RegisterSetting(B2.ACCEL_CONFIG_STATIC2, set_bits=R.ACCEL_AAF_DIS, bank=2))
    else:
        d, sq, sh = R.AAF_TABLE[int(a)]
        plan += [
            fs(B2.ACCEL_CONFIG_STATIC2, (R.ACCEL_AAF_DELT, d), clear_bits=R.ACCEL_AAF_DIS, bank=2),
            fs(B2.ACCEL_CONFIG_STATIC3, (R.ACCEL_AAF_DELTSQR_LO, sq & 0xFF), bank=2),
            fs(
                B2.ACCEL_CONFIG_STATIC4,
                (R.ACCEL_AAF_BITSHIFT, sh),
                (R.ACCEL_AAF_DELTSQR_HI, sq >> 8),
                bank=2,
            ),
        ]
    plan.append(
        fs(
            B0.PWR_MGMT0,
            (R.GYRO_MODE, R.MODE_LOW_NOISE),
            (R.ACCEL_MODE, R.MODE_LOW_NOISE),
            clear_bits=R.PwrMgmt0.TEMP_DIS | R.PwrMgmt0.IDLE,
        )
    )
    return plan


class Icm42688pDriver:
    """Stop-on-full FIFO driver. Blocking; owned by its bus's worker."""

    def __init__(self, cfg: Icm42688pConfig, dev: RegisterDevice, clock: Clock) -> None:
        self.cfg = cfg
        self.dev = dev
        self.clock = clock
        self.counters = DriverCounters()
        self.packet = R.PACKET4_BYTES if cfg.hires else R.PACKET3_BYTES
        self.fifo_capacity = R.FIFO_SIZE // self.packet
        self.nominal_period_ns = 1e9 / cfg.odr_hz
        self.group_delay_ns = 0  # the filters' delay is not published (docs/timestamps.md)
        self.poll_interval_ns = fifo_poll_interval_ns(self.fifo_capacity, self.nominal_period_ns)
        self.next_poll_ns: int | None = None  # a FIFO: polled at its interval
        self.accel_scale = accel_scale_ms2(cfg.accel_range_g, cfg.hires)
        self.gyro_scale = gyro_scale_rads(cfg.gyro_range_dps, cfg.hires)
        self.full_scale = float(2**19 - 1 if cfg.hires else 2**15 - 1)
        self.invalid_packets = 0
        # whether the chip may be in a bank other than 0 (the FIFO and its count are read in
        # bank 0); start() selects bank 0 whatever the chip holds
        self._off_bank0 = False
        self.plan = RegisterPlan(dev, register_plan(cfg), self._select_bank)
        # PWR_MGMT0: any reset turns the sensors off, which the plan turns on
        self._checker = RegisterChecker(
            [self.plan], clock, self.counters, sentinels=[(self.plan, self.plan.settings[-1])],
            poll_ns=self.poll_interval_ns + self.nominal_period_ns,
        )  # fmt: skip
        self.timing = FifoTiming()
        self.ticks_per_sample = self.nominal_period_ns / R.TICK_NS
        self._last_read_ns = 0  # when the last FIFO data read began: room was made from then
        # the newest packet delivered: its FIFO timestamp (None: after a flush, nothing to
        # continue), and a host time it was latched after (the count read before its own)
        self._last_tick: int | None = None
        self._newest_after_ns = 0
        self._count_ns = 0  # when the last FIFO count read began
        # how soon after the newest packet a packet must come for its 16-bit timestamp to tell
        # the next sample from one a whole wrap later (host time, for a clock up to 10 % fast)
        self._unwrapped_ns = 0.9 * (R.TIMESTAMP_MODULO - 1.5 * self.ticks_per_sample) * R.TICK_NS

    def _select_bank(self, dev: RegisterDevice, bank: int) -> None:
        """Select a register bank, and read the selection back until it holds: SPI has no
        acknowledge, so a write lost on the line (a garbled transfer) shows only by reading.
        Unchecked, a lost select made the register re-check read another bank's register and
        report a chip reset that never happened (a re-initialisation and a hundred samples
        lost), and a lost return to bank 0 made the next poll read its FIFO count and data from
        bank 1 or 2. A select that fails leaves the bank unknown: the next read selects bank 0
        first. Nothing to do for bank 0 while the chip is known to be there."""
        if bank == 0 and not self._off_bank0:
            return
        self._off_bank0 = True
        got = -1
        for _ in range(BANK_TRIES):
            dev.write_u8(R.Bank0.REG_BANK_SEL, bank)
            got = dev.read_u8(R.Bank0.REG_BANK_SEL)
            if got & _BANK_SEL == bank:
                self._off_bank0 = bank != 0
                return
        raise BusError(
            0, f"REG_BANK_SEL reads 0x{got:02x} after selecting bank {bank} {BANK_TRIES} times"
        )

    def start(self) -> Iterator[int]:
        self._off_bank0 = True  # until the soft reset below has selected bank 0
        # a stale bank would make WHO_AM_I read wrong (not read back: a chip that does not
        # answer is best told by its WHO_AM_I, and a select that was lost fails the reset)
        self.dev.write_u8(R.Bank0.REG_BANK_SEL, 0)
        who = self.dev.read_u8(R.Bank0.WHO_AM_I)
        if who != R.WHO_AM_I_VALUE:
            raise DeviceIdentityError(
                f"WHO_AM_I (0x{R.Bank0.WHO_AM_I:02x}) reads 0x{who:02x}, expected "
                f"0x{R.WHO_AM_I_VALUE:02x} for an ICM-42688-P: check the chip, the wiring and the "
                "chip select/address"
            )
        self.dev.write_u8(R.Bank0.DEVICE_CONFIG, R.DeviceConfig.SOFT_RESET_CONFIG)
        yield R.RESET_WAIT_NS
        if not self.dev.read_u8(R.Bank0.INT_STATUS) & R.IntStatus.RESET_DONE_INT:
            raise DeviceIdentityError("ICM-42688-P did not report RESET_DONE after soft reset")
        self._off_bank0 = False  # the reset selected bank 0
        self.counters.soft_resets += 1
        for s in self.plan.settings:  # power on last, once everything is set
            self.plan.write(s)
        yield R.POWER_ON_WAIT_NS  # no register write within 200 us of turning sensors on
        self.plan.verify_all()
        yield R.STARTUP_WAIT_NS  # gyro start-up; packets before it carry the invalid marker
        self._flush()
        self.timing.started()
        self._checker.restart()

    def _flush(self) -> None:
        t0 = self.clock.now_ns()
        self.dev.write_u8(R.Bank0.SIGNAL_PATH_RESET, R.SignalPathReset.FIFO_FLUSH)
        self.timing.flushed(t0, self.clock.now_ns())
        self._last_read_ns = t0
        self._last_tick = None  # what comes next follows the flush, not the last packet
        self.dev.read(R.Bank0.INT_STATUS, 3)  # the first count after a flush reads 0: discard it
        self.counters.fifo_resets += 1

    def _batch(
        self, p: Packets | None, t_before: int, t_after: int, full: bool = False
    ) -> RawBatch:
        if p is None:
            return RawBatch(0, {}, self.timing.read(t_before, t_after))
        counter = ChipCounter(p.timestamp, R.TIMESTAMP_MODULO)
        timing = self.timing.read(t_before, t_after, full=full, counter=counter)
        if p.clean:
            masks: tuple[npt.NDArray[np.bool_] | None, ...] = (None, None, None)
        else:
            masks = (_any(p.accel_invalid), _any(p.gyro_invalid), _any(p.temperature_invalid))
        return RawBatch(
            p.n,
            {
                Channel.ACCEL: RawChannel(p.accel, self.accel_scale, self.full_scale, masks[0]),
                Channel.GYRO: RawChannel(p.gyro, self.gyro_scale, self.full_scale, masks[1]),
                Channel.TEMPERATURE: RawChannel(p.temperature_c, invalid=masks[2]),
            },
            timing,
        )

    def read(self) -> RawBatch:
        if self._off_bank0:  # a bank select failed: the FIFO is in bank 0
            self._select_bank(self.dev, 0)
        t_before = self.clock.now_ns()
        prev_count, self._count_ns = self._count_ns, t_before
        head = self.dev.read(R.Bank0.INT_STATUS, 3)
        t_after = self.clock.now_ns()
        if head == b"\xff\xff\xff":  # the chip never sends this: a floating MISO line
            raise BusError(0, "status and FIFO count read all ones: no answer on MISO")
        status, count = head[0], int.from_bytes(head[1:3], "big")
        full = bool(status & _FIFO_FULL) or count >= R.FIFO_SIZE - self.packet + 1
        n = min(count, R.FIFO_SIZE) // self.packet
        self._checker.check_next()
        if n == 0:
            return self._batch(None, t_before, t_after)
        r0 = self.clock.now_ns()
        data = self.dev.read(R.Bank0.FIFO_DATA, n * self.packet)
        r1 = self.clock.now_ns()
        p, breaks = decode_fifo(data, self.cfg.hires, self.ticks_per_sample)
        if not p.clean:
            self.invalid_packets += int((p.accel_invalid & p.gyro_invalid).sum())
        if p.n:
            if self.timing.broken and self._continues(int(p.timestamp[0]), t_after):
                # the last read found the FIFO full, yet this is the next sample: the FIFO was
                # not full at that read's count, and the chip went on filling it until the data
                # burst made room (a stall between the two), so what the burst left comes
                # first now. The samples it dropped meanwhile show as a break after them, and
                # are counted there (placed after the restart instead, the gap was partly
                # counted twice). Or the chip dropped nothing at all.
                self.timing.mended()
            self._last_tick = int(p.timestamp[-1])
            self._newest_after_ns = prev_count  # it was not in the FIFO at that count
        if p.n < n:
            # fewer packets than counted: a garbled burst (SPI reads 0xFF when MISO floats) or a
            # FIFO out of step. Keep what decoded, flush, and resync on the next read.
            self.counters.bad_transfers += 1
            # what decoded continues the stream, but is not the newest sample: no phase
            batch = self._batch(p, t_before, t_after, full=True)
            self._flush()
            return batch
        if breaks:
            batch = self._broken(p, breaks, t_before, t_after, full)
        else:
            batch = self._batch(p, t_before, t_after, full=full)
        self._last_read_ns = r0
        if full:
            # stop-on-full: what we read is whole and valid, but the chip dropped the samples
            # that came while it was full; space frees as we read, so the stream resumes then
            self.counters.fifo_overflows += 1
            # the next packet, unless it continues this batch (`_continues`), is the first the
            # chip latched after room was made, by r1: after the count began, and after the
            # burst began too if the FIFO was full at the count (nothing could enter before)
            self.timing.broke((r0 if n == self.fifo_capacity else t_before, r1))
        return batch

    def _continues(self, tick: int, t_after: int) -> bool:
        """Whether a batch's first packet is the sample right after the newest one delivered,
        by their FIFO timestamps: one sample apart, and too soon after it (host time) for the
        16-bit counter to have wrapped in between. Unknown after a flush: False."""
        if self._last_tick is None or t_after - self._newest_after_ns >= self._unwrapped_ns:
            return False
        step = (tick - self._last_tick) % R.TIMESTAMP_MODULO
        return step <= 1.5 * self.ticks_per_sample

    def _broken(
        self, p: Packets, breaks: list[int], t_before: int, t_after: int, full: bool
    ) -> RawBatch:
        """A batch whose packets jump in time: the FIFO filled after the last read began (a
        stall inside it) and took new samples when that read made room. Each run is its own
        batch, chained: the first continues the stream but is not the newest (no phase), each
        later one follows a gap its timestamps count, the last is newest unless full now."""
        self.counters.fifo_overflows += len(breaks)
        edges = [0, *breaks, p.n]
        first = self._batch(p.part(0, edges[1]), t_before, t_after, full=True)
        tail = first
        for j, (a, b) in enumerate(itertools.pairwise(edges[1:])):
            last = j == len(breaks) - 1
            self.timing.broke((self._last_read_ns, t_before))
            tail.then = self._batch(p.part(a, b), t_before, t_after, full=full or not last)
            tail = tail.then
        return first

    def stop(self) -> None:
        with contextlib.suppress(BusError):
            self.dev.write_u8(R.Bank0.PWR_MGMT0, 0)

    def chip_status(self) -> dict[str, Any]:
        return {"invalid_packets": self.invalid_packets}


def _any(mask: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_] | None:
    """A mask only when some sample is invalid: the common case skips the pipeline's work."""
    return mask if bool(mask.any()) else None
