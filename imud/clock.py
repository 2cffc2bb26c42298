"""Clocks: the daemon runs on the host's monotonic clock, tests and benchmarks on a virtual one.

Drivers and simulators take a clock instead of calling `time` so that a whole acquisition
(reset delays included) replays at virtual time, deterministically and faster than real time.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    def now_ns(self) -> int:
        """Current time in integer nanoseconds (monotonic)."""

    def sleep_ns(self, ns: int) -> None:
        """Block the caller for `ns` nanoseconds of this clock's time."""

    def spin_until_ns(self, t_ns: int) -> int:
        """Wait, without yielding the CPU, until this clock reads `t_ns` (a wait far below the
        scheduler's granularity: a chip's stall between two SPI frames); the time it then reads.
        A clock whose time is moved by whoever drives it returns at once."""


class MonotonicClock:
    """The host's CLOCK_MONOTONIC."""

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def sleep_ns(self, ns: int) -> None:
        if ns > 0:
            time.sleep(ns / 1e9)

    def spin_until_ns(self, t_ns: int) -> int:
        now = time.monotonic_ns()
        while now < t_ns:
            now = time.monotonic_ns()
        return now


class VirtualClock:
    """A clock that only moves when told to; `sleep_ns` advances it instantly."""

    def __init__(self, start_ns: int = 1_000_000_000) -> None:
        self._now = start_ns
        self._lock = threading.Lock()

    def now_ns(self) -> int:
        return self._now

    def sleep_ns(self, ns: int) -> None:
        self.advance(ns)

    def spin_until_ns(self, t_ns: int) -> int:
        # the driver of a virtual clock moves it; a wait inside one bus access takes no time
        return self._now

    def advance(self, ns: int) -> None:
        if ns < 0:
            raise ValueError("a virtual clock cannot go backwards")
        with self._lock:
            self._now += int(ns)


def epoch_offset_ns() -> int:
    """CLOCK_REALTIME - CLOCK_MONOTONIC, read once: stamps are epoch ns that never jump."""
    a = time.monotonic_ns()
    r = time.time_ns()
    b = time.monotonic_ns()
    return r - (a + b) // 2
