"""The BMI088's registry entry: two dies, the accel's SPI reads led by one dummy byte."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from imud.channels import Channel
from imud.chips.api import ChipSpec, Die, Driver, NoiseFigures, register_links
from imud.chips.bmi088.config import GYRO, Bmi088Config
from imud.chips.bmi088.noise import noise_figures
from imud.clock import Clock
from imud.sim.api import SimChip

if TYPE_CHECKING:
    from imud.chips.api import Link


def _driver(cfg: Bmi088Config, links: Sequence[Link], clock: Clock) -> Driver:
    from imud.chips.bmi088.driver import Bmi088Driver

    acc, gyr = register_links(links)
    return Bmi088Driver(cfg, acc, gyr, clock)


def _noise(cfg: Bmi088Config) -> NoiseFigures:
    assert cfg.gyro_filter_hz is not None  # the config's validator sets its default
    return noise_figures(cfg.gyro_filter_hz, cfg.accel_odr_hz)


def _sim(cfg: Bmi088Config, clock: Clock) -> SimChip:
    from imud.chips.bmi088.sim import Bmi088Sim
    from imud.sim.settings import SimSettings

    return Bmi088Sim(cfg.sim or SimSettings(), clock)


SPEC = ChipSpec(
    name="bmi088",
    config_model=Bmi088Config,
    make_driver=_driver,
    make_sim=_sim,
    transports=("spi", "i2c"),
    channels=Channel.ACCEL | Channel.GYRO | Channel.TEMPERATURE,
    dies=(Die("accel", spi_dummy_bytes=1), Die("gyro")),
    # each die on its oscillator: the stream runs at the gyro's times, the accel interpolated
    die_periods=lambda c: (1e9 / c.accel_odr_hz, 1e9 / c.odr_hz),
    time_base=GYRO,
    noise=_noise,
)
