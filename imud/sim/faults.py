"""Faults a simulated bus injects into one device's transfers (`[device.sim.faults]`).

The simulated buses ask `TransferFaults.draw()` once per transfer, before the chip answers: it
may first stall (the bus call blocks, holding the bus, for `stall_ms` on the device's clock: at
virtual time the clock jumps, in the daemon the bus worker really freezes), then says which
failure the transfer meets, if any. What was injected is counted by kind, so a test can check
that the daemon counted exactly that.
"""

from __future__ import annotations

import enum
from collections import Counter

import numpy as np

from imud.clock import Clock
from imud.sim.settings import SimSettings


class Fault(enum.Enum):
    NONE = "none"
    NAK = "nak"  # I2C: no acknowledge; SPI: reads float high
    EIO = "eio"
    TIMEOUT = "timeout"
    GARBLE = "garble"  # SPI: the answer reads all 0xFF
    GONE = "gone"  # inside an outage: the device does not answer at all


class TransferFaults:
    def __init__(self, s: SimSettings, clock: Clock, salt: int) -> None:
        self.f = s.faults
        self.nak_rate = s.nak_rate
        self.clock = clock
        self.rng = np.random.default_rng([s.seed, 0xFA17, salt])
        self.origin_ns = clock.now_ns()
        self.windows = [
            (self.origin_ns + int(o.at_s * 1e9), self.origin_ns + int((o.at_s + o.for_s) * 1e9))
            for o in self.f.outages
        ]
        self.injected: Counter[Fault] = Counter()
        self.stalls = 0

    def _gone(self, now: int) -> bool:
        return any(a <= now < b for a, b in self.windows)

    def draw(self) -> Fault:
        """Called by the bus with its lock held, before the chip answers."""
        if self.windows and self._gone(self.clock.now_ns()):
            self.injected[Fault.GONE] += 1
            return Fault.GONE
        f, r = self.f, self.rng.random
        if not (self.nak_rate or f.eio_rate or f.timeout_rate or f.garble_rate or f.stall_rate):
            return Fault.NONE
        if f.stall_rate and r() < f.stall_rate:
            self.stalls += 1
            self.clock.sleep_ns(int(f.stall_ms * 1e6))
        fault = Fault.NONE
        if self.nak_rate and r() < self.nak_rate:
            fault = Fault.NAK
        elif f.eio_rate and r() < f.eio_rate:
            fault = Fault.EIO
        elif f.timeout_rate and r() < f.timeout_rate:
            fault = Fault.TIMEOUT
        elif f.garble_rate and r() < f.garble_rate:
            fault = Fault.GARBLE
        if fault is not Fault.NONE:
            self.injected[fault] += 1
        return fault
