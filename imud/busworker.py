"""One bus, its devices, one blocking loop: open the bus, connect and start each device, poll
whichever is due next.

Devices on one bus are served in turn by one worker (`imud.buschild` runs it, in a process of its
own or a thread of the daemon's), so their transfers never interleave and the event loop never
waits on a bus. A bus that will not open, a device that will not connect or start, a driver that
raises: each is retried with backoff (`imud.backoff`) and shown in that device's status, and none
of them stops the loop or the bus's other devices.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from imud.backoff import Backoff
from imud.buses.models import I2cBus, SimBus
from imud.busmsg import Stream
from imud.calib.watch import CalibrationWatcher
from imud.chips.api import DeviceBase, Driver
from imud.clock import Clock
from imud.device import RETRY_MAX_NS, RETRY_MIN_NS, DeviceRunner
from imud.emit import Publish
from imud.reload import Action, BusPlan
from imud.rt import go_realtime
from imud.sim.api import SimChip
from imud.status import DeviceState

log = logging.getLogger("imud.bus")

Connect = Callable[[Any], tuple[Driver, SimChip | None]]
# where a runner's batches go: (its index on the bus, which stream, what to call when the way
# is full) -> the function it publishes with
Outlet = Callable[[int, Stream, Callable[[], None]], Publish]
MAX_WAIT_NS = 1_000_000_000  # wake at least this often, so the heartbeat stays fresh
SHORT_FIFO_NS = 20_000_000  # a FIFO that lasts less than this needs real-time scheduling


@dataclass
class BusWorker:
    """Owns one bus: opens it (and reopens it with backoff while it will not open), then runs
    its devices' start/poll steps in turn, sleeping until the next one is due."""

    key: str
    runners: list[DeviceRunner]
    connectors: list[Connect]  # per runner: open bus -> (driver, simulator or None)
    opener: Callable[[], Any]
    clock: Clock
    realtime_priority: int | None = None
    stop: threading.Event = field(default_factory=threading.Event)
    heartbeat_ns: int = 0
    bus: Any = None
    realtime: bool = False
    reopen: Backoff = field(default_factory=lambda: Backoff(RETRY_MIN_NS, RETRY_MAX_NS))
    calibrations: CalibrationWatcher | None = None
    outlet: Outlet | None = None  # set by `build_worker`: where runners publish
    epoch_offset_ns: int = 0
    # bumped each time the device list changes; status reports and acknowledgements carry it
    generation: int = 0
    on_reconfigured: Callable[[BusWorker], None] | None = None
    _pending: BusPlan | None = None
    _pending_lock: threading.Lock = field(default_factory=threading.Lock)

    # --- runners --------------------------------------------------------------------------------
    def make_runner(self, index: int, d: DeviceBase) -> DeviceRunner:
        runner = DeviceRunner(
            d, None, None, _nowhere, self.epoch_offset_ns, now_ns=self.clock.now_ns
        )
        self.bind(index, runner)
        return runner

    def bind(self, index: int, runner: DeviceRunner) -> None:
        """Point a runner's streams at its index on this bus (it moves when a reload changes
        the device list)."""
        if self.outlet is None:
            return
        drop = runner.note_publish_drop
        runner.publish = self.outlet(index, Stream.DATA, drop)
        runner.publish_raw = self.outlet(index, Stream.RAW, drop)
        truth = runner.cfg.publishes_truth
        runner.publish_truth = self.outlet(index, Stream.TRUTH, _ignore) if truth else None

    # --- reload -------------------------------------------------------------------------------
    def reconfigure(self, plan: BusPlan) -> None:
        """A reload's plan for this bus (safe from any thread): applied by the worker between
        two steps, so no transfer is cut and no batch of a kept device is lost."""
        with self._pending_lock:
            self._pending = plan

    def _apply_pending(self) -> None:
        with self._pending_lock:
            plan, self._pending = self._pending, None
        if plan is None:
            return
        old = list(zip(self.runners, self.connectors, strict=True))
        runners: list[DeviceRunner] = []
        connectors: list[Connect] = []
        for index, slot in enumerate(plan.slots):
            d = slot.device
            if slot.action is Action.KEEP:
                assert slot.was is not None
                r, conn = old[slot.was]  # unchanged: it goes on streaming, its chip untouched
                self.bind(index, r)
            else:
                r, conn = self.make_runner(index, d), connector(d, self.clock)
                if slot.action is Action.RESTART:  # its stream's seq continues
                    assert slot.was is not None
                    prev = old[slot.was][0]
                    prev.stop()
                    if prev.stream_end is not None:
                        r.resume(*prev.stream_end)
                    log.info("%s: restarting with its new settings", d.name)
                else:
                    log.info("%s: added", d.name)
            runners.append(r)
            connectors.append(conn)
        for i in plan.removed:
            old[i][0].stop()
            log.info("%s: removed", old[i][0].cfg.name)
        self.runners, self.connectors = runners, connectors
        self.generation += 1
        if self.calibrations is not None:
            self.calibrations.watch(list(runners))
        if self.on_reconfigured is not None:
            self.on_reconfigured(self)

    # --- the loop -----------------------------------------------------------------------------
    def _bus_failed(self, e: Exception, now: int) -> None:
        wait = self.reopen.failed(now)
        for r in self.runners:
            msg = str(e) if isinstance(e, OSError) else r.unexpected(f"open {self.key}", e)
            r.bus_down(msg, wait)

    def _warn_short_fifo(self, r: DeviceRunner, driver: Driver) -> None:
        span_ns = driver.fifo_capacity * driver.nominal_period_ns
        if span_ns < SHORT_FIFO_NS and not self.realtime:
            log.warning(
                "%s: its FIFO holds %.1f ms of samples (%d at %g Hz): an ordinary scheduler delay "
                "can overflow it; set [daemon] realtime_priority (e.g. 20) and grant it",
                r.cfg.name,
                span_ns / 1e6,
                driver.fifo_capacity,
                r.cfg.odr_hz,
            )

    def ensure_bus(self, now: int) -> bool:
        """Open the bus, then connect each device not yet connected (an SPI device opens its
        own chip select). Failures retry with backoff. True when some device can be served."""
        pending = [i for i, r in enumerate(self.runners) if r.driver is None]
        if pending and self.reopen.ready(now):
            if self.bus is None:
                try:
                    self.bus = self.opener()
                except Exception as e:
                    self._bus_failed(e, now)
                    return False
            failed = False
            for i in pending:
                r = self.runners[i]
                try:
                    driver, sim = self.connectors[i](self.bus)
                    r.attach(driver, sim)
                except Exception as e:
                    msg = str(e) if isinstance(e, OSError) else r.unexpected("connect", e)
                    r.bus_down(msg, self.reopen.wait_ns)
                    failed = True
                    continue
                self._warn_short_fifo(r, driver)
            if failed:
                self.reopen.failed(now)
            else:
                self.reopen.reset()
        return any(r.driver is not None for r in self.runners)

    def run_once(self) -> int:
        """One scheduling decision: run the step that is due, or say how long to wait (ns)."""
        if self._pending is not None:
            self._apply_pending()
        now = self.clock.now_ns()
        self.heartbeat_ns = now
        if not self.runners:  # every device of this bus removed by a reload
            return MAX_WAIT_NS
        if not self.ensure_bus(now):
            return max(1, min(self.reopen.due_ns - now, MAX_WAIT_NS))
        due = min((r for r in self.runners if r.driver is not None), key=lambda r: r.next_due_ns)
        wake = due.next_due_ns
        if wake > now:
            if self.reopen.pending:  # devices still to connect: wake for their retry too
                wake = min(wake, self.reopen.due_ns)
            return max(1, min(wake - now, MAX_WAIT_NS))
        if due.state == DeviceState.RUNNING:
            due.note_lateness(now - due.next_due_ns, now)
        try:
            due.step()
        except Exception as e:  # step() catches everything; this only guards against its bugs
            due.unexpected("step", e)
            due.state = DeviceState.ERROR
            due.next_due_ns = self.clock.now_ns() + RETRY_MIN_NS
        return 0

    def run(self) -> None:
        """Blocking loop until `stop` is set; then the devices are put to sleep."""
        thread = threading.current_thread()
        name, thread.name = thread.name, f"bus {self.key}"
        if self.realtime_priority:
            self.realtime = go_realtime(self.realtime_priority, f"bus {self.key} worker")
        if self.calibrations is not None:
            self.calibrations.start(self.stop)
        try:
            while not self.stop.is_set():
                wait = self.run_once()
                if wait > 0:
                    self.stop.wait(wait / 1e9)
            for r in self.runners:
                r.stop()
        finally:
            thread.name = name


def _nowhere(_: bytes) -> None:
    """A runner's publish before `bind` points it somewhere."""


def _ignore() -> None:
    """A truth batch that found the way full: truth is for tests, not counted."""


class _ChipSelects:
    """An SPI bus as a whole, or a serial port: nothing shared to open; each device opens its
    own chip select or port."""


def opener(d: DeviceBase) -> Callable[[], Any]:
    """What opens the bus this device is on (shared by every device on it)."""
    bus = d.bus
    if isinstance(bus, SimBus) and bus.transport == "i2c":
        from imud.sim.i2c import SimI2CBus

        seed = d.sim.seed if d.sim else 0
        return lambda: SimI2CBus(seed=seed)
    if isinstance(bus, I2cBus):
        from imud.buses.i2c import open_smbus

        return lambda: open_smbus(bus)
    return _ChipSelects


def connector(d: DeviceBase, clock: Clock) -> Connect:
    """Device on an open bus -> (driver, simulator or None)."""
    from imud.wiring import connect

    return lambda shared: connect(d, shared, clock)


def build_worker(
    key: str,
    devices: list[DeviceBase],
    clock: Clock,
    epoch_offset_ns: int,
    outlet: Outlet,
    realtime_priority: int | None = None,
) -> BusWorker:
    """The worker of bus `key` and its devices (in config order), publishing through `outlet`.
    The bus opens in the worker's own loop."""
    w = BusWorker(key, [], [], opener(devices[0]), clock, realtime_priority)
    w.outlet, w.epoch_offset_ns = outlet, epoch_offset_ns
    for d in devices:
        w.runners.append(w.make_runner(len(w.runners), d))
        w.connectors.append(connector(d, clock))
    w.calibrations = CalibrationWatcher(list(w.runners))
    w.calibrations.check()  # before the first sample: it is calibrated from the start
    return w
