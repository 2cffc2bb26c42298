"""The ADIS16465's registry entry: SPI only, with its own 16-bit framing (`raw_spi`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, cast

from imud.channels import Channel
from imud.chips.adis16465.config import Adis16465Config
from imud.chips.adis16465.noise import noise_figures
from imud.chips.api import ChipSpec, Driver, NoiseFigures
from imud.clock import Clock
from imud.sim.api import SimChip

if TYPE_CHECKING:
    from imud.buses.spi import SpiDevLike
    from imud.chips.api import Link


def _driver(cfg: Adis16465Config, links: Sequence[Link], clock: Clock) -> Driver:
    from imud.chips.adis16465.driver import Adis16465Driver

    (link,) = links
    if not callable(getattr(link, "xfer2", None)):
        raise TypeError("the ADIS16465 needs the raw SPI device (its spec sets raw_spi)")
    return Adis16465Driver(cfg, cast("SpiDevLike", link), clock)


def _noise(cfg: Adis16465Config) -> NoiseFigures:
    return noise_figures(cfg.model, cfg.filt_ctrl, cfg.dec_rate)


def _sim(cfg: Adis16465Config, clock: Clock) -> SimChip:
    from imud.chips.adis16465.sim import Adis16465Sim
    from imud.sim.settings import SimSettings

    return Adis16465Sim(cfg.sim or SimSettings(), clock, model=cfg.model)


SPEC = ChipSpec(
    name="adis16465",
    config_model=Adis16465Config,
    make_driver=_driver,
    make_sim=_sim,
    transports=("spi",),
    channels=(
        Channel.ACCEL
        | Channel.GYRO
        | Channel.TEMPERATURE
        | Channel.DELTA_ANGLE
        | Channel.DELTA_VELOCITY
    ),
    raw_spi=True,
    counters=("checksum_errors",),  # bursts whose checksum failed (of garbled_transfers)
    noise=_noise,
    grade="industrial",  # ADIS16465: 2 deg/h in-run bias stability (datasheet)
)
