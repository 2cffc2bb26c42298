"""Exponential backoff with a cap: the one retry policy of devices, buses and bus processes.

Retrying at once would hammer a chip or bus that is down (and fill the log); never retrying
would leave a recoverable device dead. Each failure doubles the wait up to `max_ns`; a success
(`reset`) starts over. Times are integer ns on whatever clock the caller runs on.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Backoff:
    min_ns: int
    max_ns: int
    wait_ns: int = 0  # the wait the next failure will impose
    due_ns: int = 0  # no retry before this instant (0: none pending)

    def __post_init__(self) -> None:
        if not 0 < self.min_ns <= self.max_ns:
            raise ValueError("backoff needs 0 < min_ns <= max_ns")
        self.wait_ns = self.min_ns

    def failed(self, now_ns: int) -> int:
        """Record a failure at `now_ns`; returns the wait before the retry."""
        wait = self.wait_ns
        self.due_ns = now_ns + wait
        self.wait_ns = min(2 * wait, self.max_ns)
        return wait

    def ready(self, now_ns: int) -> bool:
        return now_ns >= self.due_ns

    def reset(self) -> None:
        self.wait_ns = self.min_ns
        self.due_ns = 0

    @property
    def pending(self) -> bool:
        return self.due_ns != 0
