"""The `[[device]]` table of a BMI088: two dies (`bus` the accel, `gyro_bus` the gyro) on one
physical bus, their ranges, rates and filters, and what an I2C bus can carry."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, ValidationInfo, field_validator, model_validator

from imud.buses import budget
from imud.buses.models import Bus
from imud.chips.api import DeviceBase
from imud.chips.bmi088.registers import (
    ACCEL_ODR_CODES,
    GYRO_BANDWIDTH_CODES,
    MAX_SPI_HZ,
)

ACCEL, GYRO = 0, 1  # the dies, in the order of the spec's `dies` (`RawBatch.die`)


def gyro_modes_for(odr: float) -> list[int]:
    return [bw for code, (o, bw) in GYRO_BANDWIDTH_CODES.items() if o == odr]


def fifo_bytes_per_second(accel_odr: float, gyro_odr: float) -> float:
    """What both FIFO streams move over the bus: 7-byte accel frames, 6-byte gyro frames."""
    return accel_odr * 7 + gyro_odr * 6


class Bmi088Config(DeviceBase):
    """A BMI088: `bus` is the accel die, `gyro_bus` the gyro die, on the same physical bus.

    Published at the gyro's rate; the accel is interpolated onto the gyro's sample times."""

    chip: Literal["bmi088"]
    gyro_bus: Bus = Field(description="the gyro die: its own chip select or I2C address")
    accel_range_g: Literal[3, 6, 12, 24] = 24
    accel_odr_hz: float = Field(1600, description="12.5, 25, 50, 100, 200, 400, 800, 1600")
    accel_filter: Literal["normal", "osr2", "osr4"] = Field(
        "normal", description="normal, or 2x / 4x oversampling (lower bandwidth)"
    )
    gyro_range_dps: Literal[125, 250, 500, 1000, 2000] = 2000
    odr_hz: Literal[100, 200, 400, 1000, 2000] = Field(
        2000, description="the gyro's output data rate: the published rate"
    )
    gyro_filter_hz: int | None = Field(
        None, description="2000 Hz: 532 or 230; 1000: 116; 400: 47; 200: 23 or 64; 100: 12 or 32"
    )

    def die_buses(self) -> list[Bus]:
        return [self.bus, self.gyro_bus]

    @field_validator("accel_odr_hz")
    @classmethod
    def _accel_odr(cls, v: float) -> float:
        if float(v) not in ACCEL_ODR_CODES:
            allowed = ", ".join(f"{a:g}" for a in ACCEL_ODR_CODES)
            raise ValueError(f"the BMI088 accel has no output data rate {v:g} Hz; use {allowed}")
        return float(v)

    @field_validator("gyro_bus")
    @classmethod
    def _same_bus(cls, v: Bus, info: ValidationInfo) -> Bus:
        acc: Bus | None = info.data.get("bus")
        if acc is None or "serial" in (v.transport, acc.transport):
            return v  # the device check says which buses the chip takes
        if type(v) is not type(acc) or v.key != acc.key:
            raise ValueError(
                f"the gyro die must be on the accel die's bus ({acc.kind} {acc.key}): the "
                "driver talks to both from one worker; give the gyro its own chip select "
                "(SPI) or address (I2C) on that bus"
            )
        if v.transport != acc.transport:
            raise ValueError("both dies need the same transport (i2c or spi)")
        if v.slot == acc.slot:
            where = "chip select" if is_spi(v) else "address"
            raise ValueError(
                f"the gyro die needs its own {where}: it is the accel die's ({' '.join(v.slot)})"
            )
        return v

    @model_validator(mode="after")
    def _filters_and_bus(self) -> Bmi088Config:
        odr = float(self.odr_hz)
        modes = gyro_modes_for(odr)
        if self.gyro_filter_hz is None:
            self.gyro_filter_hz = max(modes)
        elif self.gyro_filter_hz not in modes:
            listed = " or ".join(str(m) for m in modes)
            raise ValueError(
                f"gyro_filter_hz = {self.gyro_filter_hz}: at odr_hz = {odr:g} the BMI088 "
                f"gyro filters at {listed} Hz"
            )
        for field, b in (("bus", self.bus), ("gyro_bus", self.gyro_bus)):
            if b.transport == "spi" and b.clock_hz > MAX_SPI_HZ:
                raise ValueError(
                    f"the BMI088's SPI runs at most at 10 MHz; {field}.speed_hz is "
                    f"{b.clock_hz / 1e6:g} MHz"
                )
        if self.bus.transport == "i2c":  # one I2C bus: the slower setting is the truth
            why = budget.problem(
                "i2c",
                min(self.bus.clock_hz, self.gyro_bus.clock_hz),
                fifo_bytes_per_second(self.accel_odr_hz, odr),
                f"accel {self.accel_odr_hz:g} Hz + gyro {odr:g} Hz of 7- and 6-byte FIFO frames",
                "lower the rates or use 400 kHz I2C or SPI",
            )
            if why:
                raise ValueError(why)
        return self

    def gyro_bandwidth_code(self) -> int:
        for code, mode in GYRO_BANDWIDTH_CODES.items():
            if mode == (float(self.odr_hz), self.gyro_filter_hz):
                return code
        raise AssertionError("validated above")


def is_spi(bus: Bus) -> bool:
    return bus.transport == "spi"
