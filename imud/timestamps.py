"""Per-sample timestamps from the chip's own sample clock, and sequence numbers that count chip
samples (so a gap is a count of lost samples).

A polled FIFO tells us, at each read, that its newest sample k was produced no later than the end
of the count read (t_after) and that sample k+1 was not produced before its start (t_before). The
chip's samples lie on a line t_k = a + k p, p being the chip's real period (its oscillator is off by
up to a few percent). Together the reads' bounds leave a small polygon of feasible lines; the
stamps follow the line through the middle of the range it allows at the newest read, with the
middle of the periods it allows (exact, from the bounds' convex hulls: O(1) per read). The
polygon shrinks as 1/reads at every phase the reads see, so the stamps carry no bias from where
in its period a read happened to come, only the bus's own: a bound is as tight as the read's
bracket, so a latch inside the bracket off its middle moves the stamps by half the difference.
Before there is a polygon (the first reads), or when the bounds contradict each other (a driver
whose brackets are not hard bounds), an exponentially forgetting least-squares fit to the bands'
midpoints and the band of the recent reads stand in. Samples lost to a FIFO reset are counted from
the same line: the chip's sample clock keeps running while its FIFO is emptied. Consecutive stamps
of a stream without a gap keep within `SLEW` of the period: a new estimate is steered to.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from imud.chips.api import Stamped
from imud.compiled import load

_min, _max = np.minimum.reduce, np.maximum.reduce  # without ndarray.min's Python wrapper
# the reads' bounds are kept for HULL_SPAN_NS of host time (the fit uses the last half to all of
# it): long enough to pin the period to a few ppm at any poll rate, short enough that a clock
# drifting with temperature stays within DRIFT_SLACK_NS of a straight line over it
HULL_SPAN_NS = 20e9
DRIFT_SLACK_NS = 2_000.0
PERIOD_DRIFT = 1e-4  # how far a period pinned before a resync may have moved since
# how far a stamp may step off the period from the one before it, while a continuous stream's
# estimate moves (a fraction of the period): an error of 1 ms is worked off in 0.2 s of stream
SLEW = 0.005
# once a segment has this many reads, its feasible set is solved at most every SOLVE_EVERY_NS of
# host time; the reads between only add their bounds, and stamps follow the last solution's line.
# A chip without a FIFO is read once a sample (2000 solves/s at 2 kHz, measured 83 us each, a
# sixth of a core), a FIFO chip every few ms: the line moves by ppm between solves, far below a
# read's bracket (bench/timestamp_error.py --virtual: the same errors at 10 and at 100 ms)
SOLVE_SETTLED_READS = 200
SOLVE_EVERY_NS = 100_000_000
_kernels = load("imud._kernels")  # one call for line_stamps and the ticks' steps, when built
I64 = npt.NDArray[np.int64]


def line_stamps_numpy(
    n: int,
    s: float,
    b: float,
    k0: int,
    period: float,
    corr: float,
    last_ts: int | None,
    follow: bool,
    slew_room: float,
) -> I64:
    """The stamps of samples k0 .. k0 + n - 1 on the line t(k) = s + period (k - b), moved by
    `corr`; when `follow`, steered from `last_ts` (sample k0 - 1's stamp) by at most
    `slew_room` ns a sample; rounded half to even; strictly after `last_ts` when there is one.
    The compiled kernel's twin and reference."""
    ks = np.arange(k0, k0 + n, dtype=np.float64)
    est = s + period * (ks - b) + corr
    if follow and last_ts is not None:
        steps = np.arange(1, n + 1, dtype=np.float64)
        cont = last_ts + steps * period
        room = steps * slew_room
        est = cont + np.clip(est - cont, -room, room)
    t = np.rint(est).astype(np.int64)
    # strictly increasing across batches, whatever the fit did (within a batch the line rises a
    # period a sample, so only a first stamp not after the last can break it)
    if last_ts is not None and t[0] <= last_ts:
        t = np.maximum(t, last_ts + 1 + np.arange(n, dtype=np.int64))
    return t


def line_stamps(
    n: int,
    s: float,
    b: float,
    k0: int,
    period: float,
    corr: float,
    last_ts: int | None,
    follow: bool,
    slew_room: float,
) -> I64:
    """`line_stamps_numpy`, in one call of the compiled kernel when it was built."""
    if _kernels is None:
        return line_stamps_numpy(n, s, b, k0, period, corr, last_ts, follow, slew_room)
    t = np.empty(n, dtype=np.int64)
    _kernels.stamps(t, s, b, k0, period, corr, last_ts, follow and last_ts is not None, slew_room)
    return t


def tick_steps(ticks: I64, mod: int) -> tuple[int, int]:
    """(largest, sum) of a counter's steps between consecutive samples, each modulo its wrap."""
    if _kernels is not None and ticks.dtype == np.int64:  # (the kernel reads int64s)
        largest, total = _kernels.tick_steps(ticks, mod)
        return largest, total
    steps = np.diff(ticks) % mod
    return (int(steps.max()), int(steps.sum())) if steps.size else (0, 0)


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


Point = tuple[float, float]


def _turn(o: Point, a: Point, b: Point) -> float:
    """> 0: o -> a -> b turns left."""
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


class _Hulls:
    """The hard bounds of a run of reads, reduced to the ones that can matter: the lower convex
    hull of the points (k, t_after) (the grid passes below them all) and the upper hull of the
    points (k + 1, t_before) (it passes above them). A line clears a set of points exactly when
    it clears their hull's vertices, and a hull of reads at every phase keeps a handful of them,
    so the exact feasible region costs a few dozen numbers whatever the number of reads. Reads
    come in order of k (Andrew's monotone chain: amortised O(1) a read)."""

    def __init__(self, start: int, t0: float = 0.0) -> None:
        self.start = start  # the read count when it began
        self.t0 = t0  # the host time of its first read (relative to the reference)
        self.below: list[Point] = []
        self.above: list[Point] = []

    def add(self, x: float, t_before: float, t_after: float, phase: bool = True) -> None:
        _push(self.below, (x, t_after), 1.0)
        if phase:
            _push(self.above, (x + 1.0, t_before), -1.0)

    def merged(self, other: _Hulls) -> _Hulls:
        """The hull of both runs' bounds (other's reads all after this one's)."""
        out = _Hulls(self.start, self.t0)
        for pts, side, dst in ((self.below + other.below, 1.0, out.below),
                               (self.above + other.above, -1.0, out.above)):  # fmt: skip
            for q in sorted(pts):
                _push(dst, q, side)
        return out


def _push(h: list[Point], q: Point, side: float) -> None:
    """Add `q` (x not below the last point's) to a lower (`side` 1) or upper (-1) hull."""
    if h and h[-1][0] == q[0]:
        if (h[-1][1] - q[1]) * side <= 0:
            return  # a looser bound at the same index
        h.pop()
    while len(h) >= 2 and _turn(h[-2], h[-1], q) * side <= 0:
        h.pop()
    h.append(q)


class SampleClock:
    def __init__(self, nominal_period_ns: float, memory_reads: int = 500, recent: int = 32) -> None:
        self.nominal = nominal_period_ns
        self.period = nominal_period_ns
        self.memory = memory_reads
        self.k_last = -1  # index of the newest delivered sample
        self.last_ts: int | None = None
        self._ts_k = -2  # the sample index `last_ts` stamps
        self._pending_resync = False
        self._pending_restart: tuple[int, int] | None = None
        self._tps: float | None = None  # chip-counter ticks per sample, when a driver gives them
        self._last_tick: int | None = None  # the counter at the newest delivered sample
        self._tick_k = -1  # the sample index `_last_tick` belongs to
        self.silent_gaps = 0  # gaps only the chip's counter showed (the FIFO said nothing)
        # the counter's ticks over the one-sample steps followed since the baseline began, and
        # the number of those steps: their ratio is the ticks per sample
        self._tick_u = 0
        self._tick_n = 0
        self._tps_n = 0  # the steps the current estimate came from
        self._tps_known = False  # the driver gave the ratio (ChipCounter.per_sample)
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
        # the bounds of this segment's last HULL_SPAN_NS, in two overlapping generations (the
        # older, used, spans half of it to all of it), and those of the segments before it that
        # agreed with it
        self._hulls = (_Hulls(0),) * 2
        self._prior: _Hulls | None = None
        self._prior_ok = True  # the last polygon agreed with the prior segments
        self._roots = (0.0, 0.0)  # the last feasible period range (0: none)
        self._exact = False  # the period came from the reads' bounds (not the midpoint fit)
        self._period_bounds: tuple[float, float] | None = None  # what the bounds allow
        # (index, host time) of the newest read's sample as the feasible polygon puts it
        self._anchor: tuple[float, float] | None = None
        # how far the anchored line may be off: half the polygon's range of the anchor sample's
        # instant and of the period (ns): at index k, by phase + |k - anchor| * period
        self._spread: tuple[float, float] = (0.0, 0.0)
        self._unpinned = False  # the gap that starts the next segment was counted as an estimate
        self._segment = 0
        self._segment_pending = False  # the next observation starts a new segment
        self._solved_ns = -SOLVE_EVERY_NS  # host time of the read the last solve came at

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

    def _at(self, k: float) -> float:
        """The fitted grid at one index (`_line` without an array's overhead)."""
        return self._t_ref + self._my + self.period * (k - (self._k_ref + self._mk))

    def _observe(
        self,
        k: int,
        t_before: int,
        t_after: int,
        new_segment: bool = False,
        solve: bool = True,
        phase: bool = True,
    ) -> None:
        """Add one read to the fit. The slope is pooled over segments between FIFO resyncs, so a
        gap whose sample count was misjudged by one cannot bias it. `solve` False: only keep the
        read's bounds; the feasible set is found at the next read that has samples to stamp (a
        chip polled faster than it samples, as the ADIS16465 is at 8 polls a sample, would
        otherwise solve it at every empty poll: measured 80 % of a core). `phase` False: a batch
        that is not the newest (a full FIFO's): only its upper bound holds (t_before is when the
        read began, not a bound on the sample after it), so only that one enters the hulls."""
        if self._count == 0:
            self._k_ref, self._t_ref = k, t_after
        self._count += 1
        if new_segment or self._segment_pending:
            self._segment_pending = False
            self._seg_n = 0
            self._segment += 1
            new_segment = True
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
        self._add_bounds(x, t_before - self._t_ref, t_after - self._t_ref, new_segment, phase)
        if not solve:
            return
        if (
            self._anchor is not None
            and self._seg_n > SOLVE_SETTLED_READS
            and t_after - self._solved_ns < SOLVE_EVERY_NS
        ):
            return  # settled, and solved a moment ago: its line stands
        self._solved_ns = t_after
        self._anchor = None
        poly = self._feasible()
        if poly is not None:
            p_lo, p_hi, c_lo, c_hi = poly
            p = (p_lo + p_hi) / 2.0
            if 0.9 * self.nominal < p < 1.1 * self.nominal:
                t_new = self._at(k) + (c_lo + c_hi) / 2.0
                self.period = p
                self._anchor = (float(k), t_new)
                self._spread = ((c_hi - c_lo) / 2.0, (p_hi - p_lo) / 2.0)
                self._exact = True
                return
        if self._exact and self._count - self._hulls[0].start < 8:
            return  # a new segment too short to say more: the period is the chip's, it stays
        # the bounds contradict each other (a driver whose brackets are not hard bounds, a clock
        # that jumped): the midpoint fit, and the band of the recent reads
        self._exact = False
        if self._count >= 3 and self._vk > 4.0:
            p = self._cky / self._vk
            # a chip is off by a few percent at most: anything else is a bad fit, keep the old
            if 0.9 * self.nominal < p < 1.1 * self.nominal:
                self.period = p

    def _add_bounds(
        self, x: float, tb: float, ta: float, new_segment: bool, phase: bool = True
    ) -> None:
        old, young = self._hulls
        if new_segment:
            # the segments so far stay in the fit while they agree with the new one (they do
            # unless the gap between was misjudged): their bounds are kept, hulled together
            run = old if old.below else None
            if run is not None and self._prior is not None and self._prior_ok:
                run = self._prior.merged(run)
            # after a gap counted as an estimate, the earlier bounds carry indices that may be
            # off by a sample: bounds that loose would still agree, and narrow the polygon
            # around a wrong line
            self._prior = None if self._unpinned else run
            old = young = _Hulls(self._count, ta)
        elif not old.below:  # the first read (of the stream, or since a rebase)
            old = young = _Hulls(self._count, ta)
        elif ta - old.t0 >= HULL_SPAN_NS:  # the younger, half as long, takes over
            old, young = young, _Hulls(self._count, ta)
        if young is old and ta - old.t0 >= HULL_SPAN_NS / 2:
            young = _Hulls(self._count, ta)
        if self._prior is not None and ta - self._prior.t0 > 2 * HULL_SPAN_NS:
            self._prior = None  # long gone: the chip's clock may have drifted since
        old.add(x, tb, ta, phase)
        if young is not old:
            young.add(x, tb, ta, phase)
        self._hulls = (old, young)

    def _feasible(self) -> tuple[float, float, float, float] | None:
        """The polygon of this segment's bounds with the earlier segments', or alone if they
        disagree, or its last half alone if the whole disagrees (a clock that drifted)."""
        old, young = self._hulls
        if self._prior is not None:
            both = self._polygon(self._prior.below + old.below, self._prior.above + old.above)
            self._prior_ok = both is not None
            if both is not None:
                return both
        for h in (old, young) if young is not old else (old,):
            if self._count - h.start >= 8:
                poly = self._polygon(h.below, h.above)
                if poly is not None:
                    return poly
        return None

    def _polygon(
        self, below: list[Point], above: list[Point]
    ) -> tuple[float, float, float, float] | None:
        """What a set of reads allows together, exactly: the range of the chip's period and the
        range of the newest read's sample instant (relative to the current fit there), over
        every grid line that satisfies all of their hard bounds (None: too few reads to say,
        or bounds that contradict each other).

        Each read bounds the grid twice, t_k <= t_after and t_(k+1) > t_before (`below`, `above`:
        those bounds' hull vertices, relative to the reference). Over many reads they leave a
        small polygon of feasible lines (period, phase), which shrinks as 1/reads whatever the
        reads' phases, where a fit to the bands' midpoints converges as 1/sqrt(reads) and follows
        the pattern of the poll phases. With c the line's offset from the current fit at the
        newest index K and d its period correction, a bound at index x, a = K - x samples older,
        allows c <= U + d a (below) or c > L + d a (above). The lowest upper bound less the
        highest lower one is a concave piecewise-linear function of d: the feasible d lie between
        its two roots, found exactly by Newton's method from outside, starting next to the last
        ones (a step or two over a dozen vertices: plain Python beats NumPy at that size); as
        both bounds rise with d, the highest feasible c is at the largest root, the lowest at
        the smallest."""
        if not below or not above:
            return None
        k_new = below[-1][0]
        if k_new - below[0][0] < 4:
            return None
        p, my, mk = self.period, self._my, self._mk
        slack = min(DRIFT_SLACK_NS, 0.02 * p)  # a clock that drifts bends the grid a little
        ups = [(k_new - x, y + slack - my - p * (x - mk)) for x, y in below]
        lows = [(k_new - x, y - slack - my - p * (x - mk)) for x, y in above]

        def root(d: float, side: float) -> tuple[float, float, float] | None:
            """From outside on `side` (+1: the largest root, -1: the smallest) inwards: the
            root and both bounds on c there."""
            for _ in range(64):
                hi, ai = min((u + d * a, a) for a, u in ups)
                lo, aj = max((v + d * a, a) for a, v in lows)
                if hi - lo >= -1e-3:
                    return d, hi, lo
                slope = ai - aj
                if slope * side >= 0:
                    return None  # no feasible line: the reads contradict each other
                d -= (hi - lo) / slope
            return None

        # start just outside the last roots (new bounds only move them inwards), else far out
        lo_d, hi_d = self._roots
        margin = 1e-3 * p / max(1.0, k_new - below[0][0])
        right = root(hi_d - p + margin, 1.0) if hi_d else None
        if right is None or right[1] - right[2] > 1e-3:  # started inside: from far out
            right = root(0.1 * p, 1.0)
        left = root(lo_d - p - margin, -1.0) if lo_d else None
        if left is None or left[1] - left[2] > 1e-3:
            left = root(-0.1 * p, -1.0)
        if right is None or left is None or left[0] > right[0]:
            self._roots = (0.0, 0.0)
            return None
        self._roots = (p + left[0], p + right[0])
        d_lo, d_hi = left[0], right[0]
        known = self._period_bounds
        if known is not None:
            # the chip's period does not change with its FIFO: what earlier segments pinned
            # holds in a new one that cannot say as much yet (widened for a drifting clock)
            lo = max(d_lo, known[0] * (1 - PERIOD_DRIFT) - p)
            hi = min(d_hi, known[1] * (1 + PERIOD_DRIFT) - p)
            if lo <= hi:
                d_lo, d_hi = lo, hi
        if (d_lo, d_hi) != (left[0], right[0]):
            c_lo = max(v + d_lo * a for a, v in lows)
            c_hi = min(u + d_hi * a for a, u in ups)
        else:
            c_lo, c_hi = left[2], right[1]
        self._period_bounds = (p + d_lo, p + d_hi)
        return p + d_lo, p + d_hi, c_lo, c_hi

    def _band(self, rows: npt.NDArray[np.float64]) -> tuple[float, float]:
        k, tb, ta = rows[:, 0], rows[:, 1], rows[:, 2]
        line = self._line(k)
        hi = float(_min(ta - line))  # t_k <= t_after
        lo = float(_max(tb - line)) - self.period  # t_{k+1} > t_before
        return lo, hi

    def _correction(self) -> float:
        """Shift of the fitted line to the middle of what the reads allow: the feasible polygon's
        range at the newest read, or, before there is one, the band the recent reads allow at
        the fitted period.

        Reads from before the last resync count only while they agree with the current ones: if
        a gap was misjudged by a sample, they would pull the line off by a period."""
        if self._anchor is not None:
            k, t = self._anchor
            return t - self._at(k)
        if not len(self._recent):
            return 0.0
        rows = self._recent.rows(ordered=False)  # a band does not care about order
        lo, hi = self._band(rows)
        if lo > hi:
            current = rows[rows[:, 3] == self._segment]
            if len(current):
                lo, hi = self._band(current)
        return (lo + hi) / 2.0

    def _index_at(self, t: float) -> float:
        """The fitted line's (fractional) sample index at host time `t`."""
        return (
            (t - self._correction() - self._t_ref - self._my) / self.period + self._k_ref + self._mk
        )

    def _index_before(self, t: float) -> int:
        """Index of the newest sample the fitted line puts at or before host time `t`."""
        return math.floor(self._index_at(t))

    def _pinned(
        self, k: int, n: int, read: tuple[int, int] | None, restart: tuple[int, int] | None
    ) -> tuple[int, bool, bool]:
        """After a gap: the newest index `k` the line picked, moved into those the brackets
        allow; whether the count is an estimate; and whether the brackets allow more than one
        count (or none), which is what makes the bounds from before the gap suspect. Over
        every line the reads' hard bounds allow (the feasible polygon); without one (too few
        reads, or bounds that disagree) the count is an estimate whatever the brackets say.

        The read's count was latched inside its bracket, so the newest sample came before its
        end and the one after it not before its start; the FIFO was restarted inside `restart`,
        so the batch's first sample came after its start and the one before it before its end.
        Each leaves a window of a period and the bracket's width; a loaded host that widens
        both leaves two or more counts possible, which no fit can tell apart."""
        if read is None and restart is None:
            return k, True, True  # nothing to pin it with
        if self._anchor is None:
            slack, unbounded = 0.0, True
        else:
            phase, period = self._spread
            off = phase + abs(k - self._anchor[0]) * period
            slack, unbounded = (DRIFT_SLACK_NS + off) / self.period, False
        lo, hi = -math.inf, math.inf
        if read is not None:
            lo, hi = self._index_at(read[0]) - 1.0, self._index_at(read[1])
        if restart is not None:
            lo = max(lo, self._index_at(restart[0]) + n - 1)
            hi = min(hi, self._index_at(restart[1]) + n)
        least = max(math.floor(lo - slack) + 1, self.k_last + n)  # integers in (lo, hi]
        most = math.floor(hi + slack)
        if most < least:  # the brackets disagree with the line: keep its pick, say so
            return k, True, True
        return min(max(k, least), most), unbounded or most > least, most > least

    def _learn_ticks(
        self, first: int, n: int, ticks: npt.NDArray[np.int64], mod: int, advance: int | None
    ) -> None:
        """Ticks per sample of the chip's own counter, whatever the tick's unit (constant on the
        chip's clock): the ticks over the samples seen one after another since the counter was
        last followed without a break, so the estimate sharpens as 1/samples rather than staying
        at a batch's quantisation. `advance`: unwrapped ticks from the last batch's newest packet
        to this batch's first, when known (a batch continuing the stream, or a gap counted by
        ticks); None starts the baseline over. A gap's ticks are left out: its sample count came
        from this estimate, and fed back it would hold on to its own error (a gap of 1800
        samples counted one short, measured, kept the next ones short too)."""
        if n >= 2:
            largest, span = tick_steps(ticks, mod)
            if largest >= mod // 2:  # a sample apart is half a wrap: ticks say nothing
                self._tps = self._last_tick = None
                return
        else:
            span = 0
        if advance is None or self._last_tick is None:
            self._tick_u, self._tick_n = span, n - 1
        elif first == self._tick_k + 1:  # the next sample: its step counts too
            self._tick_u += advance + span
            self._tick_n += n
        else:
            self._tick_u += span
            self._tick_n += n - 1
        self._last_tick = int(ticks[-1])
        self._tick_k = first + n - 1
        samples = self._tick_n
        # the estimate follows the baseline as it grows; a new baseline replaces an older
        # estimate once it is as long, or long enough to be good (the ratio is fixed by the
        # chip's clock tree: it changes only with its clock source); one the driver gave stays
        if self._tps_known:
            return
        if samples >= 1 and (self._tps is None or samples >= min(256, self._tps_n)):
            tps = self._tick_u / samples
            if tps < mod // 2:
                self._tps, self._tps_n = tps, samples

    def _tick_index(
        self,
        k_host: int,
        n: int,
        ticks: npt.NDArray[np.int64],
        mod: int,
        uncertain: float | None,
        ahead: float = 0.0,
    ) -> tuple[int, int | None]:
        """After a gap, count the samples in it from the chip's counter (exact), using the host
        estimate only to choose how often the counter wrapped meanwhile. `uncertain`: how many
        samples the host estimate may be off (its read brackets' width; None: unknown, taken as
        a quarter wrap): while that is under half a wrap, the ticks decide; beyond it the wrap
        count is a guess and the host's own estimate stands. `ahead`: how far past `k_host`
        the middle of the host's range lies (`k_host` its earliest end), the wraps being chosen
        around that middle. Returns the index and the unwrapped ticks across the gap (None:
        the host's count was kept)."""
        if self._tps is None or self._last_tick is None or self.k_last < 0:
            return k_host, None
        gap = (int(ticks[0]) - self._last_tick) % mod  # from the sample at self._tick_k
        per_wrap = mod / self._tps
        if uncertain is None:
            uncertain = per_wrap / 4
        if uncertain >= per_wrap / 2 - 1:
            return k_host, None
        first_host = k_host - n + 1 + ahead
        wraps = max(0, round((first_host - self._tick_k - gap / self._tps) / per_wrap))
        advance = gap + wraps * mod
        first = self._tick_k + round(advance / self._tps)
        # host and chip disagree beyond the host's error: keep the host's, unless the counter
        # steps a whole number of ticks a sample (a sample counter: learnt over 16 samples or
        # more, no tick ratio is that close to an integer by chance), which then counts the gap
        # exactly: the host only picked the wraps (a STIM300's host clock, its bytes handed
        # over late by a loaded machine, placed a gap 10 samples long that was one)
        exact = self._sample_counter()
        if abs(first - first_host) > uncertain + 2 and not exact:
            return k_host, None
        return first + n - 1, advance

    def _sample_counter(self) -> bool:
        """The chip's counter steps a whole number of ticks a sample (the driver says so, or
        learnt over 16 samples or more: no tick ratio is that close to an integer by chance): it
        counts samples."""
        if self._tps is None or not self._tps.is_integer():
            return False
        return self._tps_known or self._tps_n >= 16

    def _tick_index_below(
        self, n: int, t_after: int, ticks: npt.NDArray[np.int64], mod: int
    ) -> tuple[int, int] | None:
        """After a gap, a batch that is not the newest (its read's bracket does not place it):
        its newest sample still came after the last one delivered and no later than `t_after`.
        When exactly one of the counts the chip's counter allows lies in that range, it is the
        count, however wide the range is in host time short of a wrap (a read late by more than
        half a wrap would otherwise leave it to the host's guess). The newest index and the
        unwrapped ticks across the gap; None: none or several fit."""
        tps, last_k = self._tps, self._tick_k
        if tps is None or self._last_tick is None or self.k_last < 0:
            return None
        gap = (int(ticks[0]) - self._last_tick) % mod

        def newest(wraps: int) -> int:
            return last_k + round((gap + wraps * mod) / tps) + n - 1

        lo = self.k_last + n
        k_after = self._index_before(t_after)
        # the fitted line's own error there: a couple of samples, and its period's (a few
        # percent while a fit is young) over the samples since the last delivered one
        hi = k_after + 2 + 0.05 * max(0, k_after - self.k_last)
        wraps = max(0, math.floor(((lo - n + 1 - last_k) * tps - gap) / mod))
        while newest(wraps) < lo:
            wraps += 1
        if newest(wraps) > hi or newest(wraps + 1) <= hi:
            return None
        return newest(wraps), gap + wraps * mod

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
        if full and restart is None:
            below = self._tick_index_below(n, t_after, ticks, mod)
            if below is not None:
                return below[0], below[1], silent
        # how far off the host's count may be: the width of the read it placed the batch by;
        # unknown for a batch that is not the newest and says nothing of when it ended
        uncertain: float | None = None
        ahead = 0.0
        if full and restart is not None:
            # the host count puts the first sample right after restart[0] (the earliest it can
            # be), though it may have come as late as restart[1]: the wraps are chosen around
            # the middle, so a bracket up to a wrap wide (a long stall inside the read that made
            # room in the FIFO) still leaves the count to the chip's counter
            ahead = max(0.0, (restart[1] - restart[0]) / self.period) / 2
            uncertain = ahead + 2
        elif not full:
            uncertain = (t_after - t_before) / self.period + 2
        k, advance_or_none = self._tick_index(k_host, n, ticks, mod, uncertain, ahead)
        if k < self.k_last + n:  # neither count can go backwards
            return self.k_last + n, None, silent
        return k, advance_or_none, silent

    def _stamp_one(self, k: int, lost: int, uncertain: bool) -> Stamped:
        """`update`'s stamping for a batch of one sample (same steering and ordering)."""
        est = self._at(k) + self._correction()
        last = self.last_ts
        if last is not None and k == self._ts_k + 1:
            cont = last + self.period
            room = SLEW * self.period
            est = cont + min(max(est - cont, -room), room)
        t = round(est)  # half to even, as np.rint
        if last is not None and t <= last:
            t = last + 1
        self.last_ts = t
        self.k_last = self._ts_k = k
        return Stamped(k, lost, np.array([t], dtype=np.int64), self.period, uncertain)

    def resume(self, next_seq: int, last_t_ns: int, period_ns: float | None = None) -> None:
        """Continue a stream stamped elsewhere (a bus process that died) up to `last_t_ns`,
        whose next sample would have been `next_seq`: the first batch counts the gap from the
        time elapsed since, at the period that stream measured (`period_ns`; else nominal: a
        chip 2 % fast would have 2 % of a long gap miscounted)."""
        self.rebase()
        if period_ns is not None:
            self.period = period_ns
        self.k_last = self._ts_k = next_seq - 1
        self.last_ts = last_t_ns

    def rebase(self) -> None:
        """The chip was reinitialised: its sample grid restarted. Keep counting from the gap."""
        self._count = 0
        self._seg_n = 0
        self._vk = self._cky = self._mk = self._my = 0.0
        # the period is kept: a reset restarts the chip's sample grid, not its oscillator, and
        # the gap until the first read of the new grid is counted with it
        self._recent.clear()
        self._hulls = (_Hulls(0),) * 2
        self._prior = None
        self._prior_ok = True
        self._anchor = None
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
        ticks_per_sample: int | None = None,
    ) -> Stamped:
        """Stamp a batch of `n` samples whose newest was latched between the two host times.

        `resync`: the FIFO was reset since the last batch; `restart` brackets the instant it was
        re-enabled, when the driver knows it. `full`: a stop-on-full FIFO filled up, so its newest
        sample is not the one latched just before the read: the batch continues the stream but
        says nothing about the clock's phase. `ticks_per_sample`: the counter's ticks a sample,
        when the driver knows them (else learnt)."""
        resync = resync or self._pending_resync
        restart = restart or self._pending_restart
        if n == 0:
            self._pending_resync = resync
            self._pending_restart = restart if resync else None
            if not resync and not full and not self._rebase and self.k_last >= 0:
                self._observe(self.k_last, t_before, t_after, solve=False)
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
        uncertain = unpinned = False
        if self.k_last < 0:
            k_new = n - 1
        elif self._rebase:  # no fit yet on the new grid: count the gap at the nominal period
            gap = ((t_before + t_after) / 2.0 - (self.last_ts or 0)) / self.period
            k_new = self.k_last + max(n, round(gap))
            self._rebase = False
            uncertain = True  # the new grid's phase is not known: one more or less may fit
        elif resync and full and restart is not None:  # only the restart instant says where
            k_new = max(self._index_before(restart[0]) + n, self.k_last + n)
            k_new, uncertain, unpinned = self._pinned(k_new, n, None, restart)
        elif resync:
            k_new = max(self._resync_index(n, t_before, t_after, restart), self.k_last + n)
            # a stop-on-full FIFO's newest sample is not the one latched before the read
            read = None if full else (t_before, t_after)
            k_new, uncertain, unpinned = self._pinned(k_new, n, read, restart)
        else:
            k_new = self.k_last + n
        segment = resync  # the bounds before a gap hold for the line after it only if the gap
        if ticks is not None and ticks_modulo:  # was counted exactly
            if ticks_per_sample:
                self._tps, self._tps_known = float(ticks_per_sample), True
            k_new, advance, silent = self._counted(k_new, n, t_before, t_after, resync, full,
                                                   restart, ticks, ticks_modulo)  # fmt: skip
            self._learn_ticks(k_new - n + 1, n, ticks, ticks_modulo, advance)
            resync = resync or silent
            if advance is not None:  # the counter followed the gap: exact
                uncertain = unpinned = False
            # a sample counter (whole ticks a sample) that followed the gap counts it exactly:
            # the same line goes on. A new segment would drop the polygon's settling (solving
            # at every read, merging hulls): an ADIS16465 losing samples on a busy machine spent
            # more on that than on reading, and so lost more
            segment = resync and not (advance is not None and self._sample_counter())
        first = k_new - n + 1
        lost = first - (self.k_last + 1) if self.k_last >= 0 else 0
        self._unpinned = unpinned
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
            # (a full batch only as the first: its stamps need a line; its bounds are kept to the
            # one that holds)
            self._observe(k_new, t_before, t_after, new_segment=segment, phase=not full)
        if n == 1:  # a chip without a FIFO, once a sample: the same in scalars (NumPy's
            return self._stamp_one(first, lost, uncertain)  # per-call cost is most of it at n = 1)
        # the stream goes on (no sample missing, whatever the FIFO went through): steer from
        # the last stamp towards the new estimate by at most SLEW of a period a sample, so
        # consecutive stamps stay within SLEW of the period while the fit refines (a read's news
        # would otherwise show as a step)
        follow = self.last_ts is not None and first == self._ts_k + 1
        t = line_stamps(
            n,
            self._t_ref + self._my,
            self._k_ref + self._mk,
            first,
            self.period,
            self._correction(),
            self.last_ts,
            follow,
            SLEW * self.period,
        )
        self.last_ts = int(t[-1])
        self.k_last = self._ts_k = k_new
        return Stamped(first, lost, t, self.period, uncertain)
