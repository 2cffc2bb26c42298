"""Chip registry. Adding a chip: one module here, its simulator in `imud.sim`, one line below."""

from __future__ import annotations

from typing import Any

from imud.chips.base import ChipSpec, Driver
from imud.clock import Clock


def _mpu6050_driver(cfg: Any, bus: Any, clock: Clock) -> Driver:
    from imud.buses.i2c import I2CDevice
    from imud.chips.mpu6050 import Mpu6050Driver

    return Mpu6050Driver(cfg, I2CDevice(bus, cfg.bus.address), clock)


def _mpu6050_sim(cfg: Any, clock: Clock) -> Any:
    from imud.sim.mpu6050 import Mpu6050Sim

    return Mpu6050Sim(cfg.sim, clock)


def _specs() -> dict[str, ChipSpec]:
    from imud.chips.mpu6050 import Mpu6050Config

    return {
        "mpu6050": ChipSpec("mpu6050", Mpu6050Config, _mpu6050_driver, _mpu6050_sim, ("i2c",)),
    }


CHIPS: dict[str, ChipSpec] = _specs()
