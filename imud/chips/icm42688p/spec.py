"""The ICM-42688-P's registry entry."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from imud.channels import Channel
from imud.chips.api import ChipSpec, Driver, NoiseFigures, register_links
from imud.chips.icm42688p.config import Icm42688pConfig
from imud.chips.icm42688p.noise import noise_figures
from imud.clock import Clock
from imud.sim.api import SimChip

if TYPE_CHECKING:
    from imud.chips.api import Link


def _driver(cfg: Icm42688pConfig, links: Sequence[Link], clock: Clock) -> Driver:
    from imud.chips.icm42688p.driver import Icm42688pDriver

    (dev,) = register_links(links)
    return Icm42688pDriver(cfg, dev, clock)


def _noise(cfg: Icm42688pConfig) -> NoiseFigures:
    return noise_figures(cfg.odr_hz, cfg.ui_filter)


def _sim(cfg: Icm42688pConfig, clock: Clock) -> SimChip:
    from imud.chips.icm42688p.sim import Icm42688pSim
    from imud.sim.settings import SimSettings

    return Icm42688pSim(cfg.sim or SimSettings(), clock)


SPEC = ChipSpec(
    name="icm42688p",
    config_model=Icm42688pConfig,
    make_driver=_driver,
    make_sim=_sim,
    transports=("spi", "i2c"),
    channels=Channel.ACCEL | Channel.GYRO | Channel.TEMPERATURE,
    noise=_noise,
)
