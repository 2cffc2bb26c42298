"""The daemon: one anyio event loop for supervision, one worker per bus for blocking I/O.

Bus workers run in their own processes (`imud.buschild`, supervised by `imud.busproc`; the
default) or as threads here (`[daemon] bus_processes = false`). The event loop answers signals
and status queries, and tells systemd how things are: READY=1 once every device has either
started or failed its first attempt (a failed device keeps retrying, and status says why),
WATCHDOG=1 while the daemon itself is alive and serving. A bus process that crashes or hangs is
restarted by its relay thread and does not stop the watchdog; in thread mode, where a hung
worker cannot be restarted, a worker that stops making progress does.
"""

from __future__ import annotations

import gc
import json
import logging
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import anyio
import zenoh

from imud import __version__
from imud.buses.models import SimBus
from imud.busmsg import KIND_DATA, KIND_RAW, KIND_TRUTH
from imud.busproc import BusProcess, RunnerProxy
from imud.busworker import BusWorker, build_workers
from imud.chips.api import DeviceBase
from imud.clock import Clock, MonotonicClock, epoch_offset_ns
from imud.config import ImudConfig
from imud.device import DeviceRunner, Publish
from imud.publisher import PublisherThread
from imud.sdnotify import Notifier
from imud.status import DeviceState
from imud.wire import VERSION
from imud.zsession import daemon_config

log = logging.getLogger("imud.daemon")

STALL_NS = 10_000_000_000  # a worker (thread mode) or relay silent this long: not serving
READY_TIMEOUT_S = 30.0  # READY=1 at the latest this long after start, whatever is still starting


def _make_publisher(session: zenoh.Session, key: str) -> tuple[Publish, zenoh.Publisher]:
    # BLOCK: subscribers get every batch through transient stalls. It runs on the publisher
    # thread or a relay thread, never on a bus worker, so acquisition never waits for the network.
    pub = session.declare_publisher(
        key,
        encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM.with_schema(f"imud.batch.v{VERSION}"),
        congestion_control=zenoh.CongestionControl.BLOCK,
        priority=zenoh.Priority.DATA_HIGH,
    )
    return pub.put, pub


def _on_matching(pub: zenoh.Publisher, want: Callable[[bool], None]) -> Any:
    """Call `want(True)` while some subscriber matches the publisher, `want(False)` when none
    does; returns the listener, which must be kept alive."""
    listener = pub.declare_matching_listener(lambda status: want(bool(status.matching)))
    status: Any = pub.matching_status  # a MatchingStatus; the .pyi says bool
    if status.matching:  # a subscriber that was there before the listener
        want(True)
    return listener


class Daemon:
    def __init__(self, cfg: ImudConfig, clock: Clock | None = None) -> None:
        self.cfg = cfg
        self.clock = clock or MonotonicClock()
        self.started = time.monotonic()
        self.notifier = Notifier()
        self.workers: list[BusWorker | BusProcess] = []
        self.publisher: PublisherThread | None = None
        self.ready = False
        self.stall_ns = STALL_NS
        self._stop_requested = threading.Event()

    def request_stop(self) -> None:
        """Stop as on SIGTERM (for embedding and tests); safe from any thread."""
        self._stop_requested.set()

    @property
    def runners(self) -> list[DeviceRunner | RunnerProxy]:
        return [r for w in self.workers for r in w.runners]

    def status(self) -> dict[str, Any]:
        buses = []
        for w in self.workers:
            if isinstance(w, BusProcess):
                pid = w.proc.pid if w.proc is not None and w.proc.poll() is None else None
                buses.append({"bus": w.key, "pid": pid, "restarts": w.restarts,
                              "last_error": w.last_error})  # fmt: skip
            else:
                buses.append({"bus": w.key, "pid": None, "restarts": 0, "last_error": None})
        return {
            "version": __version__,
            "uptime_s": round(time.monotonic() - self.started, 3),
            "ready": self.ready,
            "buses": buses,
            "devices": [r.status() for r in self.runners],
        }

    def _build(self, session: zenoh.Session, offset_ns: int) -> list[Any]:
        """Bus workers (threads here, or one child process per bus) and the Zenoh publishers
        they feed; returns what must stay alive."""
        prefix = self.cfg.zenoh.prefix
        keep: list[Any] = []
        puts: dict[tuple[str, int], Publish] = {}
        raw_pubs: dict[str, zenoh.Publisher] = {}
        for d in self.cfg.device:
            put, pub = _make_publisher(session, f"{prefix}/{d.name}/imu")
            puts[(d.name, KIND_DATA)] = put
            keep.append(pub)
            put, pub = _make_publisher(session, f"{prefix}/{d.name}/raw")
            puts[(d.name, KIND_RAW)] = put
            raw_pubs[d.name] = pub
            keep.append(pub)
            if isinstance(d.bus, SimBus) and d.sim is not None and d.sim.truth:
                put, pub = _make_publisher(session, f"{prefix}/{d.name}/sim/truth")
                puts[(d.name, KIND_TRUTH)] = put
                keep.append(pub)
        self._build_workers(puts, offset_ns)
        for r in self.runners:  # the raw stream is computed only while someone subscribes
            keep.append(_on_matching(raw_pubs[r.cfg.name], r.want_raw))
        return keep

    def _build_workers(self, puts: dict[tuple[str, int], Publish], offset_ns: int) -> None:
        if self.cfg.daemon.bus_processes:
            spec = {
                "config": self.cfg.model_dump(mode="json"),
                "offset_ns": offset_ns,
                "log_level": logging.getLevelName(logging.getLogger().getEffectiveLevel()),
            }
            by_bus: dict[str, list[DeviceBase]] = {}
            for d in self.cfg.device:
                by_bus.setdefault(d.bus.key, []).append(d)

            def kinds(d: DeviceBase) -> tuple[Publish, Publish | None, Publish]:
                n = d.name
                return puts[(n, KIND_DATA)], puts.get((n, KIND_TRUTH)), puts[(n, KIND_RAW)]

            self.workers = [
                BusProcess(key, ds, spec, [kinds(d) for d in ds]) for key, ds in by_bus.items()
            ]
            return
        rt = self.cfg.daemon.realtime_priority
        publisher = self.publisher = PublisherThread(
            realtime_priority=max(1, rt - 1) if rt else None
        )
        publisher.start()

        def publish_for(_: int, d: DeviceBase, kind: int, on_drop: Callable[[], None]) -> Publish:
            put = puts[(d.name, kind)]
            return lambda payload: publisher.submit(put, payload, on_drop)

        self.workers = list(build_workers(self.cfg, self.clock, offset_ns, publish_for))

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
        async with anyio.create_task_group() as tg:

            async def signals() -> None:
                with anyio.open_signal_receiver(signal.SIGTERM, signal.SIGINT, signal.SIGHUP) as s:
                    async for sig in s:
                        if sig == signal.SIGHUP:
                            log.warning(
                                "SIGHUP: config reload is not implemented yet; keeping the "
                                "running config"
                            )
                            continue
                        log.info("%s received, stopping", signal.Signals(sig).name)
                        tg.cancel_scope.cancel()
                        return

            async def requested() -> None:
                while not self._stop_requested.is_set():
                    await anyio.sleep(0.05)
                log.info("stop requested, stopping")
                tg.cancel_scope.cancel()

            tg.start_soon(signals)
            tg.start_soon(requested)

    def _summary(self) -> str:
        rs = self.runners
        running = sum(r.state == DeviceState.RUNNING for r in rs)
        lost = sum(r.lost_samples for r in rs)
        rate = sum(r.measured_rate_hz for r in rs)
        return f"{running}/{len(rs)} devices running, {rate:.0f} samples/s, {lost} lost"

    def _ready_line(self) -> str:
        rs = self.runners
        running = sum(r.state == DeviceState.RUNNING for r in rs)
        text = f"{running}/{len(rs)} devices running"
        down = [r for r in rs if r.state != DeviceState.RUNNING]
        if down:
            text += "; " + "; ".join(
                f"{r.cfg.name}: {r.state}: {r.status().get('last_error') or '-'}" for r in down
            )
        return text

    def _serving(self, now_ns: int) -> list[str]:
        """What keeps the daemon from serving: relay threads (process mode) or bus workers
        (thread mode, where a hung one cannot be restarted) that stopped making progress."""
        return [w.key for w in self.workers if now_ns - w.heartbeat_ns > self.stall_ns]

    async def _supervise(self) -> None:
        deadline = time.monotonic() + READY_TIMEOUT_S
        while (
            any(r.state == DeviceState.STARTING for r in self.runners)
            and time.monotonic() < deadline
        ):
            await anyio.sleep(0.02)
        self.ready = True
        self.notifier.notify("READY=1", f"STATUS={self._ready_line()}")
        log.info("ready: %s", self._ready_line())
        period = min(self.notifier.watchdog_s / 2, 1.0) if self.notifier.watchdog_s else 1.0
        ticks = 0
        while True:
            await anyio.sleep(period)
            ticks += 1
            stuck = self._serving(time.monotonic_ns())
            if stuck:
                log.error("not serving: %s made no progress; letting the watchdog fire",
                          ", ".join(stuck))  # fmt: skip
            else:
                self.notifier.notify("WATCHDOG=1")
            if ticks % max(1, round(5 / period)) == 0:
                self.notifier.notify(f"STATUS={self._summary()}")
