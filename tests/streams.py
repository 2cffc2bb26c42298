"""A real subscriber's view of one device's stream, for tests that check the accounting: every
seq is either a sample that arrived or a lost one, counted where the gap is."""

from __future__ import annotations

from typing import Any

import zenoh

import imud.client as ic


class Stream:
    """One device's batches as (first_seq, count, lost_before)."""

    def __init__(self, session: zenoh.Session, name: str) -> None:
        self.sub = session.declare_subscriber(ic.data_key(name), zenoh.handlers.FifoChannel(65536))
        self.batches: list[tuple[int, int, int]] = []

    def drain(self) -> None:
        while (s := self.sub.try_recv()) is not None:
            b = ic.decode(s.payload.to_bytes())
            self.batches.append((b.first_seq, b.count, b.lost_before))

    def end(self) -> int:
        return self.batches[-1][0] + self.batches[-1][1] if self.batches else -1

    def missing(self, a: int, b: int) -> int:
        """seq numbers in [a, b) that no received batch carried."""
        got = sum(max(0, min(f + n, b) - max(f, a)) for f, n, _ in self.batches)
        return (b - a) - got


def mark(dev: dict[str, Any]) -> int:
    """Where the device's next batch's seq starts: every seq is a published or a lost sample.
    (Take it while nothing is being lost, so no loss is counted as it is read.)"""
    return int(dev["samples"]) + int(dev["lost_samples"])
