"""One bus, its devices, one blocking loop: open the bus, connect and start each device, poll
whichever is due next.

Devices on one bus are served in turn by one worker (a thread here, in its own process by
default: `imud.buschild`), so their transfers never interleave and the event loop never waits on
a bus. A bus that will not open, a device that will not connect or start, a driver that raises:
each is retried with backoff (`imud.backoff`) and shown in that device's status, and none of them
stops the loop or the bus's other devices.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from imud.backoff import Backoff
from imud.buses.models import I2cBus, SerialBus, SimBus, SpiBus
from imud.busmsg import KIND_DATA, KIND_RAW, KIND_TRUTH
from imud.calib.watch import CalibrationWatcher
from imud.chips.api import DeviceBase, Driver, SimChip
from imud.clock import Clock
from imud.config import ImudConfig
from imud.device import RETRY_MAX_NS, RETRY_MIN_NS, DeviceRunner, Publish
from imud.rt import go_realtime
from imud.status import DeviceState

log = logging.getLogger("imud.bus")

Connect = Callable[[Any], tuple[Driver, SimChip | None]]
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
    # what makes a new runner (a reloaded config adds or changes a device on this bus)
    make_runner: Callable[[int, DeviceBase], DeviceRunner] | None = None
    rebind: Callable[[int, DeviceRunner], None] | None = None
    # bumped each time the device list changes; a bus process's status and acks carry it
    generation: int = 0
    on_reconfigured: Callable[[BusWorker], None] | None = None
    _pending: list[DeviceBase] | None = None
    _pending_lock: threading.Lock = field(default_factory=threading.Lock)

    def reconfigure(self, devices: list[DeviceBase]) -> None:
        """A reloaded config's devices for this bus (safe from any thread): applied by the
        worker between two steps, so no transfer is cut and no batch of a kept device is lost."""
        with self._pending_lock:
            self._pending = list(devices)

    def _apply_pending(self) -> None:
        with self._pending_lock:
            devices, self._pending = self._pending, None
        if devices is None:
            return
        assert self.make_runner is not None and self.rebind is not None
        old = {r.cfg.name: (r, c) for r, c in zip(self.runners, self.connectors, strict=True)}
        runners: list[DeviceRunner] = []
        connectors: list[Connect] = []
        for index, d in enumerate(devices):
            kept = old.pop(d.name, None)
            if kept is not None and kept[0].cfg == d:
                r, conn = kept  # unchanged: it goes on streaming, its chip untouched
                self.rebind(index, r)
            else:
                r, conn = self.make_runner(index, d), connector(d, self.clock)
                if kept is not None:  # changed: restart it, its stream's seq continuing
                    kept[0].stop()
                    if kept[0].stream_end is not None:
                        r.resume(*kept[0].stream_end)
                    log.info("%s: restarting with its new settings", d.name)
                else:
                    log.info("%s: added", d.name)
            runners.append(r)
            connectors.append(conn)
        for r, _ in old.values():
            r.stop()
            log.info("%s: removed", r.cfg.name)
        self.runners, self.connectors = runners, connectors
        self.generation += 1
        if self.calibrations is not None:
            self.calibrations.watch(list(runners))
        if self.on_reconfigured is not None:
            self.on_reconfigured(self)

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
                except Exception as e:
                    msg = str(e) if isinstance(e, OSError) else r.unexpected("connect", e)
                    r.bus_down(msg, self.reopen.wait_ns)
                    failed = True
                    continue
                r.attach(driver, sim)
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


class _ChipSelects:
    """An SPI bus as a whole, or a serial port: nothing shared to open; each device opens its
    own chip select or port."""


def opener(d: DeviceBase) -> Callable[[], Any]:
    """What opens the bus this device is on (shared by every device on it)."""
    from imud.buses.i2c import open_smbus
    from imud.sim.i2c import SimI2CBus

    bus = d.bus
    if isinstance(bus, SimBus) and bus.transport == "i2c":
        return lambda: SimI2CBus(seed=d.sim.seed if d.sim else 0)
    if isinstance(bus, I2cBus):
        return lambda: open_smbus(bus)
    assert isinstance(bus, SpiBus | SimBus | SerialBus)
    return _ChipSelects


def connector(d: DeviceBase, clock: Clock) -> Connect:
    """Device on an open bus -> (driver, simulator or None)."""
    from imud.buses.connect import connect

    return lambda shared: connect(d, shared, clock)


PublishFor = Callable[[int, DeviceBase, int, Callable[[], None]], Publish]


def build_workers(
    cfg: ImudConfig,
    clock: Clock,
    offset_ns: int,
    publish_for: PublishFor,
    only_bus: str | None = None,
) -> list[BusWorker]:
    """One worker per bus, one runner per device. Buses open in their workers.

    `publish_for(index on its bus, device, kind (imud.busmsg KIND_*), on_drop)` gives each
    runner its publish callables (a queue to the Zenoh publisher thread, or the socket to the
    daemon process)."""
    workers: dict[str, BusWorker] = {}

    def make_runner(index: int, d: DeviceBase) -> DeviceRunner:
        runner = DeviceRunner(d, None, None, lambda _: None, offset_ns, now_ns=clock.now_ns)
        rebind(index, runner)
        return runner

    def rebind(index: int, runner: DeviceRunner) -> None:
        d = runner.cfg
        runner.publish = publish_for(index, d, KIND_DATA, runner.note_publish_drop)
        runner.publish_raw = publish_for(index, d, KIND_RAW, runner.note_publish_drop)
        truth = isinstance(d.bus, SimBus) and d.sim is not None and d.sim.truth
        runner.publish_truth = publish_for(index, d, KIND_TRUTH, lambda: None) if truth else None

    for d in cfg.device:
        key = d.bus.key
        if only_bus is not None and key != only_bus:
            continue
        w = workers.get(key)
        if w is None:
            w = workers[key] = BusWorker(key, [], [], opener(d), clock)
            w.realtime_priority = cfg.daemon.realtime_priority
            w.make_runner, w.rebind = make_runner, rebind
        w.runners.append(make_runner(len(w.runners), d))
        w.connectors.append(connector(d, clock))
    for w in workers.values():
        w.calibrations = CalibrationWatcher(list(w.runners))
        w.calibrations.check()  # before the first sample: it is calibrated from the start
    return list(workers.values())
