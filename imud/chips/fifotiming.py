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
