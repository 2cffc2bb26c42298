"""Per-sample timestamps from the chip's own sample clock, and sequence numbers that count chip
samples (so a gap is a count of lost samples).

A polled FIFO tells us, at each read, that its newest sample k was produced no later than the end
of the count read (t_after) and that sample k+1 was not produced before its start (t_before). The
chip's samples lie on a line t_k = a + k p, p being the chip's real period (its oscillator is off by
up to a few percent). We fit that line to the midpoints of those bounds with an exponentially
forgetting least-squares fit (O(1) per read), then shift it by the least amount that satisfies the
hard bounds of the recent reads. Samples lost to a FIFO reset are counted from the same line: the
chip's sample clock keeps running while its FIFO is emptied.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

_min, _max = np.minimum.reduce, np.maximum.reduce  # without ndarray.min's Python wrapper


class _Ring:
    """The last `size` reads as rows (k, t_before, t_after, segment), oldest first, in a
    preallocated array: no per-read conversion from Python tuples."""

    def __init__(self, size: int) -> None:
        self.buf = np.zeros((size, 4), dtype=np.float64)
        self.size = size
        self.n = 0
        self.head = 0

    def append(self, k: float, tb: float, ta: float, seg: float) -> None:
        self.buf[self.head] = (k, tb, ta, seg)
        self.head = (self.head + 1) % self.size
        self.n = min(self.n + 1, self.size)

    def rows(self, ordered: bool = True) -> npt.NDArray[np.float64]:
        if self.n < self.size or not ordered:
            return self.buf[: self.n]
        return np.roll(self.buf, -self.head, axis=0)

    def clear(self) -> None:
        self.n = self.head = 0

    def __len__(self) -> int:
        return self.n


@dataclass(slots=True)
class Stamped:
    """Stamps of a batch: `seq` of its first sample, chip samples lost right before it, one
    host-clock instant per sample, and the chip's sample period as fitted so far."""

    first_seq: int
    lost_before: int
    t_ns: npt.NDArray[np.int64]
    period_ns: float = 0.0


class SampleClock:
    def __init__(self, nominal_period_ns: float, memory_reads: int = 500, recent: int = 32) -> None:
        self.nominal = nominal_period_ns
        self.period = nominal_period_ns
        self.memory = memory_reads
        self.k_last = -1  # index of the newest delivered sample
        self.last_ts: int | None = None
        self._pending_resync = False
        self._pending_restart: tuple[int, int] | None = None
        self._tps: float | None = None  # chip-counter ticks per sample, when a driver gives them
        self._last_tick: int | None = None  # the counter at the newest delivered sample
        self._tick_k = -1  # the sample index `_last_tick` belongs to
        self.silent_gaps = 0  # gaps only the chip's counter showed (the FIFO said nothing)
        self._tick_u = 0  # unwrapped ticks at the newest delivered sample
        self._tick_base = (0, 0)  # (sample index, unwrapped ticks) where the baseline starts
        self._rebase = False
        self._count = 0
        self._seg_n = 0
        self._k_ref = 0
        self._t_ref = 0
        self._mk = 0.0
        self._my = 0.0
        self._vk = 0.0
        self._cky = 0.0
        self._recent = _Ring(recent)
        self._history = _Ring(memory_reads)
        self._bounds = (1.0, 0.0)  # (lo, hi) on the period; lo > hi means "none yet"
        self._segment = 0
        self._segment_pending = False  # the next observation starts a new segment

    @property
    def rate_hz(self) -> float:
        """The chip's measured output rate."""
        return 1e9 / self.period

    def _line(self, k: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """The fitted sample grid at indices `k` (relative to the reference: small numbers, so
        no precision is lost however long the stream has run)."""
        out: npt.NDArray[np.float64] = (
            self._t_ref + self._my + self.period * (k - (self._k_ref + self._mk))
        )
        return out

    def _observe(self, k: int, t_before: int, t_after: int, new_segment: bool = False) -> None:
        """Add one read to the fit. The slope is pooled over segments between FIFO resyncs, so a
        gap whose sample count was misjudged by one cannot bias it."""
        if self._count == 0:
            self._k_ref, self._t_ref = k, t_after
        self._count += 1
        if new_segment or self._segment_pending:
            self._segment_pending = False
            self._seg_n = 0
            self._segment += 1
        self._seg_n += 1
        alpha = max(1.0 / self._seg_n, 1.0 / self.memory)
        forget = 1.0 - 1.0 / self.memory
        x = float(k - self._k_ref)
        y = (t_before + t_after - self.period) / 2.0 - self._t_ref  # middle of the feasible band
        dx, dy = x - self._mk, y - self._my
        self._mk += alpha * dx
        self._my += alpha * dy
        self._vk = forget * self._vk + (1 - alpha) * dx * dx
        self._cky = forget * self._cky + (1 - alpha) * dx * dy
        self._recent.append(k, t_before, t_after, self._segment)
        self._history.append(k, t_before, t_after, self._segment)
        if self._count % 8 == 0:
            self._bounds = self._slope_bounds()
        if self._count >= 3 and self._vk > 4.0:
            p = self._cky / self._vk
            lo, hi = self._bounds
            if lo <= hi:  # the reads' hard bounds beat the midpoint fit's statistics
                p = min(max(p, lo), hi)
            # a chip is off by a few percent at most: anything else is a bad fit, keep the old
            if 0.9 * self.nominal < p < 1.1 * self.nominal:
                self.period = p

    def _slope_bounds(self, edge: int = 16) -> tuple[float, float]:
        """The periods every pair of an early and a late read (same segment) allows:
        t_k <= t_after and t_(k+1) > t_before for both bound the period from both sides."""
        rows = self._history.rows()
        rows = rows[rows[:, 3] == self._segment]
        if len(rows) < 2 * edge:
            return (1.0, 0.0)
        e, late = rows[:edge, None, :], rows[None, -edge:, :]
        dk = late[..., 0] - e[..., 0]
        lo = np.max((late[..., 1] - e[..., 2]) / (dk + 1))
        with np.errstate(divide="ignore"):
            hi = np.min(np.where(dk > 1, (late[..., 2] - e[..., 1]) / (dk - 1), np.inf))
        return float(lo), float(hi)

    def _band(self, rows: npt.NDArray[np.float64]) -> tuple[float, float]:
        k, tb, ta = rows[:, 0], rows[:, 1], rows[:, 2]
        line = self._line(k)
        hi = float(_min(ta - line))  # t_k <= t_after
        lo = float(_max(tb - line)) - self.period  # t_{k+1} > t_before
        return lo, hi

    def _correction(self) -> float:
        """Shift of the fitted line to the middle of the band the recent reads allow.

        Reads from before the last resync count only while they agree with the current ones: if
        a gap was misjudged by a sample, they would pull the line off by a period."""
        if not len(self._recent):
            return 0.0
        rows = self._recent.rows(ordered=False)  # a band does not care about order
        lo, hi = self._band(rows)
        if lo > hi:
            current = rows[rows[:, 3] == self._segment]
            if len(current):
                lo, hi = self._band(current)
        return (lo + hi) / 2.0

    def _index_before(self, t: float) -> int:
        """Index of the newest sample the fitted line puts at or before host time `t`."""
        return math.floor(
            (t - self._correction() - self._t_ref - self._my) / self.period + self._k_ref + self._mk
        )

    def _learn_ticks(
        self, first: int, n: int, ticks: npt.NDArray[np.int64], mod: int, advance: int | None
    ) -> None:
        """Ticks per sample of the chip's own counter, whatever the tick's unit (constant on the
        chip's clock): the unwrapped ticks over the samples counted since the counter was last
        followed without a break, so the estimate sharpens as 1/samples rather than staying at a
        batch's quantisation. `advance`: unwrapped ticks from the last batch's newest packet to
        this batch's first, when known (a batch continuing the stream, or a gap counted by
        ticks); None starts the baseline over."""
        if n >= 2:
            steps = np.diff(ticks) % mod
            if int(steps.max()) >= mod // 2:  # a sample apart is half a wrap: ticks say nothing
                self._tps = self._last_tick = None
                return
            span = int(steps.sum())
        else:
            span = 0
        if advance is None or self._last_tick is None:
            self._tick_base = (first, 0)
            self._tick_u = span
        else:
            self._tick_u += advance + span
        self._last_tick = int(ticks[-1])
        self._tick_k = first + n - 1
        k0, u0 = self._tick_base
        samples = first + n - 1 - k0
        # a new baseline replaces the old estimate once it is long enough to be better (the
        # ratio is fixed by the chip's clock tree: it changes only with its clock source)
        if samples >= 1 and (self._tps is None or samples >= 256):
            tps = (self._tick_u - u0) / samples
            if tps < mod // 2:
                self._tps = tps

    def _tick_index(
        self, k_host: int, n: int, ticks: npt.NDArray[np.int64], mod: int, uncertain: float | None
    ) -> tuple[int, int | None]:
        """After a gap, count the samples in it from the chip's counter (exact), using the host
        estimate only to choose how often the counter wrapped meanwhile. `uncertain`: how many
        samples the host estimate may be off (its read brackets' width; None: unknown, taken as
        a quarter wrap): while that is under half a wrap, the ticks decide; beyond it the wrap
        count is a guess and the host's own estimate stands. Returns the index and the
        unwrapped ticks across the gap (None: the host's count was kept)."""
        if self._tps is None or self._last_tick is None or self.k_last < 0:
            return k_host, None
        gap = (int(ticks[0]) - self._last_tick) % mod  # from the sample at self._tick_k
        per_wrap = mod / self._tps
        if uncertain is None:
            uncertain = per_wrap / 4
        if uncertain >= per_wrap / 2 - 1:
            return k_host, None
        first_host = k_host - n + 1
        wraps = max(0, round((first_host - self._tick_k - gap / self._tps) / per_wrap))
        advance = gap + wraps * mod
        first = self._tick_k + round(advance / self._tps)
        if abs(first - first_host) > uncertain + 2:
            return k_host, None  # host and chip disagree beyond the host's error: keep the host's
        return first + n - 1, advance

    def _resync_index(
        self, n: int, t_before: int, t_after: int, restart: tuple[int, int] | None
    ) -> int:
        """Index of the newest sample after a FIFO reset, from the fitted line.

        The read alone places the new samples' phase only within a period. With the FIFO
        re-enable instant too (its first sample is the first latched after it), the phase is
        pinned twice as tightly, and the integer whose phase window sits closest to the line
        is the right one unless the line itself is off by a quarter period."""
        c = self._correction()
        mid = (t_before + t_after) / 2.0 - c
        k0 = math.floor((mid - self._t_ref - self._my) / self.period + self._k_ref + self._mk)
        if restart is None:
            return k0

        def off_line(k: int) -> float:
            rows = np.array([[k, t_before, t_after], [k - n, restart[0], restart[1]]], float)
            lo, hi = self._band(rows)
            return abs((lo + hi) / 2.0 - c)

        return min((k0 - 1, k0, k0 + 1), key=off_line)

    def _counted(
        self,
        k_host: int,
        n: int,
        t_before: int,
        t_after: int,
        resync: bool,
        full: bool,
        restart: tuple[int, int] | None,
        ticks: npt.NDArray[np.int64],
        mod: int,
    ) -> tuple[int, int | None, bool]:
        """The batch's newest index with the chip's counter, the ticks since the last batch
        (None: the counter cannot be followed across the gap), and whether the counter showed
        a gap the FIFO did not (samples lost silently, e.g. bytes a failed transfer consumed)."""
        if self.k_last < 0 or self._last_tick is None:
            return k_host, None, False
        silent = False
        if not resync:
            advance = (int(ticks[0]) - self._last_tick) % mod
            if self._tps is None:
                return k_host, advance, False
            expected = (k_host - n + 1 - self._tick_k) * self._tps
            if abs(advance - expected) <= self._tps / 2:
                return k_host, advance, False
            self.silent_gaps += 1
            silent = True
            if not full:  # place the batch by its own read, as after a FIFO reset
                k_host = max(self._resync_index(n, t_before, t_after, None), k_host)
        # how far off the host's count may be: the width of the read it placed the batch by;
        # unknown for a batch that is not the newest and says nothing of when it ended
        uncertain: float | None = None
        if not full or restart is not None:
            lo, hi = restart if full and restart is not None else (t_before, t_after)
            uncertain = (hi - lo) / self.period + 2
        k, advance_or_none = self._tick_index(k_host, n, ticks, mod, uncertain)
        if k < self.k_last + n:  # neither count can go backwards
            return self.k_last + n, None, silent
        return k, advance_or_none, silent

    def resume(self, next_seq: int, last_t_ns: int) -> None:
        """Continue a stream stamped elsewhere (a bus process that died) up to `last_t_ns`,
        whose next sample would have been `next_seq`: the first batch counts the gap from the
        time elapsed since, at the nominal period."""
        self.rebase()
        self.k_last = next_seq - 1
        self.last_ts = last_t_ns

    def rebase(self) -> None:
        """The chip was reinitialised: its sample grid restarted. Keep counting from the gap."""
        self._count = 0
        self._seg_n = 0
        self._vk = self._cky = self._mk = self._my = 0.0
        # the period is kept: a reset restarts the chip's sample grid, not its oscillator, and
        # the gap until the first read of the new grid is counted with it
        self._recent.clear()
        self._history.clear()
        self._bounds = (1.0, 0.0)
        self._last_tick = None  # the chip's counter restarted with it
        self._rebase = True
        self._pending_resync = False

    def update(
        self,
        n: int,
        t_before: int,
        t_after: int,
        resync: bool = False,
        restart: tuple[int, int] | None = None,
        full: bool = False,
        ticks: npt.NDArray[np.int64] | None = None,
        ticks_modulo: int = 0,
    ) -> Stamped:
        """Stamp a batch of `n` samples whose newest was latched between the two host times.

        `resync`: the FIFO was reset since the last batch; `restart` brackets the instant it was
        re-enabled, when the driver knows it. `full`: a stop-on-full FIFO filled up, so its newest
        sample is not the one latched just before the read: the batch continues the stream but
        says nothing about the clock's phase."""
        resync = resync or self._pending_resync
        restart = restart or self._pending_restart
        if n == 0:
            self._pending_resync = resync
            self._pending_restart = restart if resync else None
            if not resync and not full and not self._rebase and self.k_last >= 0:
                self._observe(self.k_last, t_before, t_after)
            lost = 0
            if resync and restart is not None and self._count and not self._rebase:
                # everything latched before the FIFO was emptied is gone: count it now, so a
                # FIFO that overflows read after read shows its losses as they happen
                k_gone = self._index_before(restart[0])
                if k_gone > self.k_last:  # (the counter, if any, still belongs to _tick_k)
                    lost, self.k_last = k_gone - self.k_last, k_gone
            return Stamped(self.k_last + 1, lost, np.zeros(0, dtype=np.int64), self.period)
        self._pending_resync = False
        self._pending_restart = None
        if self.k_last < 0:
            k_new = n - 1
        elif self._rebase:  # no fit yet on the new grid: count the gap at the nominal period
            gap = ((t_before + t_after) / 2.0 - (self.last_ts or 0)) / self.period
            k_new = self.k_last + max(n, round(gap))
            self._rebase = False
        elif resync and full and restart is not None:  # only the restart instant says where
            k_new = max(self._index_before(restart[0]) + n, self.k_last + n)
        elif resync:
            k_new = max(self._resync_index(n, t_before, t_after, restart), self.k_last + n)
        else:
            k_new = self.k_last + n
        if ticks is not None and ticks_modulo:
            k_new, advance, silent = self._counted(k_new, n, t_before, t_after, resync, full,
                                                   restart, ticks, ticks_modulo)  # fmt: skip
            self._learn_ticks(k_new - n + 1, n, ticks, ticks_modulo, advance)
            resync = resync or silent
        first = k_new - n + 1
        lost = first - (self.k_last + 1) if self.k_last >= 0 else 0
        if resync and restart is not None and self._count:
            # the restart instant pins the new segment's phase only when it is known to within a
            # couple of periods: a wide one (a long FIFO burst after a stop-on-full overflow) would
            # pull the fitted line off by its half width
            if restart[1] - restart[0] <= 2 * self.period:
                self._observe(first - 1, restart[0], restart[1], new_segment=True)
                if not full:
                    self._observe(k_new, t_before, t_after)
            elif not full:
                self._observe(k_new, t_before, t_after, new_segment=True)
            else:
                self._segment_pending = True
        elif not full or self._count == 0:
            self._observe(k_new, t_before, t_after, new_segment=resync)
        ks = np.arange(first, k_new + 1, dtype=np.float64)
        t = np.rint(self._line(ks) + self._correction()).astype(np.int64)
        # strictly increasing across batches, whatever the fit did (within a batch the line
        # rises a period a sample, so only a first stamp not after the last can break it)
        if self.last_ts is not None and t[0] <= self.last_ts:
            t = np.maximum(t, self.last_ts + 1 + np.arange(n, dtype=np.int64))
        self.last_ts = int(t[-1])
        self.k_last = k_new
        return Stamped(first, lost, t, self.period)
