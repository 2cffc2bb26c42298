"""I2C register access over the `smbus2.SMBus` method subset, the same on silicon and simulator."""

from __future__ import annotations

from typing import Any, Protocol

from smbus2 import i2c_msg

from imud.buses.models import I2cBus
from imud.errors import BusError, open_error

SMBUS_BLOCK_MAX = 32


class SMBusLike(Protocol):
    """The methods of `smbus2.SMBus` drivers may call; `imud.sim.i2c.SimI2CBus` implements them."""

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int: ...

    def write_byte_data(
        self, i2c_addr: int, register: int, value: int, force: bool | None = None
    ) -> None: ...

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]: ...

    def i2c_rdwr(self, *i2c_msgs: Any) -> None: ...

    def close(self) -> None: ...


class I2CDevice:
    """One chip on an I2C bus: byte registers and long burst reads. Errors become `BusError`."""

    def __init__(self, bus: SMBusLike, address: int) -> None:
        self.bus = bus
        self.address = address

    def read_u8(self, register: int) -> int:
        try:
            return self.bus.read_byte_data(self.address, register)
        except OSError as e:
            raise BusError(e.errno, f"read 0x{register:02x} @0x{self.address:02x}: {e}") from e

    def write_u8(self, register: int, value: int) -> None:
        try:
            self.bus.write_byte_data(self.address, register, value & 0xFF)
        except OSError as e:
            raise BusError(e.errno, f"write 0x{register:02x} @0x{self.address:02x}: {e}") from e

    def read(self, register: int, length: int) -> bytes:
        """Burst read; past the 32-byte SMBus block limit it is one combined i2c_rdwr transfer."""
        try:
            if length <= SMBUS_BLOCK_MAX:
                return bytes(self.bus.read_i2c_block_data(self.address, register, length))
            wr = i2c_msg.write(self.address, [register])
            rd = i2c_msg.read(self.address, length)
            self.bus.i2c_rdwr(wr, rd)
            return bytes(rd)
        except OSError as e:
            raise BusError(
                e.errno, f"read {length} B from 0x{register:02x} @0x{self.address:02x}: {e}"
            ) from e


def open_smbus(cfg: I2cBus) -> SMBusLike:
    """Open the Linux i2c-dev node named by the config."""
    from smbus2 import SMBus

    try:
        bus: SMBusLike = SMBus(cfg.bus)
    except (FileNotFoundError, PermissionError) as e:
        enable = "enable I2C (dtparam=i2c_arm=on) and load i2c-dev"
        raise open_error(cfg.key, e, enable, "i2c") from e
    return bus
