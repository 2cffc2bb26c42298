"""Configured registers as set/clear masks: written read-modify-write, verified, re-checked.

As PX4's `_register_cfg` tables do, a setting names the bits it sets and the bits it clears; the
other bits of the register (reserved, or not ours) keep what the chip holds. The same masks
verify the write and, every 100 ms, re-check one register of the plan (round robin over every
configured register of every bank and die). A mismatch, read twice so a garbled transfer is not
taken for a changed chip, means the chip was reset or glitched: counted, and raised as
`RegisterMismatch` so the runner re-initialises it.

The round robin alone finds a reset only when it comes to a register the reset changed: up to
N x 100 ms for N registers. So each die also names a sentinel, a configured register that any
reset changes (a power or FIFO-enable register whose default is off), and the checker reads it
often enough that a reset is found within 100 ms of it: every 100 ms less two poll spacings (a
check is only made at a poll, and a poll may fail while the chip reloads). Its cost is one
register read: on I2C at 400 kHz, address + register, repeated start, address + one byte is
39 bit times, 98 us; an MPU6050 at 1 kHz (polls up to 22 ms apart) reads it every 56 ms, 18
reads and 1.8 ms of bus a second (0.2 %); the worst case, polls 33 ms apart, 3 ms a second.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from imud.buses.registers import RegisterDevice
from imud.chips.api import DriverCounters
from imud.chips.bits import BitField
from imud.clock import Clock
from imud.errors import DeviceIdentityError, RegisterMismatch

CHECK_EVERY_NS = 100_000_000
WRITE_TRIES = 3  # a configured register written at most this often before the start fails


@dataclass(frozen=True, slots=True)
class RegisterSetting:
    """Bits `set_bits` set and `clear_bits` cleared in `register` (of `bank`), a register of
    `width` bits (16 for a chip of word registers), `name`d in messages when given."""

    register: int
    set_bits: int = 0
    clear_bits: int = 0
    bank: int = 0
    width: int = 8
    name: str = ""

    def __post_init__(self) -> None:
        # plain ints: `~` of an IntFlag complements only up to its highest defined bit
        for name in ("register", "set_bits", "clear_bits", "bank"):
            object.__setattr__(self, name, int(getattr(self, name)))
        if self.set_bits & self.clear_bits:
            raise ValueError(f"register 0x{self.register:02x}: a bit both set and cleared")

    @classmethod
    def fields(
        cls,
        register: int,
        *values: tuple[BitField, int],
        set_bits: int = 0,
        clear_bits: int = 0,
        bank: int = 0,
    ) -> RegisterSetting:
        """Whole fields to given values (every bit of each field set or cleared), plus single
        bits to set or clear."""
        on, off = int(set_bits), int(clear_bits)
        for f, v in values:
            on |= f.bits(v)
            off |= f.mask & ~f.bits(v)
        return cls(register, on, off, bank)

    @property
    def mask(self) -> int:
        return self.set_bits | self.clear_bits

    def apply(self, current: int) -> int:
        return ((current & ~self.clear_bits) | self.set_bits) & ((1 << self.width) - 1)

    def holds(self, value: int) -> bool:
        return value & self.mask == self.set_bits

    def describe(self, got: int) -> str:
        where = f"bank {self.bank} " if self.bank else ""
        what = f"{self.name} (0x{self.register:02x})" if self.name else f"0x{self.register:02x}"
        d = self.width // 4
        return (
            f"{where}register {what} reads 0x{got:0{d}x}; configured bits "
            f"0x{self.mask:0{d}x} should read 0x{self.set_bits:0{d}x}"
        )


class RegisterPlan:
    """The configured registers of one die.

    `select_bank(dev, bank)` switches register banks on chips that have them; every method leaves
    bank 0 selected."""

    def __init__(
        self,
        dev: RegisterDevice,
        settings: Sequence[RegisterSetting],
        select_bank: Callable[[RegisterDevice, int], None] | None = None,
        die: str = "",
    ) -> None:
        self.dev = dev
        self.settings = list(settings)
        self.select_bank = select_bank
        self.die = die
        if select_bank is None and any(s.bank for s in self.settings):
            raise ValueError("banked settings need a select_bank function")

    def _bank(self, bank: int) -> None:
        if self.select_bank is not None:
            self.select_bank(self.dev, bank)

    def _read(self, s: RegisterSetting) -> int:
        return self.dev.read_u8(s.register)

    def write(self, s: RegisterSetting, tries: int = WRITE_TRIES) -> None:
        """Read-modify-write one setting and read it back, `tries` times until it holds: a
        transfer garbled on a noisy line must not fail a whole start, and some chips ignore a
        write (a Bosch accel right after power-up). Raises `DeviceIdentityError` if it won't."""
        got = -1
        self._bank(s.bank)
        try:
            for _ in range(tries):
                self.dev.write_u8(s.register, s.apply(self._read(s)))
                got = self._read(s)
                if s.holds(got):
                    return
        finally:
            if s.bank:
                self._bank(0)
        who = f"{self.die} die: " if self.die else ""
        raise DeviceIdentityError(
            f"{who}{s.describe(got)} after writing it{f' {tries} times' if tries > 1 else ''}"
        )

    def write_all(self, tries: int = WRITE_TRIES) -> None:
        for s in self.settings:
            self.write(s, tries)

    def verify(self, s: RegisterSetting) -> int | None:
        """The register's value if it does not hold the setting (read twice), else None."""
        self._bank(s.bank)
        try:
            got = self._read(s)
            if not s.holds(got):
                got = self._read(s)  # once more: a garbled read is not a changed chip
            return None if s.holds(got) else got
        finally:
            if s.bank:
                self._bank(0)

    def verify_all(self) -> None:
        for s in self.settings:
            got = self.verify(s)
            if got is not None:
                who = f"{self.die} die: " if self.die else ""
                raise DeviceIdentityError(f"{who}{s.describe(got)} after configuring")


class Plan(Protocol):
    """What the checker needs of a plan: its settings and a double-read verify (a
    `RegisterPlan`, or a chip's own plan for registers behind its own framing)."""

    die: str
    settings: list[RegisterSetting]

    def verify(self, s: RegisterSetting) -> int | None: ...


class RegisterChecker:
    """Every 100 ms, one configured register of one of the plans, round robin over all; and
    each plan's sentinel (`sentinels`: (plan, setting) pairs) often enough that a reset is found
    within 100 ms when polls are at most `poll_ns` apart."""

    def __init__(
        self,
        plans: Sequence[Plan],
        clock: Clock,
        c: DriverCounters,
        sentinels: Sequence[tuple[Plan, RegisterSetting]] = (),
        poll_ns: float = 0,
    ) -> None:
        self.items = [(p, s) for p in plans for s in p.settings]
        self.sentinels = list(sentinels)
        self.sentinel_every_ns = max(0, int(CHECK_EVERY_NS - 2 * poll_ns))
        self.clock, self.counters = clock, c
        self._index = 0
        self._last_ns = self._sentinel_ns = clock.now_ns()

    def restart(self) -> None:
        self._last_ns = self._sentinel_ns = self.clock.now_ns()

    def _check(self, plan: Plan, s: RegisterSetting, what: str) -> None:
        got = plan.verify(s)
        if got is not None:
            self.counters.bad_registers += 1
            who = f"{plan.die} die: " if plan.die else ""
            raise RegisterMismatch(0, f"{who}{s.describe(got)}: {what}; reinitialise")

    def check_next(self) -> None:
        now = self.clock.now_ns()
        if self.sentinels and now - self._sentinel_ns >= self.sentinel_every_ns:
            self._sentinel_ns = now
            for plan, s in self.sentinels:
                self._check(plan, s, "the chip reset itself (power glitch?)")
        if now - self._last_ns < CHECK_EVERY_NS or not self.items:
            return
        self._last_ns = now
        plan, s = self.items[self._index]
        self._index = (self._index + 1) % len(self.items)
        self._check(plan, s, "the chip was reset or glitched")
