"""Bosch BMI088 over SPI or I2C: two dies (accel, gyro) configured and published as one device.

Register facts and FIFO decoding are in `imud.chips.bmi088_fifo`; how the two dies' samples are
paired into one 6-axis stream is in `imud.pairing`. The accel FIFO runs in stream mode (a skip
frame then counts exactly the frames an overflow overwrote); the gyro FIFO stops when full and
raises its overrun bit, so what imud reads is whole and the gap is counted from the clock fit.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Literal

import numpy as np
from pydantic import Field, ValidationInfo, field_validator, model_validator

from imud.buses.models import Bus, I2cBus, SimBus, SpiBus
from imud.buses.registers import RegisterDevice
from imud.chips import bmi088_fifo as f
from imud.chips.base import DeviceBase, DeviceIdentityError, DriverCounters, RawBatch
from imud.chips.checks import RegisterChecker
from imud.clock import Clock
from imud.errors import BusError
from imud.pairing import DiePairer
from imud.timestamps import SampleClock, Stamped

ACCEL_ODRS: dict[float, int] = {
    12.5: 0x5, 25.0: 0x6, 50.0: 0x7, 100.0: 0x8, 200.0: 0x9, 400.0: 0xA, 800.0: 0xB, 1600.0: 0xC,
}  # fmt: skip
ACCEL_FILTERS = {"osr4": 0x8, "osr2": 0x9, "normal": 0xA}  # ACC_CONF bwp
# GYRO_BANDWIDTH code -> (ODR Hz, filter bandwidth Hz)
GYRO_MODES: dict[int, tuple[float, int]] = {
    0x0: (2000.0, 532), 0x1: (2000.0, 230), 0x2: (1000.0, 116), 0x3: (400.0, 47),
    0x4: (200.0, 23), 0x5: (100.0, 12), 0x6: (200.0, 64), 0x7: (100.0, 32),
}  # fmt: skip
ACC_FIFO_STREAM = 0x02  # FIFO_CONFIG_0: bit 1 must be 1, bit 0 = 0 stream (overwrite oldest)
ACC_FIFO_ACCEL_EN = 0x50  # FIFO_CONFIG_1: acc_en | the bit that must be 1
ACC_PWR_ACTIVE = 0x00
ACC_PWR_SUSPEND = 0x03
ACC_ENABLE = 0x04
GYR_FIFO_MODE_FIFO = 0x40  # stop when full, overrun bit; XYZ frames
GYR_LPM_NORMAL = 0x00
GYR_LPM_SUSPEND = 0x80
GYR_BANDWIDTH_READ_BIT = 0x80  # bit 7 reads 1

ACC_RESET_WAIT_NS = 1_000_000
GYR_RESET_WAIT_NS = 30_000_000
POWER_WAIT_NS = 5_000_000  # after each accel power register write (Bosch API, Linux)
STARTUP_WAIT_NS = 10_000_000  # first samples after power-up are settling: flushed
WRITE_TRIES = 4  # accel writes after power-up may need retries (ArduPilot retries up to 8)
MAX_SPI_HZ = 10_000_000
I2C_BITS_PER_BYTE = 9
BUS_OVERHEAD = 1.25


def gyro_modes_for(odr: float) -> list[int]:
    return [bw for code, (o, bw) in GYRO_MODES.items() if o == odr]


def bus_bits_per_second(accel_odr: float, gyro_odr: float) -> float:
    """I2C bandwidth both FIFO streams need: 7-byte accel frames and 6-byte gyro frames."""
    return (accel_odr * 7 + gyro_odr * 6) * I2C_BITS_PER_BYTE * BUS_OVERHEAD


class Bmi088Config(DeviceBase):
    """A BMI088: `bus` is the accel die, `gyro_bus` the gyro die, on the same physical bus.

    Published at the gyro's rate; the accel is interpolated onto the gyro's sample times."""

    chip: Literal["bmi088"]
    gyro_bus: Bus = Field(description="the gyro die: its own chip select or I2C address")
    accel_range_g: Literal[3, 6, 12, 24] = 24
    accel_odr_hz: float = Field(1600, description="12.5, 25, 50, 100, 200, 400, 800, 1600")
    accel_filter: Literal["normal", "osr2", "osr4"] = Field(
        "normal", description="normal, or 2x / 4x oversampling (lower bandwidth)"
    )
    gyro_range_dps: Literal[125, 250, 500, 1000, 2000] = 2000
    gyro_odr_hz: Literal[100, 200, 400, 1000, 2000] = 2000
    gyro_filter_hz: int | None = Field(
        None, description="2000 Hz: 532 or 230; 1000: 116; 400: 47; 200: 23 or 64; 100: 12 or 32"
    )

    @property
    def odr_hz(self) -> float:
        """The published rate: the gyro's."""
        return float(self.gyro_odr_hz)

    def die_buses(self) -> list[Bus]:
        return [self.bus, self.gyro_bus]

    @field_validator("accel_odr_hz")
    @classmethod
    def _accel_odr(cls, v: float) -> float:
        if float(v) not in ACCEL_ODRS:
            allowed = ", ".join(f"{a:g}" for a in ACCEL_ODRS)
            raise ValueError(f"the BMI088 accel has no output data rate {v:g} Hz; use {allowed}")
        return float(v)

    @field_validator("gyro_bus")
    @classmethod
    def _same_bus(cls, v: Bus, info: ValidationInfo) -> Bus:
        acc = info.data.get("bus")
        if acc is None or not isinstance(v, I2cBus | SpiBus | SimBus):
            return v  # a serial gyro_bus: the device check says which buses the chip takes
        if not isinstance(acc, I2cBus | SpiBus | SimBus):
            return v
        if type(v) is not type(acc) or v.key != acc.key:
            raise ValueError(
                f"the gyro die must be on the accel die's bus ({acc.kind} {acc.key}): the "
                "driver talks to both from one worker; give the gyro its own chip select "
                "(SPI) or address (I2C) on that bus"
            )
        if isinstance(v, SimBus) and isinstance(acc, SimBus) and v.transport != acc.transport:
            raise ValueError("both dies need the same transport (i2c or spi)")
        if v.slot == acc.slot:
            where = "chip select" if _spi(v) else "address"
            raise ValueError(
                f"the gyro die needs its own {where}: it is the accel die's ({' '.join(v.slot)})"
            )
        return v

    @model_validator(mode="after")
    def _filters_and_bus(self) -> Bmi088Config:
        odr = float(self.gyro_odr_hz)
        modes = gyro_modes_for(odr)
        if self.gyro_filter_hz is None:
            self.gyro_filter_hz = max(modes)
        elif self.gyro_filter_hz not in modes:
            listed = " or ".join(str(m) for m in modes)
            raise ValueError(
                f"gyro_filter_hz = {self.gyro_filter_hz}: at gyro_odr_hz = {odr:g} the BMI088 "
                f"gyro filters at {listed} Hz"
            )
        speeds: list[int] = []
        for field, b in (("bus", self.bus), ("gyro_bus", self.gyro_bus)):
            speed = b.clock_hz if isinstance(b, SimBus) else getattr(b, "speed_hz", None)
            if speed is None:
                continue
            speeds.append(speed)
            if _spi(b) and speed > MAX_SPI_HZ:
                raise ValueError(
                    f"the BMI088's SPI runs at most at 10 MHz; {field}.speed_hz is "
                    f"{speed / 1e6:g} MHz"
                )
        b = self.bus
        i2c = isinstance(b, I2cBus) or (isinstance(b, SimBus) and b.transport == "i2c")
        speed = min(speeds) if speeds else None  # one I2C bus: the slower setting is the truth
        need = bus_bits_per_second(self.accel_odr_hz, odr)
        if i2c and speed is not None and need > speed:
            raise ValueError(
                f"accel {self.accel_odr_hz:g} Hz + gyro {odr:g} Hz need about {need / 1e3:.0f} "
                f"kbit/s on I2C (7- and 6-byte FIFO frames, 9 bits a byte, 25 % overhead) but "
                f"the bus runs at {speed / 1e3:g} kHz (bus.speed_hz): lower the rates or use "
                "400 kHz I2C or SPI"
            )
        return self

    def gyro_bandwidth_code(self) -> int:
        for code, mode in GYRO_MODES.items():
            if mode == (float(self.gyro_odr_hz), self.gyro_filter_hz):
                return code
        raise AssertionError("validated above")


def _spi(bus: Bus) -> bool:
    return isinstance(bus, SpiBus) or (isinstance(bus, SimBus) and bus.transport == "spi")


class Bmi088Driver:
    """Both dies' FIFOs each poll, stamped per die, paired onto gyro times. Blocking; owned by
    the bus worker thread."""

    def __init__(
        self, cfg: Bmi088Config, acc: RegisterDevice, gyr: RegisterDevice, clock: Clock
    ) -> None:
        self.cfg, self.acc, self.gyr, self.clock = cfg, acc, gyr, clock
        self.counters = DriverCounters()
        self.spi = _spi(cfg.bus)
        self.nominal_period_ns = 1e9 / cfg.gyro_odr_hz
        self.accel_period_ns = 1e9 / cfg.accel_odr_hz
        self.fifo_capacity = f.GYR_FIFO_FRAMES
        acc_frames = f.ACC_FIFO_SIZE // 7
        # a quarter of the smaller FIFO between polls; at most 10 ms, which bounds how long the
        # newest gyro samples wait for an accel sample after them
        self.poll_interval_ns = int(
            min(
                10e6,
                self.nominal_period_ns * f.GYR_FIFO_FRAMES / 4,
                self.accel_period_ns * acc_frames / 4,
            )
        )
        self.accel_scale = f.accel_scale_ms2(cfg.accel_range_g)
        self.gyro_scale = f.gyro_scale_rads(cfg.gyro_range_dps)
        self.gyro_clock = SampleClock(self.nominal_period_ns)  # the runner may lend its own
        self.accel_clock = SampleClock(self.accel_period_ns)
        wait = 3 * self.accel_period_ns + 4 * self.poll_interval_ns  # then accel is missing
        self.pairer = DiePairer(max_wait_ns=int(max(100e6, wait)))
        self.accel_skipped = 0  # frames the accel FIFO reported overwritten (skip frames)
        self.temperature = 23.0
        self._acc_plan = [
            (f.ACC_CONF, ACCEL_FILTERS[cfg.accel_filter] << 4 | ACCEL_ODRS[cfg.accel_odr_hz]),
            (f.ACC_RANGE, f.ACCEL_RANGES_G.index(cfg.accel_range_g)),
            (f.ACC_FIFO_CONFIG_0, ACC_FIFO_STREAM),
            (f.ACC_FIFO_CONFIG_1, ACC_FIFO_ACCEL_EN),
            (f.ACC_PWR_CONF, ACC_PWR_ACTIVE),
            (f.ACC_PWR_CTRL, ACC_ENABLE),
        ]
        self._gyr_plan = [
            (f.GYR_RANGE, f.GYRO_RANGES_DPS.index(cfg.gyro_range_dps)),
            (f.GYR_BANDWIDTH, GYR_BANDWIDTH_READ_BIT | cfg.gyro_bandwidth_code()),
            (f.GYR_LPM1, GYR_LPM_NORMAL),
            (f.GYR_FIFO_CONFIG_1, GYR_FIFO_MODE_FIFO),
        ]
        self._acc_check = RegisterChecker(acc, self._acc_plan, clock, self.counters)
        self._gyr_check = RegisterChecker(gyr, self._gyr_plan, clock, self.counters)
        self._g_resync = self._a_resync = False
        self._g_restart: tuple[int, int] | None = None
        self._a_restart: tuple[int, int] | None = None

    @property
    def chip_rate_hz(self) -> float:
        return self.gyro_clock.rate_hz

    def bind_clock(self, clock: SampleClock) -> None:
        """Stamp gyro samples with the runner's clock: seq numbers survive a driver re-open."""
        self.gyro_clock = clock

    # --- start ------------------------------------------------------------------------------
    def _identify(self) -> None:
        if self.spi:  # the accel die starts in I2C mode: a first SPI access switches it
            self.acc.read_u8(f.ACC_CHIP_ID)
        for dev, reg, want, die in (
            (self.acc, f.ACC_CHIP_ID, f.ACC_CHIP_ID_VALUE, "accel"),
            (self.gyr, f.GYR_CHIP_ID, f.GYR_CHIP_ID_VALUE, "gyro"),
        ):
            got = dev.read_u8(reg)
            if got != want:
                got = dev.read_u8(reg)
            if got != want:
                raise DeviceIdentityError(
                    f"BMI088 {die} die: CHIP_ID reads 0x{got:02x}, expected 0x{want:02x}: check "
                    f"the wiring and {'bus' if die == 'accel' else 'gyro_bus'} (the {die} die's "
                    "chip select or address)"
                )

    def _write_checked(self, dev: RegisterDevice, reg: int, val: int, die: str) -> None:
        got = -1
        for _ in range(WRITE_TRIES):
            dev.write_u8(reg, val)
            got = dev.read_u8(reg)
            if got == val:
                return
        raise DeviceIdentityError(
            f"BMI088 {die} die: register 0x{reg:02x} reads 0x{got:02x} after writing 0x{val:02x} "
            f"{WRITE_TRIES} times"
        )

    def start(self) -> Iterator[int]:
        self._identify()
        self.acc.write_u8(f.ACC_SOFTRESET, f.SOFTRESET_CMD)
        self.gyr.write_u8(f.GYR_SOFTRESET, f.SOFTRESET_CMD)
        yield GYR_RESET_WAIT_NS  # covers the accel's 1 ms too
        self._identify()  # the reset put the accel back in I2C mode: the dummy read again
        self.counters.resets += 1
        self.acc.write_u8(f.ACC_PWR_CONF, ACC_PWR_ACTIVE)
        yield POWER_WAIT_NS
        self.acc.write_u8(f.ACC_PWR_CTRL, ACC_ENABLE)
        yield POWER_WAIT_NS
        for reg, val in self._acc_plan:
            self._write_checked(self.acc, reg, val, "accel")
        for reg, val in self._gyr_plan:
            self._write_checked(self.gyr, reg, val, "gyro")
        yield STARTUP_WAIT_NS
        self.temperature = self._read_temperature()
        self._flush_accel()
        self._flush_gyro()
        for c in (self.accel_clock, self.gyro_clock):
            if c.k_last >= 0:  # samples before this start: count the gap on the new grid
                c.rebase()
        self.pairer.reset()
        self._acc_check.restart()
        self._gyr_check.restart()

    def _read_temperature(self) -> float:
        msb, lsb = self.acc.read(f.TEMP_MSB, 2)
        return f.temperature_c(msb, lsb)

    def _flush_accel(self) -> None:
        t0 = self.clock.now_ns()
        self.acc.write_u8(f.ACC_SOFTRESET, f.ACC_FIFO_FLUSH_CMD)
        self._a_resync, self._a_restart = True, (t0, self.clock.now_ns())
        self.counters.fifo_resets += 1

    def _flush_gyro(self) -> None:
        t0 = self.clock.now_ns()
        self.gyr.write_u8(f.GYR_FIFO_CONFIG_0, 0)  # writing the watermark empties the FIFO
        self.gyr.write_u8(f.GYR_FIFO_CONFIG_1, GYR_FIFO_MODE_FIFO)  # and this clears overrun
        self._g_resync, self._g_restart = True, (t0, self.clock.now_ns())
        self.counters.fifo_resets += 1

    # --- read -------------------------------------------------------------------------------
    def _read_gyro(self) -> None:
        tb = self.clock.now_ns()
        status = self.gyr.read_u8(f.GYR_FIFO_STATUS)
        ta = self.clock.now_ns()
        if status == 0xFF:  # 127 frames with overrun: more than the FIFO holds; MISO floats
            raise BusError(0, "gyro FIFO_STATUS reads 0xff: no answer on MISO")
        n = min(status & 0x7F, f.GYR_FIFO_FRAMES)
        overrun = bool(status & 0x80) or n >= f.GYR_FIFO_FRAMES
        resync, restart = self._g_resync, self._g_restart
        self._g_resync, self._g_restart = False, None
        if n == 0:
            self.gyro_clock.update(0, tb, ta, resync, restart=restart)
            return
        r0 = self.clock.now_ns()
        data = self.gyr.read(f.GYR_FIFO_DATA, n * f.GYR_FRAME)
        r1 = self.clock.now_ns()
        gyro = f.decode_gyro_fifo(data)
        if overrun:
            # stop-on-full: what we read is whole, but the newest sample is old and the ones
            # after it were dropped until this read made room; clearing overrun keeps it going
            self.counters.fifo_overflows += 1
            self.gyr.write_u8(f.GYR_FIFO_CONFIG_1, GYR_FIFO_MODE_FIFO)
            self._g_resync, self._g_restart = True, (r0, r1)
        st = self.gyro_clock.update(n, tb, ta, resync, restart=restart, full=overrun)
        self.pairer.add_gyro(st.first_seq + np.arange(n, dtype=np.int64), st.t_ns, gyro)

    def _read_accel(self) -> None:
        tb = self.clock.now_ns()
        head = self.acc.read(f.TEMP_MSB, 4)  # TEMP_MSB, TEMP_LSB, FIFO_LENGTH_0/1: one burst
        ta = self.clock.now_ns()
        if head == b"\xff\xff\xff\xff":
            raise BusError(0, "accel temperature and FIFO length read all ones: no answer")
        self.temperature = f.temperature_c(head[0], head[1])
        length = 0 if head[3] & 0x80 else f.fifo_length(head[2], head[3])  # bit 15: empty
        resync, restart = self._a_resync, self._a_restart
        self._a_resync, self._a_restart = False, None
        if length == 0:
            self.accel_clock.update(0, tb, ta, resync, restart=restart)
            return
        if length > f.ACC_FIFO_SIZE:
            self.counters.bad_transfers += 1
            self._flush_accel()
            return
        data = self.acc.read(f.ACC_FIFO_DATA, length)
        fifo = f.decode_accel_fifo(data)
        n = int(fifo.accel.shape[0])
        # frame positions counting the frames skip frames say were overwritten: exact gaps
        pos = np.arange(n, dtype=np.int64)
        unknown = False
        for at, count in fifo.skipped_before:
            if count >= 0xFF:  # "more than 255": the count is unknown, the clock fit decides
                unknown = True
            else:
                pos[at:] += count
            self.accel_skipped += count
            self.counters.fifo_overflows += 1
        total = int(pos[-1]) + 1 if n else 0
        if fifo.corrupt_at is not None:
            self.counters.bad_transfers += 1
        if n:
            st = self.accel_clock.update(
                total, tb, ta, resync or unknown, restart=restart if resync else None
            )
            t = st.t_ns[pos]
            self.pairer.add_accel(st.first_seq + pos, t, fifo.accel)
        else:
            self.accel_clock.update(0, tb, ta, resync, restart=restart)
        if fifo.corrupt_at is not None:
            self._flush_accel()

    def read(self) -> RawBatch:
        t0 = self.clock.now_ns()
        self._read_gyro()  # gyro first: the accel read after it covers its newest samples
        self._read_accel()
        self._acc_check.check_next()
        self._gyr_check.check_next()
        t1 = self.clock.now_ns()
        p = self.pairer.take()
        if p is None:
            z = np.zeros((0, 3), dtype=np.int32)
            stamps = Stamped(self.pairer.next_seq or 0, 0, np.zeros(0, dtype=np.int64))
            return RawBatch(z, z, np.zeros(0), self.accel_scale, self.gyro_scale, t0, t1,
                            stamps=stamps)  # fmt: skip
        return RawBatch(
            p.accel, p.gyro, np.full(p.n, self.temperature), self.accel_scale, self.gyro_scale,
            t0, t1, valid=None if bool(p.valid.all()) else p.valid,
            stamps=Stamped(p.first_seq, p.lost_before, p.t_ns),
        )  # fmt: skip

    def stop(self) -> None:
        with contextlib.suppress(BusError):
            self.acc.write_u8(f.ACC_PWR_CTRL, 0)
            self.acc.write_u8(f.ACC_PWR_CONF, ACC_PWR_SUSPEND)
            self.gyr.write_u8(f.GYR_LPM1, GYR_LPM_SUSPEND)
