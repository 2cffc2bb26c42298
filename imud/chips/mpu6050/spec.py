"""The MPU6050's registry entry."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from imud.channels import Channel
from imud.chips.api import ChipSpec, Driver, NoiseFigures, register_links
from imud.chips.mpu6050.config import Mpu6050Config
from imud.chips.mpu6050.noise import noise_figures
from imud.clock import Clock
from imud.sim.api import SimChip

if TYPE_CHECKING:
    from imud.chips.api import Link


def _driver(cfg: Mpu6050Config, links: Sequence[Link], clock: Clock) -> Driver:
    from imud.chips.mpu6050.driver import Mpu6050Driver

    (dev,) = register_links(links)
    return Mpu6050Driver(cfg, dev, clock)


def _noise(cfg: Mpu6050Config) -> NoiseFigures:
    return noise_figures(cfg.dlpf_hz)


def _sim(cfg: Mpu6050Config, clock: Clock) -> SimChip:
    from imud.chips.mpu6050.sim import Mpu6050Sim
    from imud.sim.settings import SimSettings

    return Mpu6050Sim(cfg.sim or SimSettings(), clock)


SPEC = ChipSpec(
    name="mpu6050",
    config_model=Mpu6050Config,
    make_driver=_driver,
    make_sim=_sim,
    transports=("i2c",),
    channels=Channel.ACCEL | Channel.GYRO | Channel.TEMPERATURE,
    noise=_noise,
)
