"""BMI088 driver: both dies' FIFOs each poll, one batch per die (`RawBatch.die`); the pipeline
stamps each die on its own sample clock and interpolates the accel onto the gyro's sample times
(`imud.align`; the spec's `die_periods` and `time_base`).

The accel FIFO runs in stream mode (a skip frame then counts exactly the frames an overflow
overwrote: the batch holds those positions, invalid); the gyro FIFO stops when full and raises
its overrun bit, so what imud reads is whole and the gap is counted from the clock fit. The
temperature is read with the accel FIFO's length and travels with the accel samples.
"""

from __future__ import annotations

import contextlib
import itertools
import math
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from imud.buses.registers import RegisterDevice
from imud.channels import Channel
from imud.chips.api import DriverCounters, RawBatch, RawChannel
from imud.chips.bits import BitField
from imud.chips.bmi088 import decode as d
from imud.chips.bmi088 import registers as R
from imud.chips.bmi088.config import ACCEL, GYRO, Bmi088Config, is_spi
from imud.chips.fifotiming import FifoTiming
from imud.chips.regplan import RegisterChecker, RegisterPlan, RegisterSetting
from imud.clock import Clock
from imud.errors import BusError, DeviceIdentityError, ErrorKind, error_kind

A, G = R.AccelRegister, R.GyroRegister
STARTUP_WAIT_NS = 10_000_000  # first samples after power-up are settling: flushed
WRITE_TRIES = 4  # accel writes after power-up may need retries (ArduPilot retries up to 8)
FULL_SCALE = 32767
_WHOLE = BitField(0xFF)
_OVERRUN = int(R.GyroFifoStatus.OVERRUN)


def accel_plan(c: Bmi088Config) -> list[RegisterSetting]:
    fs = RegisterSetting.fields
    F1 = R.AccFifoConfig1
    return [
        fs(
            A.ACC_CONF,
            (R.ACC_CONF_BWP, R.ACCEL_BWP_CODES[c.accel_filter]),
            (R.ACC_CONF_ODR, R.ACCEL_ODR_CODES[c.accel_odr_hz]),
        ),
        fs(A.ACC_RANGE, (R.ACC_RANGE_FIELD, R.ACCEL_RANGES_G.index(c.accel_range_g))),
        RegisterSetting(  # stream mode: an overflow keeps the newest frames
            A.FIFO_CONFIG_0,
            set_bits=R.AccFifoConfig0.MUST_BE_ONE,
            clear_bits=R.AccFifoConfig0.FIFO_MODE,
        ),
        RegisterSetting(
            A.FIFO_CONFIG_1,
            set_bits=F1.ACC_EN | F1.MUST_BE_ONE,
            clear_bits=F1.INT1_INPUT_EN | F1.INT2_INPUT_EN,
        ),
        fs(A.ACC_PWR_CONF, (_WHOLE, R.ACC_PWR_CONF_ACTIVE)),
        fs(A.ACC_PWR_CTRL, (_WHOLE, R.ACC_PWR_CTRL_ON)),
    ]


def gyro_plan(c: Bmi088Config) -> list[RegisterSetting]:
    fs = RegisterSetting.fields
    return [
        fs(G.GYRO_RANGE, (R.GYRO_RANGE_FIELD, R.GYRO_RANGES_DPS.index(c.gyro_range_dps))),
        fs(G.GYRO_BANDWIDTH, (R.GYRO_BANDWIDTH_FIELD, c.gyro_bandwidth_code())),
        fs(G.GYRO_LPM1, (_WHOLE, R.GYRO_LPM1_NORMAL)),
        fs(
            G.FIFO_CONFIG_1,
            (R.GYRO_FIFO_MODE, R.GYRO_FIFO_MODE_FIFO),
            (R.GYRO_FIFO_DATA_SELECT, 0),
        ),
    ]


class Bmi088Driver:
    """Both dies' FIFOs each poll, stamped per die, paired onto gyro times. Blocking; owned by
    the bus worker."""

    def __init__(
        self, cfg: Bmi088Config, acc: RegisterDevice, gyr: RegisterDevice, clock: Clock
    ) -> None:
        self.cfg, self.acc, self.gyr, self.clock = cfg, acc, gyr, clock
        self.counters = DriverCounters()
        self.spi = is_spi(cfg.bus)
        self.nominal_period_ns = 1e9 / cfg.odr_hz
        self.group_delay_ns = 0  # the filters' delay is not published (docs/timestamps.md)
        self.accel_period_ns = 1e9 / cfg.accel_odr_hz
        self.fifo_capacity = R.GYRO_FIFO_FRAMES
        acc_frames = R.ACC_FIFO_BYTES // R.ACC_FRAME_BYTES
        # a quarter of the smaller FIFO between polls; at most 10 ms, which bounds how long the
        # newest gyro samples wait for an accel sample after them
        self.poll_interval_ns = int(
            min(
                10e6,
                self.nominal_period_ns * R.GYRO_FIFO_FRAMES / 4,
                self.accel_period_ns * acc_frames / 4,
            )
        )
        self.next_poll_ns: int | None = None  # FIFOs: polled at the interval
        self.accel_scale = d.accel_scale_ms2(cfg.accel_range_g)
        self.gyro_scale = d.gyro_scale_rads(cfg.gyro_range_dps)
        self.accel_skipped = 0  # frames the accel FIFO reported overwritten (skip frames)
        self.temperature = 23.0
        self.acc_plan = RegisterPlan(acc, accel_plan(cfg), die="accel")
        self.gyr_plan = RegisterPlan(gyr, gyro_plan(cfg), die="gyro")
        # any reset leaves the accel off (ACC_PWR_CTRL) and the gyro FIFO in bypass mode
        plans = [self.acc_plan, self.gyr_plan]
        self._checker = RegisterChecker(
            plans, clock, self.counters, sentinels=[(p, p.settings[-1]) for p in plans],
            poll_ns=self.poll_interval_ns + self.nominal_period_ns,
        )  # fmt: skip
        self.gyro_timing, self.accel_timing = FifoTiming(), FifoTiming()
        self._held: list[RawBatch] = []  # gyro batches read at polls that failed after them

    # --- start ------------------------------------------------------------------------------
    def _identify(self) -> None:
        if self.spi:  # the accel die starts in I2C mode: a first SPI access switches it
            self.acc.read_u8(A.ACC_CHIP_ID)
        for dev, reg, want, die in (
            (self.acc, A.ACC_CHIP_ID, R.ACC_CHIP_ID_VALUE, "accel"),
            (self.gyr, G.GYRO_CHIP_ID, R.GYRO_CHIP_ID_VALUE, "gyro"),
        ):
            got = dev.read_u8(reg)
            if got != want:
                got = dev.read_u8(reg)
            if got != want:
                raise DeviceIdentityError(
                    f"BMI088 {die} die: CHIP_ID (0x{reg:02x}) reads 0x{got:02x}, expected "
                    f"0x{want:02x}: check "
                    f"the wiring and {'bus' if die == 'accel' else 'gyro_bus'} (the {die} die's "
                    "chip select or address)"
                )

    def start(self) -> Iterator[int]:
        try:
            self._identify()
        except DeviceIdentityError:  # a die still busy after a reset of its own answers zeros
            yield R.GYRO_RESET_WAIT_NS
            self._identify()
        self.acc.write_u8(A.ACC_SOFTRESET, R.SOFTRESET_CMD)
        self.gyr.write_u8(G.GYRO_SOFTRESET, R.SOFTRESET_CMD)
        yield R.GYRO_RESET_WAIT_NS  # covers the accel's 1 ms too
        self._identify()  # the reset put the accel back in I2C mode: the dummy read again
        self.counters.soft_resets += 1
        self.acc.write_u8(A.ACC_PWR_CONF, R.ACC_PWR_CONF_ACTIVE)
        yield R.ACC_POWER_WAIT_NS
        self.acc.write_u8(A.ACC_PWR_CTRL, R.ACC_PWR_CTRL_ON)
        yield R.ACC_POWER_WAIT_NS
        self.acc_plan.write_all(tries=WRITE_TRIES)
        self.gyr_plan.write_all(tries=WRITE_TRIES)
        yield STARTUP_WAIT_NS
        self.acc_plan.verify_all()
        self.gyr_plan.verify_all()
        self.temperature = self._read_temperature()
        self._flush_accel()
        self._flush_gyro()
        self.accel_timing.started()  # the runner rebases each die's sample clock
        self.gyro_timing.started()
        self._held = []  # read before the restart: the rebased clock counts them as a gap
        self._checker.restart()

    def _read_temperature(self) -> float:
        msb, lsb = self.acc.read(A.TEMP_MSB, 2)
        return d.temperature_c(msb, lsb)

    def _flush_accel(self) -> None:
        t0 = self.clock.now_ns()
        self.acc.write_u8(A.ACC_SOFTRESET, R.ACC_FIFO_FLUSH_CMD)
        self.accel_timing.flushed(t0, self.clock.now_ns())
        self.counters.fifo_resets += 1

    def _flush_gyro(self) -> None:
        t0 = self.clock.now_ns()
        self.gyr.write_u8(G.FIFO_CONFIG_0, 0)  # writing the watermark empties the FIFO
        self._clear_overrun()
        self.gyro_timing.flushed(t0, self.clock.now_ns())
        self.counters.fifo_resets += 1

    def _clear_overrun(self) -> None:
        """Writing the mode register clears the overrun flag (and keeps the frames)."""
        s = self.gyr_plan.settings[-1]
        self.gyr.write_u8(G.FIFO_CONFIG_1, s.apply(0))  # every bit of it is ours

    def _lost_in_transfer(self, e: BusError, flush: Callable[[], None]) -> bool:
        """A FIFO read failed. A NAK comes before any byte: the FIFO is as it was and the next
        poll reads it all. Any other failure may have come after the FIFO gave up bytes, which
        are gone, possibly mid-frame (gyro frames have no header to find the next one by): empty
        that FIFO so its next frames are whole and the gap is counted from the restart. True:
        samples may be lost (the stream resyncs)."""
        if error_kind(e) is ErrorKind.NAK:
            return False
        with contextlib.suppress(BusError):  # if that fails too, the next poll's read says
            flush()
        return True

    # --- read -------------------------------------------------------------------------------
    def _read_gyro(self) -> RawBatch:
        tb = self.clock.now_ns()
        status = self.gyr.read_u8(G.FIFO_STATUS)
        ta = self.clock.now_ns()
        if status == 0xFF:  # 127 frames with overrun: more than the FIFO holds; MISO floats
            raise BusError(0, "gyro FIFO_STATUS reads 0xff: no answer on MISO")
        n = min(R.GYRO_FIFO_FRAME_COUNT.get(status), R.GYRO_FIFO_FRAMES)
        # only the overrun bit says samples were dropped: 100 frames without it is a FIFO that
        # just filled, whose newest frame is the newest sample
        overrun = bool(status & _OVERRUN)
        if n == 0:
            timing = self.gyro_timing.read(tb, ta)
            if overrun:
                self.counters.fifo_overflows += 1
                self._clear_overrun()
            return RawBatch(0, {}, timing, die=GYRO)
        r0 = self.clock.now_ns()
        try:
            data = self.gyr.read(G.FIFO_DATA, n * R.GYRO_FRAME_BYTES)
        except BusError as e:
            if self._lost_in_transfer(e, self._flush_gyro):
                self.gyro_timing.broke()  # (with the flush's restart, when it went through)
            raise
        r1 = self.clock.now_ns()
        gyro = d.decode_gyro_fifo(data)
        timing = self.gyro_timing.read(tb, ta, full=overrun)
        if overrun:
            # stop-on-full: what we read is whole, but the newest sample is old and the ones
            # after it were dropped until this read made room; clearing overrun keeps it going
            self.counters.fifo_overflows += 1
            self._clear_overrun()
            self.gyro_timing.broke((r0, r1))
        gyro_ch = RawChannel(gyro, self.gyro_scale, FULL_SCALE)
        return RawBatch(n, {Channel.GYRO: gyro_ch}, timing, die=GYRO)

    def _read_accel(self) -> RawBatch | None:
        tb = self.clock.now_ns()
        head = self.acc.read(A.TEMP_MSB, 4)  # TEMP_MSB, TEMP_LSB, FIFO_LENGTH_0/1: one burst
        ta = self.clock.now_ns()
        if head == b"\xff\xff\xff\xff":
            raise BusError(0, "accel temperature and FIFO length read all ones: no answer")
        self.temperature = d.temperature_c(head[0], head[1])
        empty = (head[3] << 8) & R.FIFO_LENGTH_EMPTY
        length = 0 if empty else d.fifo_length(head[2], head[3])
        if length == 0:
            return RawBatch(0, {}, self.accel_timing.read(tb, ta), die=ACCEL)
        if length > R.ACC_FIFO_BYTES:
            self.counters.bad_transfers += 1
            self._flush_accel()
            return None
        try:
            data = self.acc.read(A.FIFO_DATA, length)
        except BusError as e:
            if self._lost_in_transfer(e, self._flush_accel):
                self.accel_timing.broke()
            raise
        fifo = d.decode_accel_fifo(data)
        n = int(fifo.accel.shape[0])
        # frame positions counting the frames skip frames say were overwritten: exact gaps,
        # published as positions with no value
        pos = np.arange(n, dtype=np.int64)
        for at, count in fifo.skipped_before:
            if count >= R.SKIP_UNKNOWN:  # "more than 255": unknown, the clock fit decides
                self.accel_timing.broke()
            else:
                pos[at:] += count
            self.accel_skipped += count
            self.counters.fifo_overflows += 1
        if fifo.corrupt_at is not None:
            self.counters.bad_transfers += 1
        batch = self._accel_batch(fifo.accel, pos, tb, ta)
        if fifo.corrupt_at is not None:
            self._flush_accel()
        return batch

    def _accel_batch(self, accel: Any, pos: Any, tb: int, ta: int) -> RawBatch:
        """`accel` frames at positions `pos` of a run of samples (the ones between skipped)."""
        n = int(accel.shape[0])
        total = int(pos[-1]) + 1 if n else 0
        values = np.zeros((total, 3), dtype=accel.dtype)
        values[pos] = accel
        missing = None
        if total != n:
            missing = np.ones(total, dtype=bool)
            missing[pos] = False
        temp = np.full(total, self.temperature)
        temp_invalid = np.isnan(temp) if math.isnan(self.temperature) else None
        if missing is not None:
            temp_invalid = missing if temp_invalid is None else (temp_invalid | missing)
        channels = {
            Channel.ACCEL: RawChannel(values, self.accel_scale, FULL_SCALE, missing),
            Channel.TEMPERATURE: RawChannel(temp, invalid=temp_invalid),
        }
        return RawBatch(total, channels, self.accel_timing.read(tb, ta), die=ACCEL)

    def read(self) -> RawBatch:
        # the register check first: a mismatch reinitialises both dies, so samples read in this
        # poll would only be thrown away with it
        self._checker.check_next()
        # gyro first: the accel read after it covers its newest samples. Gyro batches read at a
        # poll whose accel read then failed go first: the FIFO gave them up, they are not lost
        self._held.append(self._read_gyro())
        batches: list[RawBatch | None] = [*self._held, self._read_accel()]
        self._held = []
        for a, b in itertools.pairwise(batches):
            assert a is not None
            a.then = b
        first = batches[0]
        assert first is not None
        return first

    def stop(self) -> None:
        with contextlib.suppress(BusError):
            self.acc.write_u8(A.ACC_PWR_CTRL, R.ACC_PWR_CTRL_OFF)
            self.acc.write_u8(A.ACC_PWR_CONF, R.ACC_PWR_CONF_SUSPEND)
            self.gyr.write_u8(G.GYRO_LPM1, R.GYRO_LPM1_SUSPEND)

    def chip_status(self) -> dict[str, Any]:
        return {"accel_frames_skipped": self.accel_skipped}
