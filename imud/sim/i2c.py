"""A simulated I2C bus implementing the `smbus2.SMBus` subset the drivers use.

Drivers call it exactly as they call `smbus2.SMBus` (including `i2c_rdwr` with real `smbus2.i2c_msg`
objects), so the driver under test is byte-for-byte the driver that runs on silicon.
"""

from __future__ import annotations

import ctypes
import errno
import threading
from typing import Any

import numpy as np

from imud.chips.api import SimDie

I2C_M_RD = 0x0001


def _nak(addr: int) -> OSError:
    return OSError(errno.EREMOTEIO, f"Remote I/O error (no ACK from 0x{addr:02x})")


class SimI2CBus:
    def __init__(self, seed: int = 0) -> None:
        self._devices: dict[int, tuple[SimDie, float]] = {}
        self._rng = np.random.default_rng([seed, 0x12C])
        self._lock = threading.Lock()
        self.transfers = 0

    def attach(self, address: int, chip: SimDie, nak_rate: float = 0.0) -> None:
        self._devices[address] = (chip, nak_rate)

    def _chip(self, addr: int) -> SimDie:
        self.transfers += 1
        entry = self._devices.get(addr)
        if entry is None:
            raise _nak(addr)
        chip, nak_rate = entry
        if nak_rate > 0 and self._rng.random() < nak_rate:
            raise _nak(addr)
        return chip

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        with self._lock:
            return self._chip(i2c_addr).read(register, 1)[0]

    def write_byte_data(
        self, i2c_addr: int, register: int, value: int, force: bool | None = None
    ) -> None:
        with self._lock:
            self._chip(i2c_addr).write(register, bytes([value & 0xFF]))

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        if not 0 < length <= 32:
            raise ValueError("Desired block length over 32 bytes")  # as smbus2 says
        with self._lock:
            return list(self._chip(i2c_addr).read(register, length))

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: list[int], force: bool | None = None
    ) -> None:
        with self._lock:
            self._chip(i2c_addr).write(register, bytes(data))

    def i2c_rdwr(self, *msgs: Any) -> None:
        """Combined transfers: [write(reg)] + read(n), or a single write(reg, data...)."""
        with self._lock:
            i = 0
            while i < len(msgs):
                m = msgs[i]
                chip = self._chip(int(m.addr))
                if m.flags & I2C_M_RD:
                    raise OSError(errno.EINVAL, "read without a register address first")
                payload = bytes(m)
                nxt = msgs[i + 1] if i + 1 < len(msgs) else None
                if nxt is not None and nxt.flags & I2C_M_RD and nxt.addr == m.addr:
                    data = chip.read(payload[0], int(nxt.len))
                    ctypes.memmove(nxt.buf, data, len(data))
                    i += 2
                else:
                    if len(payload) > 1:
                        chip.write(payload[0], payload[1:])
                    i += 1

    def close(self) -> None:
        pass
