"""The BNO055's registry entry: I2C (a `RegisterDevice`) or its UART (a `SerialPort`, wrapped in
the BNO055 UART register protocol), either way the same driver."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from imud.buses.registers import RegisterDevice
from imud.channels import Channel
from imud.chips.api import ChipSpec, Driver, DriverCounters, NoiseFigures
from imud.chips.bno055.config import Bno055Config
from imud.chips.bno055.noise import noise_figures
from imud.clock import Clock
from imud.sim.api import SimChip

if TYPE_CHECKING:
    from imud.chips.api import Link


def _driver(cfg: Bno055Config, links: Sequence[Link], clock: Clock) -> Driver:
    from imud.chips.bno055.driver import Bno055Driver
    from imud.chips.bno055.uart import Bno055Uart

    (link,) = links
    if isinstance(link, RegisterDevice):
        return Bno055Driver(cfg, link, clock)
    counters = DriverCounters()
    uart = Bno055Uart(link, clock, counters)  # type: ignore[arg-type]
    return Bno055Driver(cfg, uart, clock, uart=uart, counters=counters)


def _noise(cfg: Bno055Config) -> NoiseFigures:
    return noise_figures()  # the same in every mode (noise.py)


def _sim(cfg: Bno055Config, clock: Clock) -> SimChip:
    from imud.chips.bno055.sim import Bno055Sim
    from imud.sim.settings import SimSettings

    bus = cfg.bus
    baud = bus.clock_hz if bus.transport == "serial" else None
    return Bno055Sim(cfg.sim or SimSettings(), clock, serial_baud=baud)


SPEC = ChipSpec(
    name="bno055",
    config_model=Bno055Config,
    make_driver=_driver,
    make_sim=_sim,
    transports=("i2c", "serial"),
    channels=Channel.ORIENTATION
    | Channel.LINEAR_ACCEL
    | Channel.GRAVITY
    | Channel.GYRO
    | Channel.ACCEL
    | Channel.MAG
    | Channel.TEMPERATURE,
    noise=_noise,
)
