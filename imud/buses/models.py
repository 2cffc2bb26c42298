"""The `bus` table of a device: where the chip is wired (or that it is simulated).

Every kind says in common what it is to a chip: its `transport` ("i2c", "spi" or "serial": a
simulated bus is one of these too) and its `clock_hz` (the I2C or SPI clock, the serial bit
rate), which the config's rate checks use (`imud.buses.budget`).
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field

Transport = Literal["i2c", "spi", "serial"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")

    simulated: ClassVar[bool] = False  # a simulator stands behind it (SimBus)


class I2cBus(_Strict):
    kind: Literal["i2c"]
    bus: int | str = Field(description="bus number (1 for /dev/i2c-1) or device path")
    address: int = Field(ge=0x03, le=0x77, description="7-bit I2C address")
    speed_hz: int = Field(400_000, gt=0, description="bus clock, used to check rates")

    @property
    def transport(self) -> Transport:
        return "i2c"

    @property
    def clock_hz(self) -> int:
        return self.speed_hz

    @property
    def key(self) -> str:
        return self.bus if isinstance(self.bus, str) else f"/dev/i2c-{self.bus}"

    @property
    def slot(self) -> tuple[str, ...]:
        return (self.key, f"0x{self.address:02x}")


class SpiBus(_Strict):
    kind: Literal["spi"]
    path: str = Field(pattern=r"^/dev/spidev\d+\.\d+$")
    mode: int = Field(3, ge=0, le=3)
    speed_hz: int = Field(1_000_000, gt=0)

    @property
    def transport(self) -> Transport:
        return "spi"

    @property
    def clock_hz(self) -> int:
        return self.speed_hz

    @property
    def key(self) -> str:
        """The bus, not the chip select: /dev/spidev0.0 and /dev/spidev0.1 share one worker."""
        return self.path.rsplit(".", 1)[0]

    @property
    def slot(self) -> tuple[str, ...]:
        return (self.path,)


class SerialBus(_Strict):
    """A UART or RS422 link (through a USB adapter or the board's own UART), 8N1."""

    kind: Literal["serial"]
    port: str = Field(description="device path, e.g. /dev/ttyUSB0 or /dev/serial/by-id/...")
    baud: int = Field(115_200, gt=0)

    @property
    def transport(self) -> Transport:
        return "serial"

    @property
    def clock_hz(self) -> int:
        return self.baud

    @property
    def key(self) -> str:
        return self.port

    @property
    def slot(self) -> tuple[str, ...]:
        return (self.port,)


class SimBus(_Strict):
    """A simulated bus: devices naming the same `bus` share it (and its worker thread).

    `transport = "i2c"` puts the chip at `address`; `"spi"` on chip select `cs`; `"serial"`
    behind a pseudo-terminal of its own at `baud`. `speed_hz` (I2C, SPI) and `baud` (serial)
    are what the config checks rates against, as for a real bus."""

    simulated: ClassVar[bool] = True
    kind: Literal["sim"]
    bus: str = "sim0"
    transport: Transport = "i2c"
    address: int = Field(0x68, ge=0x03, le=0x77)
    cs: int = Field(0, ge=0, le=15)
    speed_hz: int | None = Field(None, gt=0, description="default: 400 kHz I2C, 10 MHz SPI")
    baud: int = Field(115_200, gt=0, description="serial only: the link's bit rate")

    @property
    def key(self) -> str:
        return f"sim:{self.bus}"

    @property
    def clock_hz(self) -> int:
        if self.transport == "serial":
            return self.baud
        return self.speed_hz or (400_000 if self.transport == "i2c" else 10_000_000)

    @property
    def slot(self) -> tuple[str, ...]:
        if self.transport == "spi":
            return (self.key, f"cs{self.cs}")
        if self.transport == "serial":
            return (self.key, "serial")
        return (self.key, f"0x{self.address:02x}")


Bus = Annotated[I2cBus | SpiBus | SerialBus | SimBus, Field(discriminator="kind")]


def describe(bus: I2cBus | SpiBus | SerialBus | SimBus) -> str:
    """Short human form for status tables and logs."""
    if isinstance(bus, SimBus):
        where = {"spi": f"cs{bus.cs}", "serial": f"{bus.baud}bd"}.get(
            bus.transport, f"0x{bus.address:02x}"
        )
        return f"sim-{bus.transport}:{bus.bus}@{where}"
    if isinstance(bus, I2cBus):
        return f"i2c:{bus.key}@0x{bus.address:02x}"
    if isinstance(bus, SpiBus):
        return f"spi:{bus.path}"
    return f"serial:{bus.port}@{bus.baud}bd"
