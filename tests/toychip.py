"""A chip defined outside imud, installed the way a plugin is: through the `imud.chips` entry
point (tests/test_toy_chip.py writes the distribution's metadata, so the daemon and its bus
processes find it as they find imud's own chips).

The toy is a gyro + magnetometer on SPI that clocks out two dummy bytes before read data and
produces a channel most chips lack (the magnetic field). Its FIFO stops when full and raises an
overflow flag; the driver then empties it, and the gap is counted from the sample clock. Its
configured register is re-checked; a brown-out (`[device.sim.faults] resets`) clears it, and the
driver is re-initialised. Its config model has a check of its own (the toy's SPI clock).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from enum import IntEnum, IntFlag
from typing import Any, Literal

import numpy as np
from pydantic import model_validator

from imud.buses import budget
from imud.buses.registers import RegisterDevice
from imud.channels import Channel
from imud.chips.api import (
    ChipSpec,
    DeviceBase,
    Die,
    Driver,
    DriverCounters,
    FifoRead,
    RawBatch,
    RawChannel,
)
from imud.chips.bits import BitField
from imud.chips.regplan import RegisterChecker, RegisterPlan, RegisterSetting
from imud.clock import Clock
from imud.errors import DeviceIdentityError
from imud.sim.api import SimChip, SimDie, Truth
from imud.sim.settings import SimSettings


# --- register map --------------------------------------------------------------------------------
class ToyReg(IntEnum):
    WHO_AM_I = 0x0F
    CTRL = 0x10
    CTRL2 = 0x11  # FIFO_FLUSH (self-clearing)
    STATUS = 0x1F
    FIFO_COUNT = 0x20  # u16 little-endian, whole samples
    FIFO_DATA = 0x22


class Ctrl(IntFlag):
    ENABLE = 0x01


class Ctrl2(IntFlag):
    FIFO_FLUSH = 0x01


class Status(IntFlag):
    OVERFLOW = 0x01  # the FIFO filled and dropped samples; cleared by a flush


CTRL_RATE = BitField(0x0E)  # [3:1]: 0 = 100 Hz, 1 = 200 Hz, 2 = 400 Hz
TOY_ID = 0x5A
TOY_RATES = (100, 200, 400)
DUMMY = 2
SAMPLE = 12  # gyro xyz then mag xyz, int16 big-endian
EMPTY = -32768  # the word a read past the FIFO's end gives
EMPTY_WORD = EMPTY.to_bytes(2, "big", signed=True)
GYRO_LSB_DPS = 0.01  # 100 LSB per deg/s
MAG_LSB_T = 1e-8  # 10 nT per LSB
FIFO_SAMPLES = 64
MAX_SPI_HZ = 8_000_000
CLOCK_ERROR = 0.01  # the toy's oscillator runs 1 % fast


# --- config model --------------------------------------------------------------------------------
class ToyConfig(DeviceBase):
    chip: Literal["toy"]
    odr_hz: Literal[100, 200, 400] = 200

    @model_validator(mode="after")
    def _spi_clock(self) -> ToyConfig:
        if self.bus.clock_hz > MAX_SPI_HZ:
            raise ValueError(
                f"the toy's SPI runs at most at 8 MHz; bus.speed_hz is "
                f"{self.bus.clock_hz / 1e6:g} MHz: lower it"
            )
        why = budget.problem(
            self.bus.transport,
            self.bus.clock_hz,
            self.odr_hz * SAMPLE,
            f"{self.odr_hz} Hz of {SAMPLE}-byte samples",
            "a lower odr_hz",
        )
        if why:
            raise ValueError(why)
        return self


# --- driver --------------------------------------------------------------------------------------
class ToyDriver:
    fifo_capacity = FIFO_SAMPLES
    group_delay_ns = 0  # no filter
    next_poll_ns: int | None = None  # a FIFO: polled at its interval

    def __init__(self, cfg: ToyConfig, dev: RegisterDevice, clock: Clock) -> None:
        self.dev, self.clock = dev, clock
        self.nominal_period_ns = 1e9 / cfg.odr_hz
        self.poll_interval_ns = int(self.nominal_period_ns * FIFO_SAMPLES / 4)
        self.counters = DriverCounters()
        code = TOY_RATES.index(cfg.odr_hz)
        self.plan = RegisterPlan(
            dev, [RegisterSetting.fields(ToyReg.CTRL, (CTRL_RATE, code), set_bits=Ctrl.ENABLE)]
        )
        self.checker = RegisterChecker(
            [self.plan],
            clock,
            self.counters,
            sentinels=[(self.plan, self.plan.settings[0])],
            poll_ns=self.poll_interval_ns + self.nominal_period_ns,
        )
        self.reads = 0
        self._restart: tuple[int, int] | None = None

    def start(self) -> Iterator[int]:
        who = self.dev.read_u8(ToyReg.WHO_AM_I)
        if who != TOY_ID:
            raise DeviceIdentityError(f"toy WHO_AM_I reads 0x{who:02x}, expected 0x{TOY_ID:02x}")
        self.counters.soft_resets += 1  # enabling restarts its sample grid, as a reset does
        self.plan.write_all()
        yield 1_000_000
        self.plan.verify_all()
        self._flush()
        self._restart = None  # a fresh start: the runner rebases its sample clock anyway
        self.checker.restart()

    def _flush(self) -> None:
        t0 = self.clock.now_ns()
        self.dev.write_u8(ToyReg.CTRL2, Ctrl2.FIFO_FLUSH)
        self._restart = (t0, self.clock.now_ns())
        self.counters.fifo_resets += 1

    def _batch(self, tb: int, ta: int, words: Any = None) -> RawBatch:
        restart, self._restart = self._restart, None
        timing = FifoRead(tb, ta, resync=restart is not None, restart_ns=restart)
        if words is None:
            return RawBatch(0, {}, timing)
        return RawBatch(
            int(words.shape[0]),
            {
                Channel.GYRO: RawChannel(words[:, :3], math.radians(GYRO_LSB_DPS), 32767),
                Channel.MAG: RawChannel(words[:, 3:], MAG_LSB_T, 32767),
            },
            timing,
        )

    def read(self) -> RawBatch:
        self.checker.check_next()
        tb = self.clock.now_ns()
        head = self.dev.read(ToyReg.STATUS, 3)
        ta = self.clock.now_ns()
        self.reads += 1
        if head[0] & Status.OVERFLOW:
            self.counters.fifo_overflows += 1
            self._flush()
            return self._batch(tb, ta)
        n = int.from_bytes(head[1:3], "little")
        if n == 0:
            return self._batch(tb, ta)
        data = self.dev.read(ToyReg.FIFO_DATA, n * SAMPLE)
        words = np.frombuffer(data, ">i2").reshape(n, 6)
        empty = (words == EMPTY).all(axis=1)
        if empty.any():  # the FIFO ran dry under the read (a reset): what follows is not data
            words = words[: int(np.argmax(empty))]
        return self._batch(tb, ta, words)

    def stop(self) -> None:
        self.dev.write_u8(ToyReg.CTRL, 0)

    def chip_status(self) -> dict[str, Any]:
        return {"reads": self.reads}


# --- register-level simulator --------------------------------------------------------------------
class ToySim:
    """Turns at 30 deg/s about z in a 50 uT field along x; its clock runs 1 % fast. Truth
    indices count every sample it made since power-on, across re-enables."""

    RATE_DPS = 30.0
    FIELD_T = 50e-6

    def __init__(self, settings: SimSettings, clock: Clock) -> None:
        self.clock = clock
        self.regs = bytearray(256)
        self.regs[ToyReg.WHO_AM_I] = TOY_ID
        self.fifo = bytearray()
        self.origin = clock.now_ns()
        self.k = 0  # samples made since enabled
        self.base = 0  # samples made before this enable
        self.truth: list[tuple[int, int]] = []  # (index, t_ns)
        start = clock.now_ns()
        self.brownouts = sorted(start + int(r.at_s * 1e9) for r in settings.faults.resets)
        self.truth_on = settings.truth

    @property
    def dies(self) -> Sequence[SimDie]:
        return (self,)

    def spi_select(self) -> bool:
        return True

    def _period_ns(self) -> float:
        return 1e9 / (TOY_RATES[(self.regs[ToyReg.CTRL] >> 1) & 7] * (1 + CLOCK_ERROR))

    def _advance(self) -> None:
        now = self.clock.now_ns()
        if self.brownouts and now >= self.brownouts[0]:
            self._make_until(self.brownouts.pop(0))
            self.regs[ToyReg.CTRL] = self.regs[ToyReg.STATUS] = 0  # power-on defaults
            self.fifo.clear()
        self._make_until(now)

    def _make_until(self, t_ns: int) -> None:
        if not self.regs[ToyReg.CTRL] & Ctrl.ENABLE:
            return
        period = self._period_ns()
        due = int((t_ns - self.origin) // period)
        for k in range(self.k + 1, due + 1):
            t_s = k * period / 1e9
            yaw = math.radians(self.RATE_DPS) * t_s  # the field turns the other way in the body
            mag = (self.FIELD_T * math.cos(yaw), -self.FIELD_T * math.sin(yaw), 0.0)
            counts = [0, 0, round(self.RATE_DPS / GYRO_LSB_DPS)]
            counts += [round(m / MAG_LSB_T) for m in mag]
            if len(self.fifo) < FIFO_SAMPLES * SAMPLE:
                self.fifo += np.array(counts, dtype=">i2").tobytes()
            else:
                self.regs[ToyReg.STATUS] |= Status.OVERFLOW  # stop when full: this one is lost
            if self.truth_on:
                self.truth.append((self.base + k, self.origin + round(k * period)))
        self.k = max(self.k, due)

    def read(self, register: int, length: int) -> bytes:
        self._advance()
        if register == ToyReg.FIFO_DATA:
            out = bytes(self.fifo[:length])
            del self.fifo[:length]
            # read past its end (a brown-out emptied it between the count and the read): the
            # empty-FIFO word, as InvenSense parts return it
            return out + EMPTY_WORD * ((length - len(out)) // 2)
        if register == ToyReg.STATUS:
            count = (len(self.fifo) // SAMPLE).to_bytes(2, "little")
            return (bytes([self.regs[ToyReg.STATUS]]) + count)[:length]
        return bytes(self.regs[register : register + length])

    def write(self, register: int, data: bytes) -> None:
        self._advance()
        for i, v in enumerate(data):
            reg = register + i
            if reg == ToyReg.CTRL2 and v & Ctrl2.FIFO_FLUSH:
                self.fifo.clear()
                self.regs[ToyReg.STATUS] &= ~Status.OVERFLOW
                continue
            if reg == ToyReg.CTRL and v & Ctrl.ENABLE and not self.regs[ToyReg.CTRL] & 1:
                self.base += self.k
                self.origin, self.k = self.clock.now_ns(), 0
            self.regs[reg] = v

    def drain_truth(self) -> Truth | None:
        if not self.truth:
            return None
        rows, self.truth = self.truth, []
        index = np.array([i for i, _ in rows], dtype=np.int64)
        if np.any(np.diff(index) != 1):  # one run per drain: the rest waits for the next
            cut = int(np.flatnonzero(np.diff(index) != 1)[0]) + 1
            rows, self.truth = rows[:cut], rows[cut:]
        t = np.array([t for _, t in rows], dtype=np.int64)
        n = len(rows)
        gyro = np.tile([0.0, 0.0, math.radians(self.RATE_DPS)], (n, 1))
        return Truth(rows[0][0], t, {Channel.GYRO: gyro})


def _driver(cfg: ToyConfig, links: Sequence[Any], clock: Clock) -> Driver:
    (dev,) = links
    return ToyDriver(cfg, dev, clock)


def _sim(cfg: ToyConfig, clock: Clock) -> SimChip:
    return ToySim(cfg.sim or SimSettings(), clock)


SPEC = ChipSpec(
    name="toy",
    config_model=ToyConfig,
    make_driver=_driver,
    make_sim=_sim,
    transports=("spi",),
    channels=Channel.GYRO | Channel.MAG,
    dies=(Die("toy", spi_dummy_bytes=DUMMY),),
)
