"""The structure's proof: a chip defined entirely in this file (register map, config model,
driver, register-level simulator, registry entry added at run time) streams through the real
wiring and the real daemon to a Zenoh subscriber, with no imud module changed for it.

The toy is a gyro + magnetometer on SPI that clocks out two dummy bytes before read data and
produces a channel none of the shipped chips has (the magnetic field): the generic code must
take the die layout, the dummy bytes, the published rate and the channels from its spec.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterator, Sequence
from enum import IntEnum, IntFlag
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest

import imud.client as ic
from imud import registry
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
from imud.chips.regplan import RegisterPlan, RegisterSetting
from imud.clock import Clock
from imud.config import load_config
from imud.daemon import Daemon
from imud.errors import DeviceIdentityError
from imud.sim.api import SimChip, SimDie, Truth
from tests.helpers import free_port, run_in_process


# --- the toy chip's register map -----------------------------------------------------------------
class ToyReg(IntEnum):
    WHO_AM_I = 0x0F
    CTRL = 0x10
    FIFO_COUNT = 0x20  # u16 little-endian, whole samples
    FIFO_DATA = 0x22


class Ctrl(IntFlag):
    ENABLE = 0x01


CTRL_RATE = BitField(0x0E)  # [3:1]: 0 = 100 Hz, 1 = 200 Hz, 2 = 400 Hz
TOY_ID = 0x5A
TOY_RATES = (100, 200, 400)
DUMMY = 2
SAMPLE = 12  # gyro xyz then mag xyz, int16 big-endian
GYRO_LSB_DPS = 0.01  # 100 LSB per deg/s
MAG_LSB_T = 1e-8  # 10 nT per LSB
FIFO_SAMPLES = 64


# --- config model --------------------------------------------------------------------------------
class ToyConfig(DeviceBase):
    chip: Literal["toy"]
    odr_hz: Literal[100, 200, 400] = 200


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
        self.reads = 0

    def start(self) -> Iterator[int]:
        who = self.dev.read_u8(ToyReg.WHO_AM_I)
        if who != TOY_ID:
            raise DeviceIdentityError(f"toy WHO_AM_I reads 0x{who:02x}")
        self.plan.write_all()
        yield 1_000_000

    def read(self) -> RawBatch:
        tb = self.clock.now_ns()
        n = int.from_bytes(self.dev.read(ToyReg.FIFO_COUNT, 2), "little")
        ta = self.clock.now_ns()
        self.reads += 1
        words = np.frombuffer(self.dev.read(ToyReg.FIFO_DATA, n * SAMPLE), ">i2").reshape(n, 6)
        return RawBatch(
            n,
            {
                Channel.GYRO: RawChannel(words[:, :3], math.radians(GYRO_LSB_DPS), 32767),
                Channel.MAG: RawChannel(words[:, 3:], MAG_LSB_T, 32767),
            },
            FifoRead(tb, ta),
        )

    def stop(self) -> None:
        self.dev.write_u8(ToyReg.CTRL, 0)

    def chip_status(self) -> dict[str, Any]:
        return {"reads": self.reads}


# --- register-level simulator --------------------------------------------------------------------
class ToySim:
    """Turns at 30 deg/s about z in a 50 uT field along x; its clock runs 1 % fast."""

    RATE_DPS = 30.0
    FIELD_T = 50e-6

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.regs = bytearray(256)
        self.regs[ToyReg.WHO_AM_I] = TOY_ID
        self.fifo = bytearray()
        self.origin = clock.now_ns()
        self.k = 0  # samples produced since enabled
        self.truth: list[tuple[int, int]] = []

    @property
    def dies(self) -> Sequence[SimDie]:
        return (self,)

    def spi_select(self) -> bool:
        return True

    def _advance(self) -> None:
        if not self.regs[ToyReg.CTRL] & Ctrl.ENABLE:
            return
        period = 1e9 / (TOY_RATES[(self.regs[ToyReg.CTRL] >> 1) & 7] * 1.01)
        due = int((self.clock.now_ns() - self.origin) // period)
        for k in range(self.k + 1, due + 1):
            t_s = k * period / 1e9
            yaw = math.radians(self.RATE_DPS) * t_s  # the field turns the other way in the body
            mag = (self.FIELD_T * math.cos(yaw), -self.FIELD_T * math.sin(yaw), 0.0)
            gyro = (0.0, 0.0, self.RATE_DPS)
            counts = [round(g / GYRO_LSB_DPS) for g in gyro] + [round(m / MAG_LSB_T) for m in mag]
            if len(self.fifo) < FIFO_SAMPLES * SAMPLE:
                self.fifo += np.array(counts, dtype=">i2").tobytes()
        self.k = max(self.k, due)

    def read(self, register: int, length: int) -> bytes:
        self._advance()
        if register == ToyReg.FIFO_DATA:
            out = bytes(self.fifo[:length])
            del self.fifo[:length]
            return out.ljust(length, b"\0")
        if register == ToyReg.FIFO_COUNT:
            return (len(self.fifo) // SAMPLE).to_bytes(2, "little")[:length]
        return bytes(self.regs[register : register + length])

    def write(self, register: int, data: bytes) -> None:
        self._advance()
        for i, v in enumerate(data):
            if register + i == ToyReg.CTRL and v & Ctrl.ENABLE and not self.regs[ToyReg.CTRL] & 1:
                self.origin, self.k = self.clock.now_ns(), 0
            self.regs[register + i] = v

    def drain_truth(self) -> Truth | None:
        return None


def _driver(cfg: ToyConfig, links: Sequence[RegisterDevice], clock: Clock) -> Driver:
    (dev,) = links
    return ToyDriver(cfg, dev, clock)


def _sim(cfg: ToyConfig, clock: Clock) -> SimChip:
    return ToySim(clock)


TOY = ChipSpec(
    name="toy",
    config_model=ToyConfig,
    make_driver=_driver,
    make_sim=_sim,
    transports=("spi",),
    channels=Channel.GYRO | Channel.MAG,
    dies=(Die("toy", spi_dummy_bytes=DUMMY),),
)


@pytest.fixture
def toy_registered() -> Iterator[None]:
    registry.register(TOY)
    try:
        yield
    finally:
        registry.unregister("toy")


def test_toy_chip_streams_through_the_real_daemon(tmp_path: Path, toy_registered: None) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    path = tmp_path / "toy.toml"
    path.write_text(
        f'[daemon]\nbus_processes = false\n[zenoh]\nlisten = ["{endpoint}"]\n'
        '[[device]]\nname = "toy0"\nchip = "toy"\nodr_hz = 400\n'
        'bus = { kind = "sim", bus = "spiT", transport = "spi", cs = 0 }\n'
    )
    cfg = load_config(path)  # the loader knows the toy: it was registered at run time
    daemon = Daemon(cfg)
    got: list[ic.Batch] = []
    status: dict[str, Any] = {}
    failure: list[BaseException] = []

    def subscriber() -> None:
        try:
            end = time.monotonic() + 30
            while time.monotonic() < end:  # the daemon opens its listener first
                try:
                    s = ic.open_session(endpoint)
                    break
                except ic.NoDaemon:
                    time.sleep(0.1)
            with s:
                for b in ic.batches(s, "toy0", timeout=10.0):
                    got.append(b)
                    if sum(x.count for x in got) >= 400:
                        break
                status.update(ic.get_status(s, device="toy0"))
        except BaseException as e:  # reported by the test body
            failure.append(e)
        finally:
            daemon.request_stop()

    run_in_process(daemon, subscriber)
    assert not failure, failure
    assert sum(b.count for b in got) >= 400
    for prev, b in itertools.pairwise(got):  # continuous, or every gap counted
        assert b.first_seq - (prev.first_seq + prev.count) == b.lost_before
    gyro = np.concatenate([b.channels[Channel.GYRO] for b in got])
    mag = np.concatenate([b.channels[Channel.MAG] for b in got])
    assert set(got[0].channels) == {Channel.GYRO, Channel.MAG}  # what its spec declares
    assert gyro[:, 2] == pytest.approx(math.radians(30.0), abs=1e-6)  # rad/s, scaled by the spec
    assert np.linalg.norm(mag, axis=1) == pytest.approx(50e-6, rel=1e-3)  # tesla
    t_ns = np.concatenate([b.t_ns for b in got])
    assert np.all(np.diff(t_ns) > 0)
    assert status["odr_hz"] == 400 and status["channels"] == ["gyro", "mag"]
    assert status["chip_status"]["reads"] > 0 and status["state"] == "running"
    assert status["chip_rate_hz"] == pytest.approx(404, rel=5e-3)  # its clock runs 1 % fast
