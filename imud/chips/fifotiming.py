"""A FIFO's continuity as a driver sees it on the bus, turned into the sample clock's inputs.

The pipeline stamps a batch from the host-time bracket of the read that counted it (`FifoRead`);
what it also needs is whether the batch continues the one before, and when not, the bracket of
the event after which its first sample was latched. A driver reports those events here as they
happen (it emptied the FIFO, the FIFO filled and stopped, a burst failed part way) and takes
each batch's timing from `read`, which hands over what is pending exactly once, even when reads
fail in between. One per FIFO (per die, for a chip of several).
"""

from __future__ import annotations

from imud.chips.api import ChipCounter, FifoRead

Bracket = tuple[int, int]

# A FIFO read this much after it was due still finds room: a real-time bus worker wakes later than
# that a few times an hour on the 2-vCPU VM imud is measured on (bench/rt_latency.py, docs/
# performance.md section 5), and the FIFO chips' largest spans are tens of ms
LATE_SLACK_NS = 8_000_000
POLL_MAX_NS = 50_000_000  # a sample waits at most this long in a slow chip's FIFO


def fifo_poll_interval_ns(capacity: int, period_ns: float, halves: bool = True) -> int:
    """How long between reads of a FIFO of `capacity` samples at `period_ns`: half its span
    when the other half still leaves LATE_SLACK_NS for a late wake-up, else (or with `halves`
    False) a quarter. The cost of a read is mostly per read, not per sample, so fuller reads
    are cheaper per sample; the clock fit needs no more reads than this. At most POLL_MAX_NS."""
    span = capacity * period_ns
    interval = span / 2 if halves and span / 2 >= LATE_SLACK_NS else span / 4
    return int(min(POLL_MAX_NS, interval))


class FifoTiming:
    def __init__(self) -> None:
        self._broken = False  # the next batch does not continue the last one
        self._restart: Bracket | None = None  # when the FIFO took samples again, if known

    @property
    def broken(self) -> bool:
        """A break is pending: the next batch will say it follows one."""
        return self._broken

    def broke(self, restart: Bracket | None = None) -> None:
        """Samples were dropped or discarded (a FIFO overrun, a burst cut short, a flush about
        to begin): the next batch follows a break. `restart`, when known, brackets the instant
        after which the FIFO took samples again."""
        self._broken = True
        if restart is not None:
            self._restart = restart

    def flushed(self, t0: int, t1: int) -> None:
        """The FIFO was emptied (or re-enabled) by a write between host times t0 and t1: the
        next batch's first sample is the first the chip latched after it."""
        self.broke((t0, t1))

    def mended(self) -> None:
        """What looked like a break was none (the chip's own counter shows the next sample):
        the next batch continues the stream."""
        self._broken, self._restart = False, None

    def started(self) -> None:
        """A fresh start: the runner rebases its sample clock, so nothing is pending."""
        self.mended()

    def read(
        self,
        t_before: int,
        t_after: int,
        *,
        full: bool = False,
        counter: ChipCounter | None = None,
    ) -> FifoRead:
        """The timing of a batch whose count was read between `t_before` and `t_after`; it
        carries the pending break, which is then spent. `full`: a stop-on-full FIFO was full, so
        its newest sample is older than the read (only its upper bound holds)."""
        broken, restart = self._broken, self._restart
        self._broken, self._restart = False, None
        return FifoRead(
            t_before,
            t_after,
            resync=broken,
            restart_ns=restart if broken else None,
            fifo_full=full,
            counter=counter,
        )
