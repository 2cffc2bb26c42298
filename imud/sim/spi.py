"""A simulated SPI chip select implementing the `spidev.SpiDev` subset the drivers use.

SPI has no acknowledge, so a fault looks like a floating MISO line: the chip's answer reads as
0xFF bytes. Drivers must notice from the data (headers, identity re-checks), as on silicon.
"""

from __future__ import annotations

import errno
import threading

import numpy as np

from imud.clock import VirtualClock
from imud.sim.api import SimDie
from imud.sim.cpu import counted
from imud.sim.faults import Fault, TransferFaults

FLOATING = (Fault.NAK, Fault.GARBLE, Fault.GONE)  # SPI has no acknowledge: MISO reads high


def raise_for(fault: Fault) -> None:
    """The errno spidev reports for a failed transfer, if the fault is one."""
    if fault is Fault.EIO:
        raise OSError(errno.EIO, "Input/output error")
    if fault is Fault.TIMEOUT:
        raise OSError(errno.ETIMEDOUT, "Connection timed out")


class SimSpiDev:
    def __init__(
        self,
        chip: SimDie,
        fault_rate: float = 0.0,
        seed: int = 0,
        dummy_bytes: int = 0,
        transfer_time: tuple[VirtualClock, int, int] | None = None,
        faults: TransferFaults | None = None,
    ) -> None:
        """`transfer_time = (virtual clock, ns per transfer, ns per byte)` makes each transfer
        take bus time at virtual time (in real time the host's own call takes the time)."""
        self.transfer_time = transfer_time
        self.faults = faults
        self.chip = chip
        self.fault_rate = fault_rate
        self.dummy = dummy_bytes  # bytes the chip clocks out before register data on reads
        self.mode = 0
        self.max_speed_hz = 1_000_000
        self._rng = np.random.default_rng([seed, 0x5B1])
        self._lock = threading.Lock()
        self.transfers = 0

    @counted
    def xfer2(
        self, values: list[int], speed_hz: int = 0, delay_usecs: int = 0, bits_per_word: int = 0
    ) -> list[int]:
        if not values:
            return []
        with self._lock:
            self.transfers += 1
            if self.transfer_time is not None:  # the chip answers mid-transfer
                clock, fixed, per_byte = self.transfer_time
                clock.advance((fixed + per_byte * len(values)) // 2)
            if not self.chip.spi_select():  # the chip was not in SPI mode yet
                self._finish(len(values))
                return [0] * len(values)
            first, rest = values[0], values[1:]
            fault = self.fault_rate > 0 and self._rng.random() < self.fault_rate
            drawn = self.faults.draw() if self.faults is not None else Fault.NONE
            fault = fault or drawn in FLOATING
            if first & 0x80:  # read: register data after the address byte (and dummies)
                n = len(rest) - self.dummy
                data = self.chip.read(first & 0x7F, max(n, 0))
                rx = [0] * (1 + self.dummy) + list(data)
                self._finish(len(values))
                raise_for(drawn)  # the chip answered (its FIFO gave up the bytes), then it failed
                return [0xFF] * len(values) if fault else rx
            if not fault:  # a write lost to a fault simply does not happen
                self.chip.write(first & 0x7F, bytes(rest))
            self._finish(len(values))
            raise_for(drawn)
            return [0] * len(values)

    def _finish(self, nbytes: int) -> None:
        if self.transfer_time is not None:
            clock, fixed, per_byte = self.transfer_time
            clock.advance((fixed + per_byte * nbytes) - (fixed + per_byte * nbytes) // 2)

    def close(self) -> None:
        pass
