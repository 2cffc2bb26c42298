"""One device at run time: its lifecycle (start, poll, fail, retry, stop) in its bus worker.

The runner drives the driver, hands what it reads to the device's pipeline and the pipeline's
batches to its emitter (`imud.emit`), and answers for its status (`imud.status.DeviceStatus`).
Counters are plain ints read by the status snapshot from another thread: CPython makes each read
atomic, and status is a snapshot anyway. Nothing a chip, a bus or a driver does (an exception of
any kind included) escapes `step()`: it is counted, shown in status, logged once with its
traceback when unexpected, and retried.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator

from imud import compiled, registry
from imud.backoff import Backoff
from imud.buses.models import describe
from imud.calib.model import CalibrationModel
from imud.calib.track import GyroBiasTracker
from imud.channels import CHANNELS, channels_in
from imud.chips.api import DeviceBase, Driver
from imud.emit import Emitter, Publish
from imud.errors import (
    BUS_ERROR_KEYS,
    BusError,
    DeviceIdentityError,
    ErrorKind,
    RegisterMismatch,
    error_kind,
)
from imud.meters import LatenessMeter, LossLog, RateMeter
from imud.pipeline import Pipeline, build_pipeline
from imud.sim.api import SimChip
from imud.sim.cpu import counted
from imud.status import DeviceState, DeviceStatus
from imud.wire import KIND_TRUTH, encode

log = logging.getLogger("imud.device")

MAX_CONSECUTIVE_FAILURES = 10
RETRY_MIN_NS = 500_000_000
RETRY_MAX_NS = 30_000_000_000
# A device that fails is probed again at most a second later however long it has been down (a
# few bytes a second): a chip that comes back streams again within 1 s.
DEVICE_RETRY_MAX_NS = 1_000_000_000
_EXPECTED = (BusError, DeviceIdentityError, OSError)  # a chip or bus that misbehaves
_GOLDEN = 0.6180339887


def initial_status(cfg: DeviceBase) -> DeviceStatus:
    """A device's status before anything has run."""
    spec = registry.CHIPS[cfg.chip]
    tracking = cfg.gyro_bias_tracking
    return DeviceStatus(
        name=cfg.name,
        chip=cfg.chip,
        bus=" + ".join(describe(b) for b in cfg.die_buses()),
        odr_hz=float(cfg.odr_hz),
        channels=[CHANNELS[c].key for c in channels_in(registry.device_channels(cfg))],
        truth=cfg.publishes_truth,
        chip_counters=dict.fromkeys(spec.counters, 0),
        gyro_bias_tracking=GyroBiasTracker(tracking).status() if tracking.enabled else None,
    )


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
        self._want_raw = False
        self.publish_truth = publish_truth
        self.sim = sim
        self.epoch_offset_ns = epoch_offset_ns
        self.now_ns = now_ns
        self.state = DeviceState.STARTING
        self.last_error: str | None = None
        self.last_error_at: float | None = None  # wall-clock seconds
        self.lost_samples = 0
        self.bus_errors = 0
        self.bus_errors_by_kind = dict.fromkeys(ErrorKind, 0)
        self.restarts = 0
        self.resets = 0  # chip resets detected (a configured register found changed)
        self.unexpected_errors = 0
        self.publish_dropped = 0
        self.emitter = Emitter(cfg.name, epoch_offset_ns, publish, self._note_loss)
        self.rate = RateMeter()
        self.lateness = LatenessMeter()
        self._loss_log = LossLog(cfg.name)
        self._failures = 0
        self._retry = Backoff(RETRY_MIN_NS, DEVICE_RETRY_MAX_NS)
        self.next_due_ns = 0
        self.pipeline: Pipeline | None = None
        self._starting: Iterator[int] | None = None
        self._phase = 0.0
        self._traced: str | None = None  # the unexpected error last logged with its traceback
        self._resume: tuple[int, int, float | None] | None = None

    # --- what the emitter counts --------------------------------------------------------------
    @property
    def publish(self) -> Publish:
        return self.emitter.publish

    @publish.setter
    def publish(self, fn: Publish) -> None:
        self.emitter.publish = fn

    @property
    def publish_raw(self) -> Publish | None:
        return self.emitter.publish_raw

    @publish_raw.setter
    def publish_raw(self, fn: Publish | None) -> None:
        self.emitter.publish_raw = fn

    @property
    def samples(self) -> int:
        return self.emitter.samples

    @property
    def batches(self) -> int:
        return self.emitter.batches

    @property
    def invalid_samples(self) -> int:
        return self.emitter.invalid_samples

    @property
    def temperature_c(self) -> float | None:
        return self.emitter.temperature_c

    @property
    def stream_end(self) -> tuple[int, int] | None:
        return self.emitter.stream_end

    @property
    def measured_rate_hz(self) -> float:
        return self.rate.rate_hz

    # --- settings that change while it runs ---------------------------------------------------
    def set_calibration(self, model: CalibrationModel | None, error: str | None) -> None:
        """A (re)loaded calibration file, or why it cannot be applied (the device then runs
        uncalibrated: its batches say so). Takes effect at the next batch: no seq gap."""
        self.calibration, self.calibration_error = model, error
        if self.pipeline is not None:
            self.pipeline.cal = model
            if self.pipeline.tracker is not None:
                self.pipeline.tracker.reset()
            if self.pipeline.orient is not None:
                self.pipeline.orient.reset_bias()

    def want_raw(self, on: bool) -> None:
        """Someone subscribes to (or left) `<prefix>/<device>/raw`: compute it only then."""
        self._want_raw = on
        if self.pipeline is not None:
            self.pipeline.want_raw = on

    def resume(self, next_seq: int, last_t_ns: int, period_ns: float | None = None) -> None:
        """Continue a stream this device published before (from a bus process that died, or a
        predecessor a reload replaced): `seq` goes on from `next_seq`, and the samples the
        outage held count as lost."""
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

    def _count_bus_error(self, e: BaseException) -> None:
        self.bus_errors += 1
        self.bus_errors_by_kind[error_kind(e)] += 1

    # --- lifecycle --------------------------------------------------------------------------
    def attach(self, driver: Driver, sim: SimChip | None = None) -> None:
        """The bus is open: start this device on it at once."""
        declared = set(registry.CHIPS[self.cfg.chip].counters)
        if set(driver.counters.chip) != declared:
            raise TypeError(
                f"{self.cfg.chip}: its driver counts {sorted(driver.counters.chip)}, its spec "
                f"declares {sorted(declared)} (ChipSpec.counters): the two must be equal"
            )
        self.driver, self.sim = driver, sim
        self.state = DeviceState.STARTING
        self.next_due_ns = 0
        compiled.warn_missing()  # (its driver's module is imported by now)

    def bus_down(self, msg: str, retry_ns: int) -> None:
        """The bus (or this device's link on it) will not open; the worker retries it."""
        if self.last_error != msg:
            log.error("%s: %s; retrying in %.1f s", self.cfg.name, msg, retry_ns / 1e9)
        self.state = DeviceState.ERROR
        self._error(msg)
        self.rate.idle()

    def _fail(self, msg: str, now: int) -> None:
        wait = self._retry.failed(now)
        if self.state != DeviceState.ERROR or self.last_error != msg:
            log.error("%s: %s; retrying in %.1f s", self.cfg.name, msg, wait / 1e9)
        self.state = DeviceState.ERROR
        self._error(msg)
        self.next_due_ns = now + wait
        self.rate.idle()

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
            self.pipeline = build_pipeline(
                self.driver, self.cfg, self.calibration, self.epoch_offset_ns, self._resume
            )
            self.pipeline.want_raw = self._want_raw
        else:
            self.pipeline.restarted()  # a re-initialised chip restarts its sample grid
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
        self.emitter.flush()  # what is held goes out before the stream ends
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
            raw = self.driver.read()
            assert self.pipeline is not None
            batches = self.pipeline.run(raw)
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
            self.emitter.emit(batch, now)
        self.emitter.flush_due(now)
        self._publish_truth()
        self.rate.update(now, self.emitter.samples)

    def _read_failed(self, msg: str, now: int) -> None:
        self._failures += 1
        self._error(msg)
        if self._failures > MAX_CONSECUTIVE_FAILURES:
            self.restarts += 1
            self._fail(f"{self._failures} failed reads in a row, last: {msg}", now)

    def _note_loss(self, lost: int, now: int) -> None:
        self.lost_samples += lost
        c = self.driver.counters if self.driver is not None else None
        self._loss_log.note(
            lost, self.lost_samples, now, c.fifo_overflows if c else 0, self.bus_errors
        )

    def note_publish_drop(self) -> None:
        """The way to the publisher was full (a subscriber stuck for seconds): a batch is gone."""
        self.publish_dropped += 1

    def note_lateness(self, late_ns: int, now: int) -> None:
        self.lateness.note(late_ns, now)

    def _poll_delay(self) -> int:
        """Poll interval plus a golden-ratio fraction of a sample period: read instants then
        sweep every phase of the chip's sample clock, which is what pins its timing down (a
        poll interval near a whole number of periods would otherwise see one phase forever)."""
        assert self.driver is not None
        self._phase = (self._phase + _GOLDEN) % 1.0
        return self.driver.poll_interval_ns + int(self._phase * self.driver.nominal_period_ns)

    def _publish_truth(self) -> None:
        """The simulator's true samples since the last read. All of it counts as the
        simulator's CPU, its encoding and sending too: silicon has no truth to send."""
        if self.sim is not None and self.publish_truth is not None:
            counted(self._send_truth)()

    def _send_truth(self) -> None:
        assert self.sim is not None and self.publish_truth is not None
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

    # --- status -----------------------------------------------------------------------------
    def status(self) -> DeviceStatus:
        st = initial_status(self.cfg)
        st.state = self.state
        st.measured_rate_hz = round(self.rate.rate_hz, 3)
        st.poll_late_max_ms = round(self.lateness.max_ns / 1e6, 3)
        e = self.emitter
        st.samples, st.invalid_samples = e.samples, e.invalid_samples
        st.uncertain_gaps = e.uncertain_gaps
        st.calibration_outside_span = e.calibration_outside_span
        st.temperature_c = None if e.temperature_c is None else round(e.temperature_c, 2)
        st.lost_samples = self.lost_samples
        st.bus_errors = self.bus_errors
        for kind, n in self.bus_errors_by_kind.items():
            setattr(st, BUS_ERROR_KEYS[kind], n)
        st.restarts, st.resets = self.restarts, self.resets
        st.unexpected_errors, st.publish_dropped = self.unexpected_errors, self.publish_dropped
        st.calibration = str(self.calibration.path) if self.calibration else None
        st.calibration_error = self.calibration_error
        st.raw_subscribed = self._want_raw
        st.last_error, st.last_error_at = self.last_error, self.last_error_at
        if self.pipeline is not None:
            st.chip_rate_hz = round(self.pipeline.rate_hz, 3)
            if self.pipeline.tracker is not None:
                st.gyro_bias_tracking = self.pipeline.tracker.status()
            if self.pipeline.orient is not None:
                st.orientation = self.pipeline.orient.status()
        if self.driver is not None:
            c = self.driver.counters
            st.fifo_overflows, st.fifo_resets = c.fifo_overflows, c.fifo_resets
            st.soft_resets, st.bad_registers = c.soft_resets, c.bad_registers
            st.garbled_transfers = c.bad_transfers
            st.chip_counters = dict(c.chip)
            try:
                st.chip_status = self.driver.chip_status()
            except Exception as e:  # a status snapshot must never fail
                st.chip_status = {"error": f"{type(e).__name__}: {e}"}
        return st
