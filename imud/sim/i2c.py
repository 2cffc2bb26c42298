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

from imud.sim.api import SimDie
from imud.sim.cpu import counted
from imud.sim.faults import Fault, TransferFaults

I2C_M_RD = 0x0001


def _nak(addr: int) -> OSError:
    return OSError(errno.EREMOTEIO, f"Remote I/O error (no ACK from 0x{addr:02x})")


def _error(fault: Fault, addr: int) -> OSError | None:
    """The errno i2c-dev reports for an injected fault (None: the transfer goes through; an I2C
    read has no floating-line symptom, so a garbled answer is not simulated here)."""
    if fault in (Fault.NAK, Fault.GONE):
        return _nak(addr)
    if fault is Fault.EIO:
        return OSError(errno.EIO, "Input/output error")
    if fault is Fault.TIMEOUT:
        return OSError(errno.ETIMEDOUT, "Connection timed out")
    return None


class SimI2CBus:
    def __init__(self, seed: int = 0) -> None:
        self._devices: dict[int, tuple[SimDie, float, TransferFaults | None]] = {}
        self._rng = np.random.default_rng([seed, 0x12C])
        self._lock = threading.Lock()
        self.transfers = 0
        self._pending: OSError | None = None

    def attach(
        self,
        address: int,
        chip: SimDie,
        nak_rate: float = 0.0,
        faults: TransferFaults | None = None,
    ) -> None:
        self._devices[address] = (chip, nak_rate, faults)

    def faults(self, address: int) -> TransferFaults | None:
        """The fault stream of the device at `address` (a test may change its rates)."""
        entry = self._devices.get(address)
        return entry[2] if entry is not None else None

    def _chip(self, addr: int) -> SimDie:
        self.transfers += 1
        entry = self._devices.get(addr)
        if entry is None:
            raise _nak(addr)
        chip, nak_rate, faults = entry
        if nak_rate > 0 and self._rng.random() < nak_rate:
            raise _nak(addr)
        if faults is not None and (e := _error(faults.draw(), addr)) is not None:
            if e.errno == errno.EREMOTEIO:
                raise e  # a NAK comes in the address phase: nothing was transferred
            # an error mid-transfer: the chip answered (a FIFO gave up its bytes), then the
            # controller failed; the caller raises it after the transfer
            self._pending = e
        return chip

    def _done(self) -> None:
        e, self._pending = self._pending, None
        if e is not None:
            raise e

    @counted
    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        with self._lock:
            value = self._chip(i2c_addr).read(register, 1)[0]
            self._done()
            return value

    @counted
    def write_byte_data(
        self, i2c_addr: int, register: int, value: int, force: bool | None = None
    ) -> None:
        with self._lock:
            self._chip(i2c_addr).write(register, bytes([value & 0xFF]))
            self._done()

    @counted
    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        if not 0 < length <= 32:
            raise ValueError("Desired block length over 32 bytes")  # as smbus2 says
        with self._lock:
            data = list(self._chip(i2c_addr).read(register, length))
            self._done()
            return data

    @counted
    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: list[int], force: bool | None = None
    ) -> None:
        with self._lock:
            self._chip(i2c_addr).write(register, bytes(data))
            self._done()

    @counted
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
                self._done()

    def close(self) -> None:
        pass
