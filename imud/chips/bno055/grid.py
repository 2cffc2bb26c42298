"""Where a counter-less chip's samples fall, from read brackets alone: is a read's new sample the
one right after the previous, or may samples have been skipped?

The chip's samples lie on a grid g_k = g_0 + k P. A read bracketed by host times [tb, ta] latches
the newest sample m with g_m <= ta and g_(m+1) > tb; whether its data are new or a repeat says
whether m moved on. This keeps:
- bounds on one grid point (the reference, the newest sample pinned down), on the period (from
  the reference and an anchor grid point many indices earlier: they shrink as 1/n), and a lower
  bound on the grid point after the reference (from reads that found nothing new);
- the range of indices the newest seen sample can have (`newest`: the index, when it is one),
  numbered within an `epoch` that ends when the phase is lost. The driver counts the samples it
  delivers from that numbering (count.py), exactly while both ends of a gap are pinned in one
  epoch.
A read that straddles a grid point leaves a range, not a lost phase: its phase and period carry
over, and the next read that clears the windows pins the index again. `jitter_ns` allows for
output instants that are not exactly periodic.
"""

from __future__ import annotations

import math

MAX_STEPS = 100_000  # a longer gap is not worth enumerating: the phase is lost anyway
BROKEN_WIDEN = 2.0  # the period's bounds after a contradiction, times their width before
BROKEN_MIN_HALF = 1e-4  # and at least this share of the period either side
REFINE_AFTER = 20  # grid steps between anchor and reference before the period bounds are used


class SampleGrid:
    def __init__(self, period_ns: float, tolerance: float, jitter_ns: float = 200_000.0) -> None:
        self.prior = (period_ns * (1.0 - tolerance), period_ns * (1.0 + tolerance))
        self.jitter = jitter_ns
        self.epoch = 0
        self.reset()

    def reset(self) -> None:
        """Forget everything: the chip (re)started."""
        self.p_lo, self.p_hi = self.prior
        self.phase_losses = 0
        self.new_phase()

    def new_phase(self) -> None:
        """The chip restarted its output (a mode switch): the period holds, the phase does not."""
        self.epoch += 1  # the numbering of grid points restarts: indices of two epochs differ
        self.r = 0  # index of the reference grid point
        self.lo: float | None = None  # bounds of the reference (an ideal grid point)
        self.hi = 0.0
        self.next_lo = -math.inf  # lower bound of the grid point after the reference
        self.seen = (0, 0)  # index range of the newest sample seen
        self.anchor = (0, 0.0, 0.0)
        self.last_tb: float = -math.inf

    # --- bounds of the ideal grid point k ---------------------------------------------------
    def _lo(self, k: int) -> float:
        assert self.lo is not None
        d = k - self.r
        lo = self.lo + d * (self.p_lo if d >= 0 else self.p_hi)
        if d >= 1:
            lo = max(lo, self.next_lo + (d - 1) * self.p_lo)
        return lo

    def _hi(self, k: int) -> float:
        d = k - self.r
        return self.hi + d * (self.p_hi if d >= 0 else self.p_lo)

    def newest(self) -> int | None:
        """Index of the newest sample seen, when the reads pin it to one grid point."""
        if self.lo is None or self.seen[0] != self.seen[1]:
            return None
        return self.seen[0]

    def bounds(self, k: int) -> tuple[float, float]:
        """Earliest and latest host time of grid point k (output jitter included)."""
        return self._lo(k) - self.jitter, self._hi(k) + self.jitter

    def next_due(self) -> float | None:
        """The earliest instant the sample after the newest seen can exist (None: unknown)."""
        if self.lo is None:
            return None
        return self._lo(self.seen[0] + 1) - self.jitter

    # --- reads ------------------------------------------------------------------------------
    def observe(self, tb: int, ta: int, new: bool) -> None:
        """A read bracketed by [tb, ta] found new data (or not)."""
        j = self.jitter
        if self.lo is None:
            if new:  # the newest sample came after the last read and no later than this one
                self.lo, self.hi = max(tb - self.p_hi, self.last_tb) - j, ta + j
                self.r, self.seen, self.next_lo = 0, (0, 0), tb - j
                self.anchor = (0, self.lo, self.hi)
            self.last_tb = float(tb)
            return
        s_lo, s_hi = self.seen
        # newest index m at this latch: g_m <= ta (k_b is the highest such) and g_(m+1) > tb
        k_b = s_lo - 1
        while self._lo(k_b + 1) - j <= ta:
            k_b += 1
            if k_b - s_lo > MAX_STEPS:
                self._lose_phase(new, tb, ta)
                return
        k_a = s_lo - 1
        while self._hi(k_a + 1) + j <= tb:
            k_a += 1
        lo_m = max(k_a, s_lo + 1 if new else s_lo)
        hi_m = k_b if new else min(k_b, s_hi)
        if lo_m > hi_m:
            self._lose_phase(new, tb, ta, broke=True)  # the bounds did not hold
            return
        if hi_m > lo_m and self._hi(hi_m) - self._lo(hi_m) > self.p_lo:
            self._lose_phase(new, tb, ta)  # grid points no longer told apart
            return
        prev_hi = s_hi
        self.seen = (lo_m, hi_m)
        if lo_m == hi_m:
            self._pin(lo_m, tb, ta, new and prev_hi < lo_m)
        self.last_tb = float(tb)

    def _pin(self, m: int, tb: int, ta: int, after_last: bool) -> None:
        """The newest sample is known to be m: tighten the grid with this read."""
        j = self.jitter
        lo, hi = self._lo(m), self._hi(m)
        carried = self.next_lo + (m - self.r) * self.p_lo if m >= self.r else -math.inf
        lo = max(lo, tb - self.p_hi - j)  # g_(m+1) > tb
        if after_last:
            lo = max(lo, self.last_tb - j)  # the previous read did not see it yet
        hi = min(hi, ta + j)
        if lo > hi:
            return  # jitter beyond the allowance: keep the old bounds
        self.r, self.lo, self.hi = m, lo, hi
        self.next_lo = max(carried, tb - j)  # g_(m+1) came after this read began
        a, alo, ahi = self.anchor
        n = m - a
        if n < REFINE_AFTER:
            if hi - lo < ahi - alo:
                self.anchor = (m, lo, hi)  # early on, a tighter anchor beats a longer baseline
            return
        p_lo, p_hi = (lo - ahi) / n, (hi - alo) / n
        if p_lo <= self.p_hi and p_hi >= self.p_lo:
            self.p_lo, self.p_hi = max(self.p_lo, p_lo), min(self.p_hi, p_hi)

    def _lose_phase(self, new: bool, tb: int, ta: int, broke: bool = False) -> None:
        """Start the phase over from this read (numbering from it). If the bounds broke, a read
        was taken for a repeat that was not one (two samples alike to the last byte: a chip at
        rest can do that) more likely than the chip's period moved: the period's bounds widen
        BROKEN_WIDEN times (within the prior) rather than go back to the prior, which would cost
        seconds of probing to learn again."""
        if broke:
            mid, half = (self.p_lo + self.p_hi) / 2, (self.p_hi - self.p_lo) / 2 * BROKEN_WIDEN
            half = max(half, BROKEN_MIN_HALF * mid)
            self.p_lo, self.p_hi = max(self.prior[0], mid - half), min(self.prior[1], mid + half)
        last_tb = self.last_tb
        self.new_phase()
        self.last_tb = last_tb
        self.phase_losses += 1
        self.observe(tb, ta, new)
