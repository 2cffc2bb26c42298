"""Pipeline stages: pure functions on NumPy batches, raw counts to published samples, in order.

raw channels --stamp (the sample-clock fit, per die)--> t_ns, seq
             --align (a chip of several dies: onto one die's times; imud.align)
             --less the filters' group delay (the driver's `group_delay_ns`)--> t_ns
             --flags (invalid, saturated, alarm)--> per-sample flags
             --to_si (NaN where invalid)--> SI (the `raw` stream, on demand)
             --calibrate (temperature, bias, matrix; imud.calib.model)--> corrected
             --orient (orientation and its covariance, when enabled; imud.orient.stage)
             --track (gyro bias re-learned while still, when enabled; imud.calib.track)
             --> SampleBatch
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from imud import registry
from imud.align import Aligner
from imud.calib.model import CalibrationModel, apply, fill_temperature
from imud.calib.track import GyroBiasTracker
from imud.channels import INVALID_MASK, SATURATED, Channel, SampleFlag
from imud.chips.api import DeviceBase, Driver, FifoRead, RawBatch, Stamped
from imud.compiled import load
from imud.orient.stage import OrientationStage, noise_model
from imud.timestamps import SampleClock
from imud.wire import FLAG_CALIBRATED, FLAG_GAP_UNCERTAIN, FLAG_RESYNC

F64 = npt.NDArray[np.float64]
U32 = npt.NDArray[np.uint32]
_ALARM = np.uint32(SampleFlag.CHIP_ALARM)
# plain numbers on the hot path: an operator on an IntFlag builds a new enum member each time
_BIT = {c: np.uint32(c) for c in Channel}
_SAT = {c: np.uint32(f) for c, f in SATURATED.items()}
_TEMPERATURE = int(Channel.TEMPERATURE)
_max, _min = np.maximum.reduce, np.minimum.reduce  # skip ndarray.max's Python wrapper
SMALL_N = 4  # batches this short are checked for saturation in plain Python
_kernels = load("imud._kernels")  # `reaches` in one pass, when built
_I32 = np.dtype(np.int32)


def stamp(clock: SampleClock, t: FifoRead, n: int) -> Stamped:
    """Stamps of `n` samples from the chip's sample clock fitted to a read's host-time
    brackets."""
    c = t.counter
    st = clock.update(
        n,
        t.t_before_ns,
        t.t_after_ns,
        t.resync,
        restart=t.restart_ns,
        full=t.fifo_full,
        ticks=None if c is None else c.values,
        ticks_modulo=0 if c is None else c.modulo,
        ticks_per_sample=None if c is None else c.per_sample,
    )
    if c is not None and c.estimated:
        st.uncertain = True
    return st


def reaches(data: npt.NDArray[np.generic], full_scale: float) -> bool:
    """Whether any count is at or beyond +-full_scale: in one pass of the compiled kernel when
    it was built and the counts are int32s in one or two dimensions, else two NumPy
    reductions."""
    if _kernels is not None and data.dtype == _I32 and data.ndim <= 2:
        return bool(_kernels.reaches(data, full_scale))
    return bool(_max(data, None) >= full_scale or _min(data, None) <= -full_scale)


def sample_flags(raw: RawBatch) -> U32 | None:
    """Per-sample flags: each channel the chip marked invalid, each sensor at full scale, and
    the chip's alarm. None when no sample has any (the usual case: nothing to allocate)."""
    flags: U32 | None = None
    n = raw.n
    for ch, rc in raw.channels.items():
        if rc.invalid is not None:
            flags = np.zeros(n, dtype=np.uint32) if flags is None else flags
            flags[rc.invalid] |= _BIT[ch]
        fs = rc.full_scale
        if fs is not None and n and ch in _SAT:
            d = rc.data
            if n <= SMALL_N:  # a few samples (a chip read once a sample): plain Python is
                values = d.ravel().tolist()  # several times cheaper than two NumPy reductions
                hit_any = max(values) >= fs or min(values) <= -fs
            else:
                hit_any = reaches(d, fs)
            if hit_any:  # rare: only then per sample
                hit = (np.abs(d) >= fs).reshape(n, -1).any(axis=1)
                flags = np.zeros(n, dtype=np.uint32) if flags is None else flags
                flags[hit] |= _SAT[ch]
    if raw.alarm is not None:
        flags = np.zeros(n, dtype=np.uint32) if flags is None else flags
        flags[raw.alarm] |= _ALARM
    return flags


def to_si(raw: RawBatch) -> dict[Channel, F64]:
    """Counts to SI units; a value the chip marked invalid becomes NaN."""
    out: dict[Channel, F64] = {}
    for ch, rc in raw.channels.items():
        if rc.scale != 1.0:
            si = rc.data.astype(np.float64) * rc.scale
        elif rc.invalid is not None:
            si = rc.data.astype(np.float64)  # a copy: NaN goes in below
        else:
            si = rc.data.astype(np.float64, copy=False)
        if rc.invalid is not None:
            si[rc.invalid] = np.nan
        out[ch] = si
    return out


_OUTSIDE = np.uint32(SampleFlag.TEMPERATURE_OUTSIDE_CALIBRATION)


def correct(
    cal: CalibrationModel,
    si: dict[Channel, F64],
    n: int,
    last_temp: float | None,
    period_s: float,
) -> tuple[dict[Channel, F64], npt.NDArray[np.bool_] | None, float | None]:
    """The calibration stage: SI in, corrected out, with where the temperature term was clamped
    and the last valid temperature (carried to the next batch). `imud calibrate apply` runs
    this same function on a recording."""
    temp, last = fill_temperature(si.get(Channel.TEMPERATURE), n, last_temp)
    channels, clamped = apply(cal, si, temp, period_s)
    return channels, clamped, last


def track(
    tracker: GyroBiasTracker, channels: dict[Channel, F64], period_s: float
) -> dict[Channel, F64]:
    """The gyro (and delta angles) less the bias the tracker holds, which then learns from the
    batch. A new dict: the input may be the uncorrected stream's."""
    gyro = channels.get(Channel.GYRO)
    if gyro is None or gyro.shape[0] == 0:
        return channels
    bias = tracker.bias
    out = dict(channels)
    out[Channel.GYRO] = tracker.correct(gyro, channels.get(Channel.ACCEL), period_s)
    delta = channels.get(Channel.DELTA_ANGLE)
    if delta is not None and bias.any():
        out[Channel.DELTA_ANGLE] = delta - bias * period_s
    return out


def holes(raw: RawBatch, flags: U32 | None) -> npt.NDArray[np.bool_] | None:
    """Samples with no valid measurement at all (every channel but temperature invalid): they
    are not published, and count as lost. None when there are none."""
    if flags is None or all(rc.invalid is None for rc in raw.channels.values()):
        return None
    motion = sum(int(c) for c in raw.channels) & ~_TEMPERATURE
    if not motion or not (flags & INVALID_MASK).any():
        return None
    hole = (flags & np.uint32(motion)) == motion
    return hole if bool(hole.any()) else None


@dataclass(slots=True)
class SampleBatch:
    first_seq: int
    lost_before: int
    flags: int  # per batch
    t_ns: npt.NDArray[np.int64]
    channels: dict[Channel, F64]
    sample_flags: U32 | None  # None: no sample has a flag
    hole: npt.NDArray[np.bool_] | None = None
    raw: dict[Channel, F64] | None = None  # uncorrected SI, when someone asked for it
    outside_span: int = 0  # samples whose temperature correction was clamped at its span

    @property
    def n(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass
class DieClocks:
    """A chip whose dies sample on clocks of their own: a sample clock per die (the pipeline's
    own `clock` is the primary's, whose samples set the stream's times) and the align stage."""

    clocks: list[SampleClock]
    aligner: Aligner
    # the primary's clock counted a gap it could not pin: the next run after a gap says so
    uncertain: bool = False


class Pipeline:
    """Holds the only state a batch needs (the sample-clock fit, and where `seq` continues
    from); everything else is pure."""

    def __init__(
        self,
        clock: SampleClock,
        cal: CalibrationModel | None,
        epoch_offset_ns: int,
        resume: tuple[int, int, float | None] | None = None,
        tracker: GyroBiasTracker | None = None,
        group_delay_ns: int = 0,
        dies: DieClocks | None = None,
        orient: OrientationStage | None = None,
    ) -> None:
        self.clock = clock
        self.orient = orient
        self.dies = dies
        # the driver's configured filter delay at the nominal clock: every stamp is moved back by
        # it, scaled to the chip's fitted clock (a filter's delay is so many of its own samples)
        self.group_delay_ns = group_delay_ns
        self._nominal_period_ns = clock.period
        self.cal = cal  # swapped whole by a reload between batches: no seq gap, no lock
        self.tracker = tracker
        self.want_raw = False  # someone subscribes to the uncorrected stream
        self._last_temp: float | None = None
        self.epoch_offset_ns = epoch_offset_ns
        self.period_ns = clock.period
        # the newest stamp published (host ns, after the group delay): the delay follows the
        # fitted period, which moves as the fit refines, so the clock's own guarantee (strictly
        # increasing) is re-imposed after it is subtracted
        self._last_out: int | None = None
        if resume is not None:
            # a stream to continue: (next seq, last stamp published, its measured period); the
            # stamp goes back to the latch instant the clock fits
            next_seq, last_t, period = resume
            clock.resume(next_seq, last_t + group_delay_ns, period)
            self._last_out = last_t
            if dies is not None:
                dies.aligner.next_seq = next_seq

    def restarted(self) -> None:
        """The chip was re-initialised: its sample grid restarts; `seq` goes on counting."""
        for c in self.dies.clocks if self.dies is not None else [self.clock]:
            if c.k_last >= 0:
                c.rebase()
        if self.dies is not None:
            self.dies.aligner.restart()

    def delay_ns(self, period_ns: float) -> int:
        """The group delay on the chip's clock, whose period is now `period_ns`."""
        return round(self.group_delay_ns * period_ns / self._nominal_period_ns)

    @property
    def rate_hz(self) -> float:
        """The chip's output rate as fitted from its sample clock."""
        return 1e9 / self.period_ns

    def run(self, raw: RawBatch) -> list[SampleBatch]:
        """Everything one read of the chip gave (`raw` and the batches chained after it), as
        published batches, in order."""
        out: list[SampleBatch] = []
        dies = self.dies
        batch: RawBatch | None = raw
        if dies is None:
            while batch is not None:
                out.append(self.process(batch))
                batch = batch.then
            return out
        while batch is not None:  # each die on its own clock, then merged
            st = stamp(dies.clocks[batch.die], batch.timing, batch.n)
            if st.uncertain and batch.die == dies.aligner.primary:
                dies.uncertain = True
            if batch.n:
                seq = st.first_seq + np.arange(batch.n, dtype=np.int64)
                dies.aligner.add(batch.die, seq, st.t_ns, batch.channels)
            batch = batch.then
        while (a := dies.aligner.take()) is not None:
            merged = RawBatch(a.n, a.channels, raw.timing)
            uncertain = dies.uncertain and a.lost_before > 0
            dies.uncertain = dies.uncertain and not uncertain
            st = Stamped(a.first_seq, a.lost_before, a.t_ns, 0.0, uncertain)
            out.append(self._finish(merged, st))
        return out

    def process(self, raw: RawBatch) -> SampleBatch:
        """One die's batch (a chip of one die, or one clock) stamped and through every stage."""
        return self._finish(raw, stamp(self.clock, raw.timing, raw.n))

    def _finish(self, raw: RawBatch, st: Stamped) -> SampleBatch:
        if not st.period_ns:
            st.period_ns = self.clock.period
        if st.period_ns:
            self.period_ns = st.period_ns
        t_ns = st.t_ns
        if self.group_delay_ns and t_ns.size:
            t_ns = t_ns - self.delay_ns(st.period_ns or self.period_ns)
            last = self._last_out
            if last is not None and t_ns[0] <= last:
                t_ns = np.maximum(t_ns, last + 1 + np.arange(t_ns.size, dtype=np.int64))
        if t_ns.size:
            self._last_out = int(t_ns[-1])
        flags = sample_flags(raw)
        si = to_si(raw)
        cal = self.cal  # one model for the whole batch, whatever a reload does meanwhile
        channels, outside = si, 0
        if cal is not None:
            period_s = (st.period_ns or self.period_ns) / 1e9
            channels, clamped, self._last_temp = correct(cal, si, raw.n, self._last_temp, period_s)
            if clamped is not None:
                flags = np.zeros(raw.n, dtype=np.uint32) if flags is None else flags
                flags[clamped] |= _OUTSIDE
                outside = int(np.count_nonzero(clamped))
        if self.orient is not None:
            channels = self.orient.run(
                channels, (st.period_ns or self.period_ns) / 1e9, st.lost_before
            )
        if self.tracker is not None:
            channels = track(self.tracker, channels, (st.period_ns or self.period_ns) / 1e9)
        batch_flags = (
            # corrected: by a calibration file, or by the tracked gyro bias alone (either way
            # not what a calibration is fitted to)
            (FLAG_CALIBRATED if cal is not None or self.tracker is not None else 0)
            | (FLAG_RESYNC if st.lost_before else 0)
            | (FLAG_GAP_UNCERTAIN if st.uncertain else 0)
        )
        return SampleBatch(
            st.first_seq,
            st.lost_before,
            batch_flags,
            t_ns + self.epoch_offset_ns,
            channels,
            flags,
            holes(raw, flags),
            si if self.want_raw else None,
            outside,
        )


def build_pipeline(
    driver: Driver,
    cfg: DeviceBase,
    calibration: CalibrationModel | None,
    epoch_offset_ns: int,
    resume: tuple[int, int, float | None] | None,
) -> Pipeline:
    """A started device's pipeline: its chip's sample clock, its calibration, the gyro bias
    tracker when enabled, the driver's filter delay."""
    tracking = cfg.gyro_bias_tracking
    spec = registry.CHIPS[cfg.chip]
    dies: DieClocks | None = None
    clock = SampleClock(driver.nominal_period_ns)
    if spec.die_periods is not None:
        periods = spec.die_periods(cfg)
        clocks = [SampleClock(p) for p in periods]
        clock = clocks[spec.time_base]
        # the others' samples are waited for up to a few of their periods and polls
        others = max(p for i, p in enumerate(periods) if i != spec.time_base)
        wait = max(100e6, 3 * others + 4 * driver.poll_interval_ns)
        dies = DieClocks(clocks, Aligner(spec.time_base, len(periods), int(wait)))
    tracker = GyroBiasTracker(tracking) if tracking.enabled else None
    orient = None
    if cfg.orientation.enabled:
        figures = spec.noise(cfg) if spec.noise is not None else None
        noise = noise_model(
            None if figures is None else figures.gyro_density,
            None if figures is None else figures.accel_density,
            None if figures is None else figures.mag_sigma_t,
            cfg.orientation.gyro_bias_walk,
        )
        orient = OrientationStage(cfg.orientation, noise, tracker, tracking)
    return Pipeline(
        clock,
        calibration,
        epoch_offset_ns,
        resume,
        tracker,
        group_delay_ns=driver.group_delay_ns,
        dies=dies,
        orient=orient,
    )
