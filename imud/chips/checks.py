"""Periodic re-check of configured registers, shared by the drivers.

Every 100 ms one register of the plan is read back (round robin). A mismatch, read twice so a
garbled transfer is not taken for a changed chip, means the chip was reset or glitched: counted,
and raised as `RegisterMismatch` so the runner reinitialises it (as PX4 does).
"""

from __future__ import annotations

from imud.buses.registers import RegisterDevice
from imud.chips.base import DriverCounters
from imud.clock import Clock
from imud.errors import RegisterMismatch

CHECK_EVERY_NS = 100_000_000


class RegisterChecker:
    def __init__(
        self, dev: RegisterDevice, plan: list[tuple[int, int]], clock: Clock, c: DriverCounters
    ) -> None:
        self.dev, self.plan, self.clock, self.counters = dev, plan, clock, c
        self._index = 0
        self._last_ns = clock.now_ns()

    def restart(self) -> None:
        self._last_ns = self.clock.now_ns()

    def check_next(self) -> None:
        now = self.clock.now_ns()
        if now - self._last_ns < CHECK_EVERY_NS:
            return
        self._last_ns = now
        reg, want = self.plan[self._index]
        self._index = (self._index + 1) % len(self.plan)
        got = self.dev.read_u8(reg)
        if got != want:
            got = self.dev.read_u8(reg)
        if got != want:
            self.counters.bad_registers += 1
            raise RegisterMismatch(
                0, f"register 0x{reg:02x} reads 0x{got:02x}, configured 0x{want:02x}: reinitialise"
            )
