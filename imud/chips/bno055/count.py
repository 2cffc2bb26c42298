"""The BNO055 driver's own count of samples: the chip has no sample counter, so the driver
numbers what it delivers from the sample grid (grid.py) and hands the pipeline that number as a
counter of one tick a sample (`ChipCounter`), which the fitted sample clock then counts gaps by
exactly.

A sample's count is exact when the grid pinned its index and has followed the numbering since
the last sample whose index it pinned. Otherwise (the grid lost its phase, or a sample whose
read straddled a window and that the next read could not place) it is estimated from the
grid's bounds at its period, within what the numbering allows, counted as a suspected miss and
published as an estimate (the batch's FLAG_GAP_UNCERTAIN); the next pinned sample counts from
the last exact one again, so a misjudged gap does not carry over.
"""

from __future__ import annotations

import numpy as np

from imud.chips.api import ChipCounter, FifoRead
from imud.chips.bno055.grid import SampleGrid
from imud.chips.fifotiming import FifoTiming

COUNTER_MODULO = 1 << 62  # the driver's own count of samples: it never wraps


class SampleCount:
    """Counts and brackets for the samples a driver delivers, in order."""

    def __init__(self, grid: SampleGrid) -> None:
        self.grid = grid
        self.ticks = 0  # samples counted up to the one delivered last
        self.suspected = 0  # samples whose count was estimated
        # (grid epoch, index, ticks) of the last sample delivered whose index was pinned
        self.ref: tuple[int, int, int] | None = None
        self._mid: float | None = None  # the middle of the last delivered one's bounds

    def newest_delivered(self, epoch: int, index: int) -> bool:
        """The sample at grid `index` (of `epoch`) is the one delivered last."""
        return self.ref == (epoch, index, self.ticks)

    def next(
        self, tb: int, ta: int, timing: FifoTiming, epoch: int, seen: tuple[int, int]
    ) -> FifoRead:
        """The stamping of the next sample delivered, read within [tb, ta], whose grid index
        (in grid epoch `epoch`) is one of `seen`; `timing` holds a break the driver saw (the
        chip's output restarted), to which a counted gap adds."""
        g = self.grid
        period = (g.p_lo + g.p_hi) / 2
        a, b = seen
        current = epoch == g.epoch and g.lo is not None
        k = a
        if current:
            # of the indices allowed, the newest whose window's middle the bracket's middle has
            # passed: the likeliest (the read's bracket overlaps each one's window)
            while k < b and sum(g.bounds(k + 1)) / 2 <= (tb + ta) / 2:
                k += 1
            mid = sum(g.bounds(k)) / 2
            # the grid's bounds on this sample and the next are the reads', tighter than one
            tb, ta = max(tb, int(g.bounds(a + 1)[0])), min(ta, int(g.bounds(b)[1]))
        else:
            mid = (tb + ta - period) / 2  # the newest at the latch: after tb - P, by ta
        last, ref = self.ticks, self.ref
        if ref is not None and current and ref[0] == epoch:
            lo_t, hi_t = ref[2] + a - ref[1], ref[2] + b - ref[1]
            ticks = ref[2] + k - ref[1]
            exact = lo_t == hi_t
        elif self._mid is None:
            ticks, exact = last + 1, True  # the first sample
        else:
            ticks, exact = last + round((mid - self._mid) / period), False
        if ticks <= last:  # a gap misjudged before: it cannot be taken back
            ticks, exact = last + 1, False
        if not exact:
            self.suspected += 1
        if current and a == b:
            self.ref = (epoch, a, ticks)
        self._mid = mid
        step, self.ticks = ticks - last, ticks
        if step != 1:
            timing.broke()
        return timing.read(
            tb, ta, counter=ChipCounter(np.array([ticks], np.int64), COUNTER_MODULO, 1, not exact)
        )
