"""SPI register access over the `spidev.SpiDev` method subset, the same on silicon and simulator.

InvenSense and Bosch chips share the convention: the first byte is the register address with bit 7
set for a read; the chip answers from the second byte on (Bosch accelerometers send one dummy byte
first, hence `dummy_bytes`). `spidev` is Linux-only and imported only when a real SPI bus opens.
"""

from __future__ import annotations

from typing import Protocol

from imud.buses.models import SpiBus
from imud.errors import BusError, open_error

READ = 0x80
MAX_TRANSFER = 4096  # spidev's default buffer size (module parameter bufsiz)


class SpiDevLike(Protocol):
    """What drivers may call on a `spidev.SpiDev`; `imud.sim.spi.SimSpiDev` implements it."""

    mode: int
    max_speed_hz: int

    def xfer2(
        self, values: list[int], speed_hz: int = 0, delay_usecs: int = 0, bits_per_word: int = 0
    ) -> list[int]:
        """One chip-select frame; `speed_hz` 0 = `max_speed_hz`; `delay_usecs` before the chip
        select rises."""

    def close(self) -> None: ...


class SpiDevice:
    """One chip on one chip select: byte registers and burst reads. Errors become `BusError`."""

    def __init__(self, spi: SpiDevLike, dummy_bytes: int = 0) -> None:
        self.spi = spi
        self.dummy = dummy_bytes
        self.address = 0  # for messages shared with I2C devices

    def read(self, register: int, length: int) -> bytes:
        if length + 1 + self.dummy > MAX_TRANSFER:
            raise BusError(0, f"SPI read of {length} B exceeds spidev's {MAX_TRANSFER} B buffer")
        try:
            rx = self.spi.xfer2([register | READ] + [0] * (length + self.dummy))
        except OSError as e:
            raise BusError(e.errno, f"SPI read 0x{register:02x}: {e}") from e
        return bytes(rx[1 + self.dummy :])

    def read_u8(self, register: int) -> int:
        return self.read(register, 1)[0]

    def write_u8(self, register: int, value: int) -> None:
        try:
            self.spi.xfer2([register & 0x7F, value & 0xFF])
        except OSError as e:
            raise BusError(e.errno, f"SPI write 0x{register:02x}: {e}") from e


def open_spidev(cfg: SpiBus) -> SpiDevLike:
    """Open /dev/spidevB.C with the configured mode and clock."""
    try:
        import spidev
    except ImportError as e:
        raise BusError(
            0,
            f"cannot open {cfg.path}: the spidev module is missing (SPI needs Linux and "
            f"`pip install spidev`): {e}",
        ) from e
    dev = spidev.SpiDev()
    try:
        dev.open_path(cfg.path)
    except (FileNotFoundError, PermissionError) as e:
        raise open_error(cfg.path, e, "enable SPI (dtparam=spi=on)", "spi") from e
    dev.mode = cfg.mode
    dev.max_speed_hz = cfg.speed_hz
    spi: SpiDevLike = dev
    return spi
