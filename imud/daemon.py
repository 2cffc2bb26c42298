"""The daemon: one anyio event loop for supervision, one worker per bus for blocking I/O.

Each bus worker owns its devices and runs start/poll/publish for them in turn, so devices on one
bus are serialised and the event loop never waits on a bus. Workers run in their own processes
(`imud.busproc`, the default) or as threads here (`[daemon] bus_processes = false`). The event
loop answers signals, tells systemd how things are, and pets the watchdog only while every bus
worker is alive.
"""

from __future__ import annotations

import gc
import json
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import anyio
import zenoh

from imud import __version__
from imud.buses.models import I2cBus, SimBus, SpiBus
from imud.busproc import BusProcess, RunnerProxy
from imud.calibration import load_calibration
from imud.chips.base import ChipSim, DeviceBase, Driver
from imud.clock import Clock, MonotonicClock, epoch_offset_ns
from imud.config import ImudConfig
from imud.device import RETRY_MAX_NS, RETRY_MIN_NS, DeviceRunner, Publish
from imud.publisher import PublisherThread
from imud.sdnotify import Notifier
from imud.zsession import daemon_config

log = logging.getLogger("imud.daemon")

STALL_NS = 10_000_000_000  # a bus worker silent this long is hung: stop petting the watchdog


Connect = Callable[[Any], tuple[Driver, ChipSim | None]]


def _realtime(priority: int, who: str) -> bool:
    """SCHED_FIFO for the calling thread (and the threads it creates later)."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as e:
        log.warning(
            "%s: cannot run SCHED_FIFO at priority %d (%s): grant CAP_SYS_NICE or "
            "LimitRTPRIO=%d (the systemd unit does), or run as root; continuing without",
            who,
            priority,
            e.strerror,
            priority + 1,
        )
        return False
    log.info("%s: SCHED_FIFO at priority %d", who, priority)
    return True


@dataclass
class BusWorker:
    """Owns one bus: opens it (and reopens it with backoff while it will not open), then runs
    its devices' start/poll steps in turn, sleeping until the next one is due."""

    key: str
    runners: list[DeviceRunner]
    connectors: list[Connect]  # per runner: bus -> (driver, simulator or None)
    opener: Callable[[], Any]
    clock: Clock
    stop: threading.Event = field(default_factory=threading.Event)
    heartbeat_ns: int = 0
    realtime_priority: int | None = None
    bus: Any = None
    _reopen_ns: int = 0
    _backoff_ns: int = RETRY_MIN_NS

    def _go_realtime(self, priority: int) -> None:
        _realtime(priority, f"bus {self.key} worker")

    def _retry_later(self, now: int) -> None:
        self._reopen_ns = now + self._backoff_ns
        self._backoff_ns = min(2 * self._backoff_ns, RETRY_MAX_NS)

    def _ensure_bus(self, now: int) -> bool:
        """Open the bus, then connect each device not yet connected (an SPI device opens its
        own chip select). Failures retry with backoff. True when some device can be served."""
        pending = [i for i, r in enumerate(self.runners) if r.driver is None]
        if pending and now >= self._reopen_ns:
            if self.bus is None:
                try:
                    self.bus = self.opener()
                except OSError as e:
                    for r in self.runners:
                        r.bus_down(str(e), self._backoff_ns)
                    self._retry_later(now)
                    return False
            failed = False
            for i in pending:
                try:
                    self.runners[i].attach(*self.connectors[i](self.bus))
                except OSError as e:
                    self.runners[i].bus_down(str(e), self._backoff_ns)
                    failed = True
            if failed:
                self._retry_later(now)
        return any(r.driver is not None for r in self.runners)

    def run(self) -> None:
        """Blocking loop: poll whichever device is due next, sleep until the next is."""
        name = threading.current_thread().name
        threading.current_thread().name = f"bus {self.key}"
        if self.realtime_priority:
            self._go_realtime(self.realtime_priority)
        try:
            while not self.stop.is_set():
                now = self.clock.now_ns()
                self.heartbeat_ns = now
                if not self._ensure_bus(now):
                    self.stop.wait(min(self._reopen_ns - now, 1_000_000_000) / 1e9)
                    continue
                due = min(
                    (r for r in self.runners if r.driver is not None),
                    key=lambda r: r.next_due_ns,
                )
                if self._reopen_ns and due.next_due_ns > self._reopen_ns:
                    due.next_due_ns = max(due.next_due_ns, now)  # wake for the retry too
                    wait = min(due.next_due_ns, self._reopen_ns) - now
                    if wait > 0:
                        self.stop.wait(min(wait, 1_000_000_000) / 1e9)
                        continue
                wait = due.next_due_ns - now
                if wait > 0:  # wake at least once a second so the heartbeat stays fresh
                    self.stop.wait(min(wait, 1_000_000_000) / 1e9)
                    continue
                if due.state == "running":
                    due.note_lateness(now - due.next_due_ns, now)
                try:
                    due.step()
                except Exception:  # a bug in one device must not take the bus down
                    log.exception("%s: unexpected error", due.cfg.name)
                    due.state, due.last_error = "error", "internal error (see log)"
                    due.next_due_ns = self.clock.now_ns() + 5_000_000_000
            for r in self.runners:
                r.stop()
        finally:
            threading.current_thread().name = name


def _make_publisher(session: zenoh.Session, key: str) -> tuple[Publish, zenoh.Publisher]:
    # BLOCK: subscribers get every batch through transient stalls. It runs on the publisher
    # thread, never on a bus worker, so acquisition cannot wait for the network.
    pub = session.declare_publisher(
        key,
        encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM.with_schema("imud.batch.v1"),
        congestion_control=zenoh.CongestionControl.BLOCK,
        priority=zenoh.Priority.DATA_HIGH,
    )
    return pub.put, pub


def _queued(publisher: PublisherThread, put: Publish, on_drop: Callable[[], None]) -> Publish:
    return lambda payload: publisher.submit(put, payload, on_drop)


class _ChipSelects:
    """An SPI bus as a whole: nothing to open; each device opens its own chip select."""


def _opener(d: DeviceBase) -> Callable[[], Any]:
    from imud.buses.i2c import open_smbus
    from imud.sim.i2c import SimI2CBus

    bus = d.bus
    if isinstance(bus, SimBus) and bus.transport == "i2c":
        return lambda: SimI2CBus(seed=d.sim.seed if d.sim else 0)
    if isinstance(bus, I2cBus):
        return lambda: open_smbus(bus)
    if isinstance(bus, SpiBus | SimBus):
        return _ChipSelects
    raise ValueError(f"{bus.kind} buses arrive with the chips that use them")  # config forbids


def _connector(d: DeviceBase, clock: Clock) -> Connect:
    """Device on an open bus -> (driver, simulator or None)."""
    from imud.buses.connect import connect

    return lambda shared: connect(d, shared, clock)


PublishFor = Callable[[int, DeviceBase, bool, Callable[[], None]], Publish]


def build_workers(
    cfg: ImudConfig,
    clock: Clock,
    offset_ns: int,
    publish_for: PublishFor,
    only_bus: str | None = None,
) -> list[BusWorker]:
    """One worker per bus, one runner per device. Buses open in their workers.

    `publish_for(index on its bus, device, truth?, on_drop)` gives each runner its publish
    callable (a queue to the Zenoh publisher thread, or the socket to the daemon process)."""
    workers: dict[str, BusWorker] = {}
    for d in cfg.device:
        key = d.bus.key
        if only_bus is not None and key != only_bus:
            continue
        w = workers.get(key)
        if w is None:
            w = workers[key] = BusWorker(key, [], [], _opener(d), clock)
            w.realtime_priority = cfg.daemon.realtime_priority
        index = len(w.runners)
        cal = load_calibration(d.calibration) if d.calibration else None
        runner = DeviceRunner(d, None, cal, lambda _: None, offset_ns, now_ns=clock.now_ns)
        runner.publish = publish_for(index, d, False, runner.note_publish_drop)
        if isinstance(d.bus, SimBus) and d.sim is not None and d.sim.truth:
            runner.publish_truth = publish_for(index, d, True, lambda: None)
        fast = getattr(d, "odr_hz", 0) >= 16000
        if fast and cfg.daemon.realtime_priority is None:
            log.warning(
                "%s runs at %g Hz: its FIFO lasts only a few ms, and an ordinary scheduler delay "
                "can overflow it; set [daemon] realtime_priority (e.g. 20)",
                d.name,
                getattr(d, "odr_hz", 0),
            )
        w.runners.append(runner)
        w.connectors.append(_connector(d, clock))
    return list(workers.values())


class Daemon:
    def __init__(self, cfg: ImudConfig, clock: Clock | None = None) -> None:
        self.cfg = cfg
        self.clock = clock or MonotonicClock()
        self.started = time.monotonic()
        self.notifier = Notifier()
        self.workers: list[BusWorker | BusProcess] = []
        self.publisher: PublisherThread | None = None

    @property
    def runners(self) -> list[DeviceRunner | RunnerProxy]:
        return [r for w in self.workers for r in w.runners]

    def status(self) -> dict[str, Any]:
        return {
            "version": __version__,
            "uptime_s": round(time.monotonic() - self.started, 3),
            "devices": [r.status() for r in self.runners],
        }

    def _build(self, session: zenoh.Session, offset_ns: int) -> list[Any]:
        """Bus workers (threads here, or one child process per bus) and the Zenoh publishers
        they feed; returns what must stay alive."""
        prefix = self.cfg.zenoh.prefix
        keep: list[Any] = []
        puts: dict[tuple[str, bool], Publish] = {}
        for d in self.cfg.device:
            put, pub = _make_publisher(session, f"{prefix}/{d.name}/imu")
            puts[(d.name, False)] = put
            keep.append(pub)
            if isinstance(d.bus, SimBus) and d.sim is not None and d.sim.truth:
                put, pub = _make_publisher(session, f"{prefix}/{d.name}/sim/truth")
                puts[(d.name, True)] = put
                keep.append(pub)
        if self.cfg.daemon.bus_processes:
            spec = {
                "config": self.cfg.model_dump(mode="json"),
                "offset_ns": offset_ns,
                "log_level": logging.getLevelName(logging.getLogger().getEffectiveLevel()),
            }
            by_bus: dict[str, list[DeviceBase]] = {}
            for d in self.cfg.device:
                by_bus.setdefault(d.bus.key, []).append(d)
            self.workers = [
                BusProcess(
                    key,
                    ds,
                    spec,
                    [(puts[(d.name, False)], puts.get((d.name, True))) for d in ds],
                )
                for key, ds in by_bus.items()
            ]
            return keep
        rt = self.cfg.daemon.realtime_priority
        publisher = self.publisher = PublisherThread(
            realtime_priority=max(1, rt - 1) if rt else None
        )
        publisher.start()

        def publish_for(_: int, d: DeviceBase, truth: bool, on_drop: Callable[[], None]) -> Publish:
            return _queued(publisher, puts[(d.name, truth)], on_drop)

        self.workers = list(build_workers(self.cfg, self.clock, offset_ns, publish_for))
        return keep

    def _answer(self, q: zenoh.Query, body: dict[str, Any]) -> None:
        with q:
            q.reply(q.key_expr, json.dumps(body), encoding=zenoh.Encoding.APPLICATION_JSON)

    def _device_answer(self, r: DeviceRunner | RunnerProxy) -> Callable[[zenoh.Query], None]:
        return lambda q: self._answer(q, r.status())

    async def run(self) -> int:
        z = self.cfg.zenoh
        log.info(
            "imud %s starting: %d device(s), Zenoh %s on %s",
            __version__,
            len(self.cfg.device),
            z.mode,
            ", ".join(z.listen) or "(no listener)",
        )
        session = await anyio.to_thread.run_sync(zenoh.open, daemon_config(z))
        try:
            keep = self._build(session, epoch_offset_ns())
            qs = [
                session.declare_queryable(
                    f"{z.prefix}/daemon/status", lambda q: self._answer(q, self.status())
                )
            ]
            for r in self.runners:
                qs.append(
                    session.declare_queryable(
                        f"{z.prefix}/{r.cfg.name}/status", self._device_answer(r)
                    )
                )
            # Everything built so far lives as long as the daemon: move it out of the cyclic
            # collector's sight, so a full collection cannot stall a bus worker for milliseconds
            # (a 32 kHz FIFO overflows after 4 ms). The default thresholds stay: they keep each
            # young-generation pass small (measured: raising them made passes take 1-1.6 ms).
            gc.collect()
            gc.freeze()
            # A thread waiting for the GIL waits up to the switch interval (5 ms by default):
            # longer than a 32 kHz FIFO lasts. Hand the GIL over ten times as often.
            sys.setswitchinterval(0.0005)
            async with anyio.create_task_group() as tg:
                for w in self.workers:
                    tg.start_soon(anyio.to_thread.run_sync, w.run)
                tg.start_soon(self._supervise)
                await self._wait_for_stop()
                self.notifier.notify("STOPPING=1")
                for w in self.workers:
                    w.stop.set()
                tg.cancel_scope.cancel()  # workers finish their current step and return
            if self.publisher is not None:
                await anyio.to_thread.run_sync(self.publisher.stop)
            del keep, qs
        finally:
            await anyio.to_thread.run_sync(session.close)
        log.info("imud stopped")
        return 0

    async def _wait_for_stop(self) -> None:
        with anyio.open_signal_receiver(signal.SIGTERM, signal.SIGINT, signal.SIGHUP) as sigs:
            async for s in sigs:
                if s == signal.SIGHUP:
                    log.warning(
                        "SIGHUP: config reload is not implemented yet; keeping the running config"
                    )
                    continue
                log.info("%s received, stopping", signal.Signals(s).name)
                return

    def _summary(self) -> str:
        rs = self.runners
        running = sum(r.state == "running" for r in rs)
        lost = sum(r.lost_samples for r in rs)
        rate = sum(r.measured_rate_hz for r in rs)
        return f"{running}/{len(rs)} devices running, {rate:.0f} samples/s, {lost} lost"

    async def _supervise(self) -> None:
        while any(r.state == "starting" for r in self.runners):
            await anyio.sleep(0.02)
        self.notifier.notify("READY=1", f"STATUS={self._summary()}")
        log.info("ready: %s", self._summary())
        period = min(self.notifier.watchdog_s / 2, 1.0) if self.notifier.watchdog_s else 1.0
        ticks = 0
        while True:
            await anyio.sleep(period)
            ticks += 1
            now = self.clock.now_ns()
            stalled = [w.key for w in self.workers if now - w.heartbeat_ns > STALL_NS]
            if stalled:
                log.error("bus worker(s) hung: %s; letting the watchdog fire", ", ".join(stalled))
            else:
                self.notifier.notify("WATCHDOG=1")
            if ticks % max(1, round(5 / period)) == 0:
                self.notifier.notify(f"STATUS={self._summary()}")
