"""The `[[device]]` table of an ICM-42688-P: ranges, rate, filters, and what the bus can carry."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, ValidationInfo, field_validator

from imud.buses import budget
from imud.buses.models import Bus
from imud.chips.api import DeviceBase
from imud.chips.icm42688p.registers import (
    AAF_DEFAULT_ACCEL_HZ,
    AAF_DEFAULT_GYRO_HZ,
    AAF_TABLE,
    GYRO_RANGES_DPS,
    MAX_SPI_HZ,
    ODR_CODES,
    PACKET3_BYTES,
    PACKET4_BYTES,
)

UiFilter = Literal[
    "odr/2", "odr/4", "odr/5", "odr/8", "odr/10", "odr/16", "odr/20", "odr/40",
    "low_latency", "low_latency_8x",
]  # fmt: skip


def fifo_bytes_per_second(odr_hz: float, hires: bool) -> float:
    """What the FIFO stream moves over the bus at this rate."""
    return odr_hz * (PACKET4_BYTES if hires else PACKET3_BYTES)


def _one_of(v: float, allowed: tuple[float, ...], what: str) -> float:
    if float(v) not in allowed:
        listed = ", ".join(f"{a:g}" for a in sorted(allowed))
        raise ValueError(f"the ICM-42688-P has no {what} {v:g}; allowed: {listed}")
    return float(v)


def _aaf(v: int | str, default: int) -> int | str:
    if v == "off" or v in AAF_TABLE:
        return v
    near = min(AAF_TABLE, key=lambda b: abs(b - float(v)))
    raise ValueError(
        f"no anti-alias filter row for {v!r} Hz: pick one of the datasheet's 63 bandwidths "
        f'(42 ... 3979 Hz; nearest {near}), or "off"; the chip\'s default is {default}'
    )


class Icm42688pConfig(DeviceBase):
    """An ICM-42688-P. Gyro and accel run in low-noise mode at the same `odr_hz`."""

    chip: Literal["icm42688p"]
    gyro_range_dps: float = Field(2000, description="15.625, 31.25, 62.5, 125 ... 2000")
    accel_range_g: Literal[2, 4, 8, 16] = 16
    hires: bool = Field(False, description="20-bit FIFO packets; needs 2000 deg/s and 16 g")
    ui_filter: UiFilter = Field("odr/4", description="gyro and accel UI filter bandwidth")
    gyro_aaf_hz: int | Literal["off"] = Field(AAF_DEFAULT_GYRO_HZ, description="anti-alias 3 dB")
    accel_aaf_hz: int | Literal["off"] = Field(AAF_DEFAULT_ACCEL_HZ, description="anti-alias")
    odr_hz: float = Field(
        1000,
        validate_default=True,  # the bus checks below must run for the default rate too
        description="12.5, 25, 50, 100, 200, 500, 1000 ... 32000",
    )

    @field_validator("gyro_range_dps")
    @classmethod
    def _gyro_range(cls, v: float) -> float:
        return _one_of(v, GYRO_RANGES_DPS, "gyro range (deg/s)")

    @field_validator("gyro_aaf_hz")
    @classmethod
    def _gyro_aaf(cls, v: int | str) -> int | str:
        return _aaf(v, AAF_DEFAULT_GYRO_HZ)

    @field_validator("accel_aaf_hz")
    @classmethod
    def _accel_aaf(cls, v: int | str) -> int | str:
        return _aaf(v, AAF_DEFAULT_ACCEL_HZ)

    @field_validator("odr_hz")
    @classmethod
    def _bus_can_carry(cls, v: float, info: ValidationInfo) -> float:
        v = _one_of(v, tuple(ODR_CODES), "output data rate (Hz)")
        bus: Bus | None = info.data.get("bus")
        if bus is None or bus.transport == "serial":
            return v  # the bus failed its own checks, or the config's transport check says
        hires = bool(info.data.get("hires"))
        speed, i2c = bus.clock_hz, bus.transport == "i2c"
        if not i2c and speed > MAX_SPI_HZ:
            raise ValueError(
                f"the ICM-42688-P's SPI runs at most at 24 MHz; bus.speed_hz is {speed / 1e6:g} MHz"
            )
        size = PACKET4_BYTES if hires else PACKET3_BYTES
        best = max(
            (
                r
                for r in ODR_CODES
                if budget.bits_per_second(bus.transport, fifo_bytes_per_second(r, hires)) <= speed
            ),
            default=0,
        )
        why = budget.problem(
            bus.transport,
            speed,
            fifo_bytes_per_second(v, hires),
            f"{v:g} Hz of {size}-byte FIFO packets",
            f"use {'SPI or ' if i2c else 'a faster clock or '}at most {best:g} Hz",
        )
        if why:
            raise ValueError(why)
        return v

    @field_validator("hires")
    @classmethod
    def _hires_ranges(cls, v: bool, info: ValidationInfo) -> bool:
        g, a = info.data.get("gyro_range_dps"), info.data.get("accel_range_g")
        if v and (g != 2000 or a != 16):
            raise ValueError(
                "20-bit FIFO packets only work at gyro_range_dps = 2000 and accel_range_g = 16 "
                f"(configured: {g} and {a}); set hires = false or use those ranges"
            )
        return v
