"""What a device runner measures of itself for status: its delivered rate, how late its bus
worker comes to its polls, and its losses in the log (rate-limited)."""

from __future__ import annotations

import logging
from collections import deque

log = logging.getLogger("imud.device")

LOSS_LOG_EVERY_NS = 10_000_000_000
LATE_WINDOW_NS = 10_000_000_000
RATE_WINDOW_NS = 5_000_000_000
RATE_POINT_NS = 100_000_000


class RateMeter:
    """Delivered samples per second over the last ~5 s, from one point per 100 ms (a point per
    poll would keep thousands of tuples alive for the GC to walk at 32 kHz)."""

    def __init__(self) -> None:
        self.rate_hz = 0.0
        self._window: deque[tuple[int, int]] = deque()

    def update(self, now: int, samples: int) -> None:
        w = self._window
        if w and now - w[-1][0] < RATE_POINT_NS:
            return
        w.append((now, samples))
        while len(w) > 2 and now - w[1][0] >= RATE_WINDOW_NS:
            w.popleft()
        if len(w) >= 2 and now > w[0][0]:
            self.rate_hz = (w[-1][1] - w[0][1]) * 1e9 / (now - w[0][0])

    def idle(self) -> None:
        """Nothing is delivered (the device failed): the rate is 0 until it streams again."""
        self.rate_hz = 0.0
        self._window.clear()


class LatenessMeter:
    """How late the bus worker came to a device's polls: the worst over ~10 s, the scheduling
    jitter the chip's FIFO has to absorb."""

    def __init__(self) -> None:
        self.max_ns = 0
        self._current_ns = 0
        self._window_ns = 0

    def note(self, late_ns: int, now: int) -> None:
        if now - self._window_ns > LATE_WINDOW_NS:
            self.max_ns, self._window_ns = self._current_ns, now
            self._current_ns = 0
        self._current_ns = max(self._current_ns, late_ns)
        self.max_ns = max(self.max_ns, late_ns)


class LossLog:
    """Lost samples in the log at most every 10 s per device, with what was lost meanwhile."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._unlogged = 0
        self._logged_ns = -(10**12)

    def note(self, lost: int, total: int, now: int, overflows: int, bus_errors: int) -> None:
        self._unlogged += lost
        if now - self._logged_ns >= LOSS_LOG_EVERY_NS:
            log.warning(
                "%s: %d samples lost since the last report (%d in all; FIFO overflows %d, "
                "bus errors %d)",
                self.name,
                self._unlogged,
                total,
                overflows,
                bus_errors,
            )
            self._unlogged, self._logged_ns = 0, now
