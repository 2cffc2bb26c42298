"""A simulated chip select for a chip with its own SPI framing (e.g. 16-bit words with a
pipelined answer), implementing the `spidev.SpiDev` subset its driver uses.

The die sees each frame whole, with the clock it was sent at, so it can answer as silicon does
(a burst clocked too fast reads back wrong). A fault looks like a floating MISO line: 0xFF bytes,
and a write lost on the way simply does not happen.
"""

from __future__ import annotations

import threading

import numpy as np

from imud.sim.api import SpiFrameDie
from imud.sim.cpu import counted
from imud.sim.faults import Fault, TransferFaults
from imud.sim.spi import FLOATING, raise_for


class SimSpiFrames:
    def __init__(
        self,
        die: SpiFrameDie,
        fault_rate: float = 0.0,
        seed: int = 0,
        faults: TransferFaults | None = None,
    ) -> None:
        self.die = die
        self.faults = faults
        self.fault_rate = fault_rate
        self.mode = 0
        self.max_speed_hz = 1_000_000
        self._rng = np.random.default_rng([seed, 0x5F4])
        self._lock = threading.Lock()
        self.transfers = 0

    @counted
    def xfer2(
        self, values: list[int], speed_hz: int = 0, delay_usecs: int = 0, bits_per_word: int = 0
    ) -> list[int]:
        """One frame; `speed_hz` 0 means the device's `max_speed_hz` (as in spidev)."""
        if not values:
            return []
        with self._lock:
            self.transfers += 1
            if self.fault_rate > 0 and self._rng.random() < self.fault_rate:
                return [0xFF] * len(values)
            drawn = self.faults.draw() if self.faults is not None else Fault.NONE
            if drawn in FLOATING:  # a lost frame: the die never saw it
                return [0xFF] * len(values)
            rx = self.die.spi_frame(bytes(values), speed_hz or self.max_speed_hz)
            raise_for(drawn)  # the die saw the frame, then the transfer failed
            return list(rx)

    def close(self) -> None:
        pass
