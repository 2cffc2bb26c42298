"""The STIM300's registry entry: one unit on a serial (RS422) link."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from imud.channels import Channel
from imud.chips.api import ChipSpec, Driver, NoiseFigures
from imud.chips.stim300.config import Stim300Config
from imud.chips.stim300.noise import noise_figures
from imud.clock import Clock
from imud.sim.api import SimChip

if TYPE_CHECKING:
    from imud.chips.api import Link


def _driver(cfg: Stim300Config, links: Sequence[Link], clock: Clock) -> Driver:
    from imud.buses.serial import SerialPort
    from imud.chips.stim300.driver import Stim300Driver

    (port,) = links
    if not isinstance(port, SerialPort):
        raise TypeError("the STIM300 needs a serial link")
    return Stim300Driver(cfg, port, clock)


def _noise(cfg: Stim300Config) -> NoiseFigures:
    return noise_figures(cfg.filter_hz, cfg.accel_range_g)


def _sim(cfg: Stim300Config, clock: Clock) -> SimChip:
    from imud.buses.models import SimBus
    from imud.chips.stim300.sim import Stim300Sim
    from imud.sim.settings import SimSettings

    assert isinstance(cfg.bus, SimBus)
    return Stim300Sim(
        cfg.sim or SimSettings(),
        clock,
        datagram=int(cfg.datagram_id),
        odr_hz=int(cfg.odr_hz),
        accel_range_g=cfg.accel_range_g,
        baud=cfg.bus.baud,
        line_termination=cfg.line_termination,
        filter_hz=cfg.filter_hz,
    )


SPEC = ChipSpec(
    name="stim300",
    config_model=Stim300Config,
    make_driver=_driver,
    make_sim=_sim,
    transports=("serial",),
    channels=Channel.ACCEL | Channel.GYRO | Channel.TEMPERATURE | Channel.INCLINATION,
    counters=("crc_errors",),  # datagrams whose CRC failed (of garbled_transfers)
    noise=_noise,
    grade="tactical",  # STIM300: 0.3-0.5 deg/h gyro bias instability (datasheet)
)
