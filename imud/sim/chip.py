"""What every chip simulator shares: a sample grid driven by the chip's (imperfect) oscillator,
lazy sample generation up to the clock's present, the physics, and the ground-truth record.

A subclass says what its output rate is (from its registers) and what one chunk of samples does
to its registers and FIFO (`_emit`).

When a sample is latched. Silicon latches a FIFO count (or an output register) at the instant
the bus reads it. A simulator computes its samples inside that read, and the physics, filters
and errors of a chunk take a sizeable share of a millisecond of host time: deciding which samples
are due before that work would make the read see a count that much older than its end, a bias
of half of it in any host-side stamp (measured: +222 us on the MPU6050 model). So a simulator that
opts in (`stage_ns`) computes its samples ahead, in chunks, and at each access first does that
work and only then looks at the clock and hands the FIFO the samples due by then: the latch is
the end of the access, as on a chip. The hand-over is work too, so the chip's counts and FIFO
frames are prepared with the samples (`_encode`) and the clock is read again after each hand-over
(`_latch_at_end`): left at the latch, they kept it 30-50 us before the end exactly in the reads
that found a new sample (+22 us in the MPU6050's stamps). Staged samples are discarded (and
computed again, under the new settings) by any register write and by a grid restart.

Two start-up and power faults of `[device.sim.faults]` are kept here for every chip: `resets`,
instants at which the chip resets itself (a brown-out; the subclass's `power_on_reset` says what
that does to it, applied at the instant itself, with the samples before it made first), and
`garbage_identity_s`, a start-up window in which the identity register reads garbage
(`identity`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import numpy.typing as npt

from imud.channels import Channel
from imud.clock import Clock
from imud.sim.api import SimDie, Truth
from imud.sim.physics import ChipFigures, ErrorModel, MotionModel, TemperatureModel
from imud.sim.settings import SimSettings

CHUNK = 50_000
# a chip's register and FIFO contents for a run of samples, row i for sample i (counts, frames)
Encoded = dict[str, npt.NDArray[Any]]
STAGE_NS = 100_000_000  # how far ahead a staging simulator computes its samples
TRUTH_KEEP = 10_000  # truth chunks kept when nobody drains them
# clock reads at most per access while each hands the FIFO a sample that came due meanwhile (a
# chip whose period is shorter than a hand-over would otherwise be chased for ever)
LATCH_ROUNDS = 4


@dataclass(slots=True)
class Measured:
    """Samples computed but not yet latched: their latch times, measured values, and the truth
    (the instants the motion happened and the true values)."""

    t_ns: npt.NDArray[np.int64]
    accel: npt.NDArray[np.float64]
    gyro: npt.NDArray[np.float64]
    temp_c: npt.NDArray[np.float64]
    truth_t_ns: npt.NDArray[np.int64]
    truth_accel: npt.NDArray[np.float64] | None
    truth_gyro: npt.NDArray[np.float64] | None
    # what the chip hands its registers and FIFO, one row a sample, prepared when the samples
    # were computed (`SampledChip._encode`), or None: made at the latch from the SI values
    enc: Encoded | None = None


@dataclass(slots=True)
class _Run:
    """Staged samples not all latched yet: rows `i` onwards of `m`, row `i` being sample `k`
    (a cursor: a latch of one sample slices nothing it does not hand over)."""

    k: int
    m: Measured
    i: int = 0


class SampledChip:
    def __init__(self, settings: SimSettings, clock: Clock, figures: ChipFigures) -> None:
        self.settings = settings
        self.clock = clock
        self.t_origin_ns = clock.now_ns()  # physics time zero
        self.motion = MotionModel(settings.motion)
        self.temp = TemperatureModel(settings)
        self.errors = ErrorModel(figures, settings)
        self.clock_error = self.errors.clock_error
        self.record_truth = settings.truth
        # latched rows whose truth is not drained yet: (truth index of row i, samples, i, j)
        self._truth_rows: list[tuple[int, Measured, int, int]] = []
        self.samples_produced = 0  # truth index: chip samples since the simulator was made
        self.sampling = False
        faults = settings.faults
        self._resets_ns = sorted(self.t_origin_ns + round(r.at_s * 1e9) for r in faults.resets)
        self.self_resets = 0  # brown-outs applied so far
        self._garbage_until_ns = self.t_origin_ns + round(faults.garbage_identity_s * 1e9)
        self._garbage = np.random.default_rng([settings.seed, 0x1DE7])
        self._anchor(clock.now_ns())

    # --- for subclasses ---------------------------------------------------------------------
    @property
    def rate_hz(self) -> float:
        """True output rate (the configured rate, off by the oscillator error)."""
        raise NotImplementedError

    def _emit(
        self,
        t_ns: npt.NDArray[np.int64],
        accel: npt.NDArray[np.float64],
        gyro: npt.NDArray[np.float64],
        temp_c: npt.NDArray[np.float64],
    ) -> None:
        """Measured samples (SI, with every sensor error) latched at `t_ns`: update registers
        and FIFO."""
        raise NotImplementedError

    def _encode(self, m: Measured) -> Encoded | None:
        """What `_emit` would hand the registers and FIFO, for a staging chip to prepare when it
        computes its samples ahead (counts, FIFO frames: valid until a register write, which
        discards staged samples). The latch then only appends rows (`_emit_rows`): the
        work left inside it is what keeps the latch off the end of the access (see `_latch_at_end`).
        None: not prepared; `_emit` does it all at the latch."""
        return None

    def _emit_rows(self, enc: Encoded, i: int, j: int) -> None:
        """`_emit` for rows i..j-1 of samples that `_encode` prepared."""
        raise NotImplementedError

    def _write_one(self, reg: int, value: int) -> None:
        """One register write, after the busy check and with samples up to now produced."""
        raise NotImplementedError

    def read(self, register: int, length: int) -> bytes:
        """A burst read from `register` (the bus side of the chip)."""
        raise NotImplementedError

    def power_on_reset(self) -> None:
        """The chip resets itself (a `[device.sim.faults] resets` instant): registers to their
        power-on defaults, as the chip's own soft reset does. The clock reads the instant."""
        raise NotImplementedError(f"{type(self).__name__} does not simulate a self-reset")

    # --- shared -----------------------------------------------------------------------------
    busy_until_ns = 0  # a chip busy resetting ignores the bus until then

    @property
    def dies(self) -> Sequence[SimDie]:
        """A one-die chip is its own only die."""
        return (self,)

    def spi_select(self) -> bool:
        """Chip-select edge: most chips answer the very first SPI transfer."""
        return True

    def write(self, register: int, data: bytes) -> None:
        """Burst writes go to consecutive registers; a busy chip ignores them."""
        if self.clock.now_ns() < self.busy_until_ns:
            return
        self.advance()
        self._discard_staged()
        for i, value in enumerate(data):
            self._write_one(register + i, value)

    def identity(self, value: int, bits: int = 8) -> int:
        """What the identity register (WHO_AM_I, CHIP_ID, PROD_ID ...) reads: `value`, but
        within `garbage_identity_s` of power-on a random word that is never `value` (a chip
        still booting, or a marginal line)."""
        if self.clock.now_ns() >= self._garbage_until_ns:
            return value
        got = int(self._garbage.integers(0, 1 << bits))
        return got if got != value else value ^ ((1 << bits) - 1)

    def self_resets_due(self) -> None:
        """Apply every self-reset whose instant has passed, each at its own instant: the
        samples due before it are made first, then `power_on_reset` runs with the clock
        reading that instant (so the sample grid, busy time and start-up restart from it)."""
        while self._resets_ns and self.clock.now_ns() >= self._resets_ns[0]:
            at = self._resets_ns.pop(0)
            real, ahead = self.clock, self.lookahead_ns
            self.clock, self.lookahead_ns = _Instant(at), 0  # nothing beyond the instant
            try:
                self.advance()
                self._discard_staged()
                self.power_on_reset()
            finally:
                self.clock, self.lookahead_ns = real, ahead
            self.self_resets += 1

    def _anchor(self, now: int) -> None:
        """Restart the sample grid: the next sample comes one period after `now`."""
        self.grid_origin_ns = float(now)
        self.next_k = 1  # the next sample to latch
        self._discard_staged()

    stage_ns = 0  # compute samples this far ahead, latching them when due (see the module doc)
    _staged: list[_Run] | None = None
    _stage_k = 1  # the next sample to compute

    def _discard_staged(self) -> None:
        """Forget samples computed ahead: the settings they were computed under changed."""
        self._staged = []
        self._stage_k = self.next_k

    lookahead_ns = 0  # produce this far ahead once a sample is due (a stream sent later)

    def advance(self) -> None:
        """Produce every sample due up to now, in chunks (and `lookahead_ns` beyond, for a chip
        whose output is paced by its own clock: fewer, larger chunks cost less)."""
        if self._resets_ns and self.clock.now_ns() >= self._resets_ns[0]:
            self.self_resets_due()
        if not self.sampling:
            return
        now = self.clock.now_ns()
        period = 1e9 / self.rate_hz
        if self.stage_ns and not self.lookahead_ns:
            self._stage(now, period)
            self._latch_at_end(period)
            return
        if self.lookahead_ns:
            k_max = math.floor((now - self.grid_origin_ns) / period)
            if k_max >= self.next_k:
                k_max = self._horizon(now, self.lookahead_ns, period)
            self._produce_to(k_max, period)
            return
        # the latch at the end of the access (module doc): producing a sample is work, so the
        # clock is read again after it, until a read finds nothing more due
        for _ in range(LATCH_ROUNDS):
            k_max = math.floor((self.clock.now_ns() - self.grid_origin_ns) / period)
            if k_max < self.next_k:
                return
            self._produce_to(k_max, period)

    def _produce_to(self, k_max: int, period: float) -> None:
        for k_end, t_ns in self._grid(self.next_k, k_max, period):
            self._produce(t_ns)
            self.next_k = k_end + 1

    def _horizon(self, now: int, span_ns: int, period: float) -> int:
        """The newest grid index up to `span_ns` past `now`, never across a scheduled brown-out
        (what comes after one is the restarted chip's)."""
        ahead = now + span_ns
        if self._resets_ns:
            ahead = max(now, min(ahead, self._resets_ns[0] - 1))
        return math.floor((ahead - self.grid_origin_ns) / period)

    def _grid(
        self, k0: int, k_max: int, period: float
    ) -> Iterator[tuple[int, npt.NDArray[np.int64]]]:
        """Grid indices k0..k_max in chunks of at most CHUNK: (last index, instants)."""
        while k0 <= k_max:
            k_end = min(k_max, k0 + CHUNK - 1)
            ks = np.arange(k0, k_end + 1, dtype=np.float64)
            yield k_end, np.floor(self.grid_origin_ns + ks * period).astype(np.int64)
            k0 = k_end + 1

    def _stage(self, now: int, period: float) -> None:
        """Compute the samples due by `now` and `stage_ns` beyond, if not computed yet."""
        if self._staged is None or self._stage_k < self.next_k:
            self._discard_staged()
        assert self._staged is not None
        if math.floor((now - self.grid_origin_ns) / period) < self._stage_k:
            return  # what is due is computed already
        for k_end, t_ns in self._grid(self._stage_k, self._horizon(now, self.stage_ns, period),
                                      period):  # fmt: skip
            m = self._compute(t_ns)
            m.enc = self._encode(m)
            self._staged.append(_Run(self._stage_k, m))
            self._stage_k = k_end + 1

    def _latch_at_end(self, period: float) -> None:
        """The latch: after the work, at the end of the access (see the module doc). Handing
        samples to the FIFO and registers is itself work (tens of us in Python), and it is done
        only when a sample came due since the last access: a clock read before it would put
        the latch that far before the access's end for exactly the reads that found a new
        sample, and stamps late by half of it (measured: +22 us on the MPU6050 at 1 kHz, whose
        reads' bounds on a newest sample were never tighter than 63 us). So the clock is read
        again after each hand-over (and after computing more, should the samples computed
        ahead run out), until one finds nothing more due: the FIFO then holds what was due at
        that last clock read, and only the register read follows it."""
        for _ in range(LATCH_ROUNDS):
            now = self.clock.now_ns()
            k_due = math.floor((now - self.grid_origin_ns) / period)
            if k_due < self.next_k:
                return
            if k_due >= self._stage_k:  # due but not computed yet (the staged ones ran out)
                self._stage(now, period)
            else:
                self._latch_due(k_due)

    def _latch_due(self, k_due: int) -> None:
        """Hand the chip's registers and FIFO the computed samples up to sample `k_due`."""
        staged = self._staged
        while staged and staged[0].k <= k_due:
            run = staged[0]
            rows = run.m.t_ns.shape[0]
            j = min(rows, run.i + k_due - run.k + 1)
            self._reveal(run.m, run.i, j)
            self.next_k = run.k + j - run.i
            if j == rows:
                staged.pop(0)
            else:
                run.k, run.i = self.next_k, j

    def _compute(self, t_ns: npt.NDArray[np.int64]) -> Measured:
        """Samples latched at `t_ns`, with every sensor error, and their truth."""
        t_s = (t_ns - self.t_origin_ns) / 1e9
        f, w = self.motion.sample(t_s)
        temp = self.temp.at(t_s)
        fm, wm = self.errors.apply(t_s, f, w, temp, self.rate_hz)
        return Measured(t_ns, fm, wm, temp, t_ns, f, w)

    def _reveal(self, m: Measured, i: int, j: int) -> None:
        """Latch rows i..j-1 of computed samples: registers and FIFO, and the truth record
        (kept as the rows' place, sliced when drained: the latch stays short)."""
        if m.enc is not None:
            self._emit_rows(m.enc, i, j)
        else:
            self._emit(m.t_ns[i:j], m.accel[i:j], m.gyro[i:j], m.temp_c[i:j])
        if self.record_truth and m.truth_accel is not None and m.truth_gyro is not None:
            self._truth_rows.append((self.samples_produced, m, i, j))
            if len(self._truth_rows) > TRUTH_KEEP:
                del self._truth_rows[: TRUTH_KEEP // 2]
        self.samples_produced += j - i

    def _produce(self, t_ns: npt.NDArray[np.int64]) -> None:
        self._reveal(self._compute(t_ns), 0, t_ns.shape[0])

    def drain_truth(self) -> Truth | None:
        if not self._truth_rows:
            return None
        parts, self._truth_rows = self._truth_rows, []

        def cat(rows: Callable[[Measured], npt.NDArray[Any] | None]) -> npt.NDArray[Any]:
            return np.concatenate([cast(npt.NDArray[Any], rows(m))[i:j] for _, m, i, j in parts])

        return Truth(
            int(parts[0][0]),
            cat(lambda m: m.truth_t_ns),
            {
                Channel.ACCEL: cat(lambda m: m.truth_accel),
                Channel.GYRO: cat(lambda m: m.truth_gyro),
                Channel.TEMPERATURE: cat(lambda m: m.temp_c),
            },
        )


class _Instant:
    """The clock a self-reset runs under: it reads the reset's instant."""

    def __init__(self, at_ns: int) -> None:
        self.at_ns = at_ns

    def now_ns(self) -> int:
        return self.at_ns

    def sleep_ns(self, ns: int) -> None:
        raise RuntimeError("a chip does not sleep while it resets")

    def spin_until_ns(self, t_ns: int) -> int:
        raise RuntimeError("a chip does not wait while it resets")
