"""Chip registry. Adding a chip: one module here, its simulator in `imud.sim`, one line below."""

from __future__ import annotations

from typing import Any

from imud.chips.base import ChipSpec, Driver
from imud.clock import Clock


def _mpu6050_driver(cfg: Any, transport: Any, clock: Clock) -> Driver:
    from imud.buses.registers import register_device
    from imud.chips.mpu6050 import Mpu6050Driver

    return Mpu6050Driver(cfg, register_device(cfg.bus, transport), clock)


def _mpu6050_sim(cfg: Any, clock: Clock) -> Any:
    from imud.sim.mpu6050 import Mpu6050Sim

    return Mpu6050Sim(cfg.sim, clock)


def _icm42688p_driver(cfg: Any, transport: Any, clock: Clock) -> Driver:
    from imud.buses.registers import register_device
    from imud.chips.icm42688p import Icm42688pDriver

    return Icm42688pDriver(cfg, register_device(cfg.bus, transport), clock)


def _icm42688p_sim(cfg: Any, clock: Clock) -> Any:
    from imud.sim.icm42688p import Icm42688pSim

    return Icm42688pSim(cfg.sim, clock)


def _bmi088_driver(cfg: Any, transport: Any, clock: Clock) -> Driver:
    from imud.buses.registers import register_device
    from imud.chips.bmi088 import Bmi088Driver

    acc, gyr = transport  # one transport per die: the accel's, then the gyro's
    return Bmi088Driver(
        cfg,
        register_device(cfg.bus, acc, spi_dummy_bytes=1),  # the accel die's dummy byte
        register_device(cfg.gyro_bus, gyr),
        clock,
    )


def _bmi088_sim(cfg: Any, clock: Clock) -> Any:
    from imud.sim.bmi088 import Bmi088Sim

    return Bmi088Sim(cfg.sim, clock)


def _specs() -> dict[str, ChipSpec]:
    from imud.chips.bmi088 import Bmi088Config
    from imud.chips.icm42688p import Icm42688pConfig
    from imud.chips.mpu6050 import Mpu6050Config

    return {
        "mpu6050": ChipSpec("mpu6050", Mpu6050Config, _mpu6050_driver, _mpu6050_sim, ("i2c",)),
        "icm42688p": ChipSpec(
            "icm42688p", Icm42688pConfig, _icm42688p_driver, _icm42688p_sim, ("spi", "i2c")
        ),
        "bmi088": ChipSpec("bmi088", Bmi088Config, _bmi088_driver, _bmi088_sim, ("spi", "i2c")),
    }


CHIPS: dict[str, ChipSpec] = _specs()
