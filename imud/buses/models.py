"""The `bus` table of a device: where the chip is wired (or that it is simulated)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class I2cBus(_Strict):
    kind: Literal["i2c"]
    bus: int | str = Field(description="bus number (1 for /dev/i2c-1) or device path")
    address: int = Field(ge=0x03, le=0x77, description="7-bit I2C address")
    speed_hz: int = Field(400_000, gt=0, description="bus clock, used to check rates")

    @property
    def key(self) -> str:
        return self.bus if isinstance(self.bus, str) else f"/dev/i2c-{self.bus}"


class SpiBus(_Strict):
    kind: Literal["spi"]
    path: str = Field(pattern=r"^/dev/spidev\d+\.\d+$")
    mode: int = Field(3, ge=0, le=3)
    speed_hz: int = Field(1_000_000, gt=0)

    @property
    def key(self) -> str:
        return self.path


class SerialBus(_Strict):
    kind: Literal["serial"]
    port: str
    baud: int = Field(115_200, gt=0)

    @property
    def key(self) -> str:
        return self.port


class SimBus(_Strict):
    """A simulated I2C bus: devices naming the same `bus` share it (and its worker thread)."""

    kind: Literal["sim"]
    bus: str = "sim0"
    address: int = Field(0x68, ge=0x03, le=0x77)
    speed_hz: int = Field(400_000, gt=0)

    @property
    def key(self) -> str:
        return f"sim:{self.bus}"


Bus = Annotated[I2cBus | SpiBus | SerialBus | SimBus, Field(discriminator="kind")]


def describe(bus: I2cBus | SpiBus | SerialBus | SimBus) -> str:
    """Short human form for status tables and logs."""
    if isinstance(bus, I2cBus | SimBus):
        return f"{bus.kind}:{bus.key.removeprefix('sim:')}@0x{bus.address:02x}"
    return f"{bus.kind}:{bus.key}"
