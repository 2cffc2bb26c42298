"""The register interface chip drivers use, whatever the bus underneath (I2C or SPI)."""

from __future__ import annotations

from typing import Protocol


class RegisterDevice(Protocol):
    address: int

    def read(self, register: int, length: int) -> bytes: ...

    def read_u8(self, register: int) -> int: ...

    def write_u8(self, register: int, value: int) -> None: ...
