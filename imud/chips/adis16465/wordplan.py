"""Configured 16-bit registers as set/clear masks: written read-modify-write, verified, re-checked.

The same scheme as `imud.chips.regplan` (PX4's `_register_cfg`), for a chip whose registers are
16-bit words behind its own SPI framing: a setting names the bits it sets and clears, the other
bits keep what the chip holds; every 100 ms one setting is read back, twice before it counts as
changed, and a mismatch raises `RegisterMismatch` so the runner re-initialises the chip.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from imud.chips.api import DriverCounters
from imud.chips.regplan import CHECK_EVERY_NS
from imud.clock import Clock
from imud.errors import DeviceIdentityError, RegisterMismatch


class WordPort(Protocol):
    def read_words(self, registers: Sequence[int]) -> list[int]: ...

    def write_word(self, register: int, value: int) -> None: ...


@dataclass(frozen=True, slots=True)
class WordSetting:
    """Bits `set_bits` set and `clear_bits` cleared in the 16-bit register `register`."""

    name: str
    register: int
    set_bits: int = 0
    clear_bits: int = 0

    def __post_init__(self) -> None:
        for f in ("register", "set_bits", "clear_bits"):
            object.__setattr__(self, f, int(getattr(self, f)))  # plain ints, never IntFlags
        if self.set_bits & self.clear_bits:
            raise ValueError(f"{self.name}: a bit both set and cleared")

    @property
    def mask(self) -> int:
        return self.set_bits | self.clear_bits

    def apply(self, current: int) -> int:
        return ((current & ~self.clear_bits) | self.set_bits) & 0xFFFF

    def holds(self, value: int) -> bool:
        return value & self.mask == self.set_bits

    def describe(self, got: int) -> str:
        return (
            f"{self.name} (0x{self.register:02x}) reads 0x{got:04x}; configured bits "
            f"0x{self.mask:04x} should read 0x{self.set_bits:04x}"
        )


class WordPlan:
    def __init__(self, port: WordPort, settings: Sequence[WordSetting]) -> None:
        self.port = port
        self.settings = list(settings)

    def write_all(self) -> None:
        """Read-modify-write every setting (one pipelined read of them all first)."""
        current = self.port.read_words([s.register for s in self.settings])
        for s, value in zip(self.settings, current, strict=True):
            self.port.write_word(s.register, s.apply(value))

    def verify(self, s: WordSetting) -> int | None:
        """The register's value if it does not hold the setting (read twice), else None."""
        (got,) = self.port.read_words([s.register])
        if not s.holds(got):
            (got,) = self.port.read_words([s.register])
        return None if s.holds(got) else got

    def verify_all(self) -> None:
        for s in self.settings:
            got = self.verify(s)
            if got is not None:
                raise DeviceIdentityError(f"{s.describe(got)} after configuring")


class WordChecker:
    """Every 100 ms, one setting of the plan, round robin."""

    def __init__(self, plan: WordPlan, clock: Clock, counters: DriverCounters) -> None:
        self.plan, self.clock, self.counters = plan, clock, counters
        self._index = 0
        self._last_ns = clock.now_ns()

    def restart(self) -> None:
        self._last_ns = self.clock.now_ns()

    def check_next(self) -> None:
        now = self.clock.now_ns()
        if now - self._last_ns < CHECK_EVERY_NS or not self.plan.settings:
            return
        self._last_ns = now
        s = self.plan.settings[self._index]
        self._index = (self._index + 1) % len(self.plan.settings)
        got = self.plan.verify(s)
        if got is not None:
            self.counters.bad_registers += 1
            raise RegisterMismatch(0, f"{s.describe(got)}: reinitialise")
