"""The register interface chip drivers use, whatever the bus underneath (I2C or SPI)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:
    from imud.buses.models import Bus


@runtime_checkable
class RegisterDevice(Protocol):
    address: int

    def read(self, register: int, length: int) -> bytes: ...

    def read_u8(self, register: int) -> int: ...

    def write_u8(self, register: int, value: int) -> None: ...


def register_device(bus_cfg: Bus, transport: Any, spi_dummy_bytes: int = 0) -> RegisterDevice:
    """Wrap an open transport (an `smbus2.SMBus`-like or a `spidev.SpiDev`-like) for the device
    the bus config names: I2C at its address, or SPI on its chip select."""
    from imud.buses.i2c import I2CDevice
    from imud.buses.models import I2cBus, SimBus
    from imud.buses.spi import SpiDevice

    if bus_cfg.transport == "spi":
        return SpiDevice(transport, spi_dummy_bytes)
    assert isinstance(bus_cfg, I2cBus | SimBus)
    return I2CDevice(transport, bus_cfg.address)
