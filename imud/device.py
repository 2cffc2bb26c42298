"""One device at run time: driver + pipeline + publishers + health counters.

Everything here runs in the device's bus worker. Counters are plain ints read by the status
snapshot from another thread: CPython makes each read atomic, and status is a snapshot anyway.
Nothing a chip, a bus or a driver does (an exception of any kind included) escapes `step()`: it
is counted, shown in status, logged once with its traceback when unexpected, and retried.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

from imud.backoff import Backoff
from imud.buses.models import describe
from imud.calib.model import CalibrationModel
from imud.calib.track import GyroBiasTracker
from imud.channels import INVALID_MASK, Channel
from imud.chips.api import DeviceBase, Driver, RawBatch, SimChip
from imud.errors import (
    BUS_ERROR_KEYS,
    BusError,
    DeviceIdentityError,
    ErrorKind,
    RegisterMismatch,
    error_kind,
)
from imud.pipeline import Pipeline, SampleBatch
from imud.status import DeviceState, initial_status
from imud.timestamps import SampleClock
from imud.wire import FLAG_CALIBRATED, FLAG_RESYNC, KIND_TRUTH, encode

log = logging.getLogger("imud.device")

Publish = Callable[[bytes], None]
MAX_CONSECUTIVE_FAILURES = 10
RETRY_MIN_NS = 500_000_000
RETRY_MAX_NS = 30_000_000_000
# A device that fails is probed again at most a second later however long it has been down (a
# few bytes a second): a chip that comes back streams again within 1 s.
DEVICE_RETRY_MAX_NS = 1_000_000_000
LOSS_LOG_EVERY_NS = 10_000_000_000
_EXPECTED = (BusError, DeviceIdentityError, OSError)  # a chip or bus that misbehaves


def _runs(hole: npt.NDArray[np.bool_] | None, n: int) -> list[tuple[int, int]]:
    """[start, end) of each run of publishable samples; the whole batch when there are no
    holes."""
    if hole is None:
        return [(0, n)] if n else []
    edges = np.flatnonzero(np.diff(np.concatenate(([True], hole, [True])).astype(np.int8)))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


class DeviceRunner:
    def __init__(
        self,
        cfg: DeviceBase,
        driver: Driver | None,
        calibration: CalibrationModel | None,
        publish: Publish,
        epoch_offset_ns: int,
        *,
        sim: SimChip | None = None,
        publish_truth: Publish | None = None,
        now_ns: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.cfg = cfg
        self.driver = driver
        self.calibration = calibration
        self.calibration_error: str | None = None
        self.calibration_outside_span = 0  # samples whose temperature correction was clamped
        self.publish = publish
        self.publish_raw: Publish | None = None  # the uncorrected stream, while subscribed
        self._want_raw = False
        self.publish_truth = publish_truth
        self.sim = sim
        self.epoch_offset_ns = epoch_offset_ns
        self.now_ns = now_ns
        self.state = DeviceState.STARTING
        self.last_error: str | None = None
        self.last_error_at: float | None = None  # wall-clock seconds
        self.samples = 0
        self.lost_samples = 0
        self.invalid_samples = 0
        self.bus_errors = 0
        self.bus_errors_by_kind = dict.fromkeys(ErrorKind, 0)
        self.restarts = 0
        self.resets = 0  # chip resets detected (a configured register found changed)
        self.unexpected_errors = 0
        self.batches = 0
        self.temperature_c: float | None = None
        self.measured_rate_hz = 0.0
        self._rate_window: deque[tuple[int, int]] = deque()
        self._failures = 0
        self._retry = Backoff(RETRY_MIN_NS, DEVICE_RETRY_MAX_NS)
        self.next_due_ns = 0
        self.pipeline: Pipeline | None = None
        self._starting: Iterator[int] | None = None
        self._phase = 0.0
        self.poll_late_max_ns = 0
        self.publish_dropped = 0
        self._late_cur_ns = 0
        self._late_window_ns = 0
        self._unpublished_lost = 0
        self._loss_unlogged = 0
        self._loss_logged_ns = -(10**12)
        self._traced: str | None = None  # the unexpected error last logged with its traceback
        self._resume: tuple[int, int, float | None] | None = None
        # (next seq, last stamp less the epoch offset) of what was published: where a
        # successor (this device restarted with new settings by a reload) continues
        self.stream_end: tuple[int, int] | None = None

    def set_calibration(self, model: CalibrationModel | None, error: str | None) -> None:
        """A (re)loaded calibration file, or why it cannot be applied (the device then runs
        uncalibrated: its batches say so). Takes effect at the next batch: no seq gap."""
        self.calibration, self.calibration_error = model, error
        if self.pipeline is not None:
            self.pipeline.cal = model
            if self.pipeline.tracker is not None:
                self.pipeline.tracker.reset()

    def want_raw(self, on: bool) -> None:
        """Someone subscribes to (or left) `<prefix>/<device>/raw`: compute it only then."""
        self._want_raw = on
        if self.pipeline is not None:
            self.pipeline.want_raw = on

    def resume(self, next_seq: int, last_t_ns: int, period_ns: float | None = None) -> None:
        """Continue a stream this device published before (from a bus process that died):
        `seq` goes on from `next_seq`, and the samples the outage held count as lost."""
        self._resume = (next_seq, last_t_ns, period_ns)

    # --- errors -----------------------------------------------------------------------------
    def _error(self, msg: str) -> None:
        self.last_error = msg
        self.last_error_at = time.time()

    def unexpected(self, where: str, e: BaseException) -> str:
        """An exception no driver should raise (a bug, an answer nobody expected): counted, and
        logged with its traceback once per distinct message, not on every retry."""
        self.unexpected_errors += 1
        msg = f"{where}: unexpected {type(e).__name__}: {e}"
        if msg != self._traced:
            log.error("%s: %s (logged once; see the traceback)", self.cfg.name, msg, exc_info=e)
            self._traced = msg
        self._error(msg)
        return msg

    # --- lifecycle --------------------------------------------------------------------------
    def attach(self, driver: Driver, sim: SimChip | None = None) -> None:
        """The bus is open: start this device on it at once."""
        self.driver, self.sim = driver, sim
        self.state = DeviceState.STARTING
        self.next_due_ns = 0

    def bus_down(self, msg: str, retry_ns: int) -> None:
        """The bus (or this device's link on it) will not open; the worker retries it."""
        if self.last_error != msg:
            log.error("%s: %s; retrying in %.1f s", self.cfg.name, msg, retry_ns / 1e9)
        self.state = DeviceState.ERROR
        self._error(msg)
        self._idle()

    def _idle(self) -> None:
        self.measured_rate_hz = 0.0
        self._rate_window.clear()

    def _fail(self, msg: str, now: int) -> None:
        wait = self._retry.failed(now)
        if self.state != DeviceState.ERROR or self.last_error != msg:
            log.error("%s: %s; retrying in %.1f s", self.cfg.name, msg, wait / 1e9)
        self.state = DeviceState.ERROR
        self._error(msg)
        self.next_due_ns = now + wait
        self._idle()

    def _start(self, now: int) -> None:
        """Advance the driver's start sequence by one step; the bus is free between steps."""
        assert self.driver is not None
        try:
            if self._starting is None:
                self._starting = self.driver.start()
            wait = next(self._starting)
            # from the end of the step: its last write (e.g. a reset) starts the chip's delay
            self.next_due_ns = self.now_ns() + wait
            return
        except StopIteration:
            self._starting = None
        except _EXPECTED as e:
            self._starting = None
            if isinstance(e, BusError):
                self._count_bus_error(e)
            self._fail(f"start failed: {e}", self.now_ns())
            return
        except Exception as e:
            self._starting = None
            self._fail(self.unexpected("start", e), self.now_ns())
            return
        if self.pipeline is None:
            clock = SampleClock(self.driver.nominal_period_ns)
            tracking = self.cfg.gyro_bias_tracking
            tracker = GyroBiasTracker(tracking) if tracking.enabled else None
            self.pipeline = Pipeline(
                clock,
                self.calibration,
                self.epoch_offset_ns,
                self._resume,
                tracker,
                group_delay_ns=self.driver.group_delay_ns,
            )
            self.pipeline.want_raw = self._want_raw
        elif self.pipeline.clock.k_last >= 0:
            # a re-initialised chip restarts its sample grid; keep seq counting across it
            self.pipeline.clock.rebase()
        if self.state == DeviceState.ERROR:
            log.warning("%s: recovered after: %s", self.cfg.name, self.last_error)
        else:
            log.info(
                "%s: %s on %s running at %g Hz",
                self.cfg.name,
                self.cfg.chip,
                " + ".join(describe(b) for b in self.cfg.die_buses()),
                self.cfg.odr_hz,
            )
        self.state = DeviceState.RUNNING
        self._failures = 0
        self._retry.reset()
        self.next_due_ns = self.now_ns() + self.driver.poll_interval_ns

    def stop(self) -> None:
        if self.driver is not None and self.state == DeviceState.RUNNING:
            try:
                self.driver.stop()
            except Exception as e:  # best effort: the daemon is stopping anyway
                self.unexpected("stop", e)
        self.state = DeviceState.STOPPED

    # --- one scheduling step ------------------------------------------------------------------
    def step(self) -> None:
        """Start, retry or poll, whichever is due. Never raises for chip, bus or driver trouble."""
        now = self.now_ns()
        if self.driver is None:
            self.next_due_ns = now + RETRY_MAX_NS
            return
        if self.state != DeviceState.RUNNING:
            self._start(now)
            return
        self.next_due_ns = now + self._poll_delay()
        try:
            raw: RawBatch | None = self.driver.read()
            assert self.pipeline is not None
            batches = []
            while raw is not None:
                batches.append(self.pipeline.process(raw))
                raw = raw.then
        except RegisterMismatch as e:
            self.restarts += 1
            self.resets += 1
            self._error(str(e))
            log.warning("%s: %s", self.cfg.name, e)
            self.state = DeviceState.STARTING
            self._start(now)
            return
        except _EXPECTED as e:
            self._count_bus_error(e)
            self._read_failed(f"bus error: {e}", now)
            return
        except Exception as e:
            self._read_failed(self.unexpected("read", e), now)
            return
        self._failures = max(0, self._failures - 1)
        wanted = self.driver.next_poll_ns
        if wanted is not None:
            self.next_due_ns = wanted
        for batch in batches:
            self._publish(batch, now)
        self._publish_truth()
        self._update_rate(now)

    def _count_bus_error(self, e: BaseException) -> None:
        self.bus_errors += 1
        self.bus_errors_by_kind[error_kind(e)] += 1

    def _read_failed(self, msg: str, now: int) -> None:
        self._failures += 1
        self._error(msg)
        if self._failures > MAX_CONSECUTIVE_FAILURES:
            self.restarts += 1
            self._fail(f"{self._failures} failed reads in a row, last: {msg}", now)

    def _publish(self, batch: SampleBatch, now: int) -> None:
        if batch.lost_before:
            self._note_loss(batch.lost_before, now)
        self.calibration_outside_span += batch.outside_span
        run_end = 0
        whole = batch.hole is None
        runs = ((0, batch.n),) if whole and batch.n else _runs(batch.hole, batch.n)
        for start, end in runs:
            if start > run_end:  # samples with no valid data at all are holes: lost
                self._note_loss(start - run_end, now)
            sf = batch.sample_flags
            if sf is not None and not whole:
                sf = sf[start:end]
            chans = (
                batch.channels if whole else {c: a[start:end] for c, a in batch.channels.items()}
            )
            t_ns = batch.t_ns if whole else batch.t_ns[start:end]
            flags = batch.flags | (FLAG_RESYNC if self._unpublished_lost else 0)
            lost, seq = self._unpublished_lost, batch.first_seq + start
            self.publish(encode(self.cfg.name, seq, t_ns, chans, sf, flags=flags, lost_before=lost))
            if batch.raw is not None and self.publish_raw is not None:
                raw = batch.raw if whole else {c: a[start:end] for c, a in batch.raw.items()}
                uncorrected = flags & ~FLAG_CALIBRATED
                self.publish_raw(
                    encode(self.cfg.name, seq, t_ns, raw, sf, flags=uncorrected, lost_before=lost)
                )
            self._unpublished_lost = 0
            self.stream_end = (seq + end - start, int(t_ns[-1]) - self.epoch_offset_ns)
            run_end = end
            self.samples += end - start
            self.batches += 1
            if sf is not None:
                self.invalid_samples += int(np.count_nonzero(sf & INVALID_MASK))
            temp = chans.get(Channel.TEMPERATURE)
            if temp is not None:
                t = float(temp[-1])
                if t == t:  # not NaN
                    self.temperature_c = t
        if batch.n and run_end < batch.n:
            self._note_loss(batch.n - run_end, now)

    def _note_loss(self, lost: int, now: int) -> None:
        """Count lost samples, carry them to the next published batch, and say so in the log
        (at most every 10 s per device, with what was lost meanwhile)."""
        self.lost_samples += lost
        self._unpublished_lost += lost
        self._loss_unlogged += lost
        if now - self._loss_logged_ns >= LOSS_LOG_EVERY_NS:
            c = self.driver.counters if self.driver is not None else None
            log.warning(
                "%s: %d samples lost since the last report (%d in all; FIFO overflows %d, "
                "bus errors %d)",
                self.cfg.name,
                self._loss_unlogged,
                self.lost_samples,
                c.fifo_overflows if c else 0,
                self.bus_errors,
            )
            self._loss_unlogged, self._loss_logged_ns = 0, now

    def note_publish_drop(self) -> None:
        """The way to the publisher was full (a subscriber stuck for seconds): a batch is gone."""
        self.publish_dropped += 1

    def note_lateness(self, late_ns: int, now: int) -> None:
        """How late the bus worker came to this device's poll; the worst over ~10 s is shown
        in status: the scheduling jitter the FIFO has to absorb."""
        if now - self._late_window_ns > 10_000_000_000:
            self.poll_late_max_ns, self._late_window_ns = self._late_cur_ns, now
            self._late_cur_ns = 0
        self._late_cur_ns = max(self._late_cur_ns, late_ns)
        self.poll_late_max_ns = max(self.poll_late_max_ns, late_ns)

    def _poll_delay(self) -> int:
        """Poll interval plus a golden-ratio fraction of a sample period: read instants then
        sweep every phase of the chip's sample clock, which is what pins its timing down (a
        poll interval near a whole number of periods would otherwise see one phase forever)."""
        assert self.driver is not None
        self._phase = (self._phase + 0.6180339887) % 1.0
        return self.driver.poll_interval_ns + int(self._phase * self.driver.nominal_period_ns)

    def _publish_truth(self) -> None:
        if self.sim is None or self.publish_truth is None:
            return
        t = self.sim.drain_truth()
        if t is not None:
            self.publish_truth(
                encode(
                    self.cfg.name,
                    t.index,
                    t.t_ns + self.epoch_offset_ns,
                    t.channels,
                    kind=KIND_TRUTH,
                )
            )

    def _update_rate(self, now: int, window_ns: int = 5_000_000_000) -> None:
        """Delivered samples per second over the last ~5 s, from one point per 100 ms (a
        point per poll would keep thousands of tuples alive for the GC to walk at 32 kHz)."""
        w = self._rate_window
        if w and now - w[-1][0] < 100_000_000:
            return
        w.append((now, self.samples))
        while len(w) > 2 and now - w[1][0] >= window_ns:
            w.popleft()
        if len(w) >= 2 and now > w[0][0]:
            self.measured_rate_hz = (w[-1][1] - w[0][1]) * 1e9 / (now - w[0][0])

    # --- status -----------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        c = self.driver.counters if self.driver is not None else None
        chip: dict[str, Any] = {}
        if self.driver is not None:
            try:
                chip = self.driver.chip_status()
            except Exception as e:  # a status snapshot must never fail
                chip = {"error": f"{type(e).__name__}: {e}"}
        return {
            **initial_status(self.cfg),
            "state": self.state,
            "measured_rate_hz": round(self.measured_rate_hz, 3),
            "chip_rate_hz": round(self.pipeline.rate_hz, 3) if self.pipeline else None,
            "samples": self.samples,
            "lost_samples": self.lost_samples,
            "invalid_samples": self.invalid_samples,
            "fifo_overflows": c.fifo_overflows if c else 0,
            "bus_errors": self.bus_errors,
            **{BUS_ERROR_KEYS[k]: n for k, n in self.bus_errors_by_kind.items()},
            # frames the driver read whole but found corrupt (CRC, checksum, garbled framing);
            # of them, those a CRC or a checksum caught
            "garbled_transfers": c.bad_transfers if c else 0,
            "crc_errors": c.crc_errors if c else 0,
            "checksum_errors": c.checksum_errors if c else 0,
            "bad_registers": c.bad_registers if c else 0,
            "restarts": self.restarts,
            "resets": self.resets,
            "unexpected_errors": self.unexpected_errors,
            "poll_late_max_ms": round(self.poll_late_max_ns / 1e6, 3),
            "publish_dropped": self.publish_dropped,
            "temperature_c": None if self.temperature_c is None else round(self.temperature_c, 2),
            "calibration": str(self.calibration.path) if self.calibration else None,
            "calibration_error": self.calibration_error,
            "calibration_outside_span": self.calibration_outside_span,
            "raw_subscribed": self._want_raw,
            "gyro_bias_tracking": (
                self.pipeline.tracker.status()
                if self.pipeline is not None and self.pipeline.tracker is not None
                else initial_status(self.cfg)["gyro_bias_tracking"]
            ),
            "last_error": self.last_error,
            "last_error_at": self.last_error_at,
            "chip_status": chip,
        }
