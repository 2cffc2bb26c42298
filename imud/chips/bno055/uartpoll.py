"""When to read a BNO055 over its UART, and whether with a short probe or the whole burst.

Over a 115200-baud UART a full read (46 bytes, a 2 ms pause inside the request, a serial
adapter's millisecond frames) takes 8-10 ms from one request to the next: about the chip's
100 Hz period. Read back to back, two full reads rarely latch within one period, so almost none
is a repeat, and a new read alone places its sample only within a period plus a bracket: the
sample grid (grid.py) never learned its phase, and every read left the count of samples since
the previous one to a guess (measured before this module: a sample miscounted every second or
so, stamps 2-3 ms off).

So the phase is found with probes: reads of only the first PROBE_LEN bytes (accelerometer,
magnetometer, gyroscope: they change with every sample), about 7 ms apart, until the grid has
pinned a sample and narrowed its period to LOCKED_PERIOD_NS (a second or two after start; a
full read every ACQUIRE_PROBES meanwhile). Probes are aimed at the middle of the next sample's
window, so whether they find it or not, the window halves (down to about a bracket). Then full
reads are placed: each starts so its request goes in just after the next sample surely exists
and its bracket ends before the one after can: its index is certain, and a sample the link had
no time for is counted exactly. (The driver sends each request's first chunk ahead, so a read is
only its last two bytes late: Bno055Uart.prepare_read.) When the window has grown too wide for
that (the period's residual error adds up), full reads are aimed into it instead, each finding
the sample or not. A read the scheduler made late straddles a window now and then: the driver
holds that sample back and the next read, placed after the last sample it can be, tells which
one it was.
"""

from __future__ import annotations

import statistics
from collections import deque

from imud.chips.bno055.grid import SampleGrid

PROBE_LEN = 18  # ACC, MAG, GYR: 0x08-0x19
ACQUIRE_PROBES = 8  # probes in a row while the phase or the period is not known yet
MAX_AIMED = 8  # aimed reads in a row before placing is tried with a wider margin; twice as
# many, and reads are placed however wide the window
LOCKED_PERIOD_NS = 100_000  # the period's bounds this narrow: reads may follow probes
MARGIN_NS = 1_000_000  # room left on either side of a placed full read's typical bracket
TIGHTEN_NS = 1_500_000  # how much narrower than needed probing leaves the window
FLOOR_NS = 300_000  # aimed reads narrow a window to about a bracket (and the jitter allowed)
EARLY_NS = 300_000  # a placed full read's request goes in this long after a sample surely is
LATE_MARGIN_NS = 500_000  # a full read the link is late for still needs this much room
TIMING_READS = 32  # recent full reads the request and bracket times are taken from


class UartPoller:
    """The probe-or-read decision and the next read's start, from the grid's bounds and the
    link's recent timing."""

    def __init__(self, grid: SampleGrid) -> None:
        self.grid = grid
        # per kind of read (probe, full): from its start to its request being in, and the
        # width of its latch bracket
        self._timed: dict[bool, tuple[deque[int], deque[int]]] = {
            kind: (deque(maxlen=TIMING_READS), deque(maxlen=TIMING_READS)) for kind in (True, False)
        }
        self.probes = 0
        self.streak = 0  # probes since the last full read
        self.aimed = 0  # full reads aimed into a window since the last placed one
        self._tightening = False

    def note(self, t0: int, tb: int, ta: int, probe: bool) -> None:
        """A read that began at t0 latched within [tb, ta]."""
        self.probes += probe
        self.streak = self.streak + 1 if probe else 0
        lead, bracket = self._timed[probe]
        lead.append(tb - t0)
        bracket.append(ta - tb)

    def probe_now(self, held: bool = False) -> bool:
        """Probe instead of reading it all: only while the newest sample's index is not pinned
        (no phase yet, or it was lost) or the period is still too rough for a window to hold
        over a few reads. Then reads must come faster than a full one can to repeat at all."""
        g = self.grid
        if held and g.lo is not None and self._timing(probe=False) is not None:
            return False  # a straddled sample is held: a placed full read tells its index
        if g.newest() is None or g.p_hi - g.p_lo > LOCKED_PERIOD_NS:
            # a full read every ACQUIRE_PROBES all the same, so data flows even over a link too
            # damaged or too late for the phase ever to pin
            return self.streak < ACQUIRE_PROBES
        return False

    def _tighten(self, m: int, bracket: float) -> bool:
        """The next sample's window leaves too little room after it for a full read's bracket
        with MARGIN_NS on either side: aim full reads into it, each finding the sample or not,
        until it is TIGHTEN_NS narrower than that (or as narrow as a bracket allows), so a few
        aimed reads buy many placed ones. An aimed read that finds the sample delivers it; one
        that does not is the price."""
        g = self.grid
        lo, hi = g.bounds(m + 1)
        room = g.p_lo - bracket - 2 * MARGIN_NS  # the widest window a full read can be placed by
        floor = bracket + 2 * g.jitter + FLOOR_NS
        limit = max(room - TIGHTEN_NS, floor) if self._tightening else room
        if self._tightening and self.aimed >= MAX_AIMED:
            limit = max(limit, room)  # aiming stopped paying: place reads as soon as one fits
        self._tightening = hi - lo > limit and self.aimed < 2 * MAX_AIMED
        return self._tightening

    def _timing(self, probe: bool) -> tuple[float, float] | None:
        """A probe's or a full read's typical time from its start to its request being in, and
        its latch bracket's typical width (medians: a read the scheduler delays straddles a
        window now and then, and the grid says so; planning for the worst would skip a sample
        a read)."""
        lead, bracket = self._timed[probe]
        if not lead:
            return None
        return statistics.median(lead), statistics.median(bracket)

    def next_read(self, now: int, held: bool = False) -> int:
        """When the next read should start. A probe: aimed to split the next sample's window
        (its request in at the window's middle less half a bracket: latching before the
        sample raises the window's lower bound to the request's instant, after it lowers the
        upper one to the bracket's end). A full read: its request in EARLY_NS after the next
        sample surely exists, if its bracket then ends LATE_MARGIN_NS before the one after can
        exist (it latches that sample for certain); if the link is too late for that, the same
        after the following sample, and the one in between is lost, counted exactly.

        `held`: the driver holds a sample whose read straddled a window, its index one of the
        grid's `seen` range: a full read placed after the range's last sample finds that one
        exactly, and whether it repeats the held sample or not tells which the held one was."""
        g = self.grid
        probe = self.probe_now(held)
        timing = self._timing(probe)
        if g.lo is None or timing is None:
            return now
        lead, bracket = timing
        m = g.newest()
        if held and not probe:
            first = g.seen[1]
        elif m is None:
            # a phase, but the newest sample one of a range: a read between the range's last
            # sample and the next latches that one for certain, and pins the index again
            first = g.seen[1]
        elif probe or self._tighten(m, bracket):
            self.aimed += not probe
            lo, hi = g.bounds(m + 1)
            return max(now, int((lo + hi - bracket) / 2 - lead))
        else:
            first = m + 1
        self.aimed = 0
        for k in (first, first + 1):
            after_k, before_next = g.bounds(k)[1], g.bounds(k + 1)[0]
            start = max(now, int(after_k + EARLY_NS - lead))
            if start + lead + bracket + LATE_MARGIN_NS <= before_next:
                return start
        return now
