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

import contextlib
import gc
import json
import logging
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import anyio
import zenoh
from anyio.abc import TaskGroup

from imud import __version__
from imud.buses.models import SimBus
from imud.busmsg import KIND_DATA, KIND_RAW, KIND_TRUTH
from imud.busproc import BusProcess, RunnerProxy
from imud.busworker import BusWorker, build_workers
from imud.chips.api import DeviceBase
from imud.clock import Clock, MonotonicClock, epoch_offset_ns
from imud.config import ImudConfig, load_config
from imud.device import DeviceRunner, Publish
from imud.errors import ConfigError
from imud.publisher import PublisherThread
from imud.reload import ConfigFile, ReloadPlan, plan_reload
from imud.sdnotify import Notifier
from imud.status import DeviceState
from imud.wire import VERSION
from imud.zerrors import ZenohSetupError, describe
from imud.zsession import daemon_config

log = logging.getLogger("imud.daemon")

RELOAD_POLL_S = 1.0  # how often the config file's stat is looked at
READY_TIMEOUT_S = 30.0  # READY=1 at the latest this long after start, whatever is still starting


def _declare_publisher(session: zenoh.Session, key: str) -> zenoh.Publisher:
    # BLOCK: subscribers get every batch through transient stalls. It runs on the publisher
    # thread or a relay thread, never on a bus worker, so acquisition never waits for the network.
    return session.declare_publisher(
        key,
        encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM.with_schema(f"imud.batch.v{VERSION}"),
        congestion_control=zenoh.CongestionControl.BLOCK,
        priority=zenoh.Priority.DATA_HIGH,
    )


def _key(prefix: str, d: DeviceBase, kind: int) -> str:
    return (
        f"{prefix}/{d.name}/" + {KIND_DATA: "imu", KIND_RAW: "raw", KIND_TRUTH: "sim/truth"}[kind]
    )


def _has_truth(d: DeviceBase) -> bool:
    return isinstance(d.bus, SimBus) and d.sim is not None and d.sim.truth


def _on_matching(pub: zenoh.Publisher, want: Callable[[bool], None]) -> Any:
    """Call `want(True)` while some subscriber matches the publisher, `want(False)` when none
    does; returns the listener, which must be kept alive."""
    listener = pub.declare_matching_listener(lambda status: want(bool(status.matching)))
    status: Any = pub.matching_status  # a MatchingStatus; the .pyi says bool
    if status.matching:  # a subscriber that was there before the listener
        want(True)
    return listener


@dataclass
class _Endpoints:
    """A device's side of the Zenoh session: its publishers by kind (imud.busmsg KIND_*), the
    raw stream's matching listener and its status queryable."""

    pubs: dict[int, zenoh.Publisher]
    others: list[Any]

    def undeclare(self) -> None:
        for x in [*self.pubs.values(), *self.others]:
            with contextlib.suppress(zenoh.ZError):
                x.undeclare()


class Daemon:
    def __init__(
        self, cfg: ImudConfig, clock: Clock | None = None, config_path: Path | None = None
    ) -> None:
        self.cfg = cfg
        self.clock = clock or MonotonicClock()
        self.config_path = config_path  # watched for edits, re-read on SIGHUP; None: neither
        self.started = time.monotonic()
        self.notifier = Notifier()
        self.workers: list[BusWorker | BusProcess] = []
        self.publisher: PublisherThread | None = None
        self.ready = False
        # a worker (thread mode) or relay silent this long ([daemon] hung_after_s): not serving
        self.stall_ns = int(cfg.daemon.hung_after_s * 1e9)
        self._stop_requested = threading.Event()
        self._reload_requested = threading.Event()
        self.session: zenoh.Session | None = None
        self._ends: dict[str, _Endpoints] = {}
        self._daemon_q: Any = None
        self._raw_on: set[str] = set()  # devices whose raw stream has a subscriber
        self.offset_ns = 0
        self._tg: TaskGroup | None = None
        # what the last reload said: shown in status until a later one succeeds
        self.config_error: str | None = None
        self.config_error_at: float | None = None
        self.reloads = 0
        self.last_reload_at: float | None = None
        self.restart_needed: str | None = None

    def request_stop(self) -> None:
        """Stop as on SIGTERM (for embedding and tests); safe from any thread."""
        self._stop_requested.set()

    def request_reload(self) -> None:
        """Reload the config file as on SIGHUP; safe from any thread."""
        self._reload_requested.set()

    @property
    def runners(self) -> list[DeviceRunner | RunnerProxy]:
        return [r for w in self.workers for r in w.runners]

    def _runner(self, name: str) -> DeviceRunner | RunnerProxy | None:
        return next((r for r in self.runners if r.cfg.name == name), None)

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
            "config": str(self.config_path) if self.config_path is not None else None,
            "config_error": self.config_error,
            "config_error_at": self.config_error_at,
            "reloads": self.reloads,
            "last_reload_at": self.last_reload_at,
            "restart_needed": self.restart_needed,
            "buses": buses,
            "devices": [r.status() for r in self.runners],
        }

    # --- Zenoh side -----------------------------------------------------------------------------
    def _declare(self, session: zenoh.Session, prefix: str, d: DeviceBase) -> _Endpoints:
        name = d.name
        kinds = (KIND_DATA, KIND_RAW, KIND_TRUTH) if _has_truth(d) else (KIND_DATA, KIND_RAW)
        pubs = {k: _declare_publisher(session, _key(prefix, d, k)) for k in kinds}
        # the raw stream is computed only while someone subscribes
        listener = _on_matching(pubs[KIND_RAW], lambda on: self._want_raw(name, on))
        q = session.declare_queryable(f"{prefix}/{name}/status", self._device_answer(name))
        return _Endpoints(pubs, [listener, q])

    def _declare_all(self, session: zenoh.Session, cfg: ImudConfig) -> None:
        """Everything the daemon declares, on `session`: the daemon's status queryable and each
        device's endpoints; the workers publish there from the moment this returns."""
        prefix = cfg.zenoh.prefix
        q = session.declare_queryable(
            f"{prefix}/daemon/status", lambda q: self._answer(q, self.status())
        )
        ends = {d.name: self._declare(session, prefix, d) for d in cfg.device}
        self.session, self._daemon_q, self._ends = session, q, ends

    def _want_raw(self, name: str, on: bool) -> None:
        (self._raw_on.add if on else self._raw_on.discard)(name)
        r = self._runner(name)
        if r is not None:
            r.want_raw(on)

    def _put(self, name: str, kind: int) -> Publish:
        """Publish on the device's current publisher: a reload that reopens the session swaps
        publishers under the bus workers without them noticing."""

        def put(payload: bytes) -> None:
            ends = self._ends.get(name)
            pub = ends.pubs.get(kind) if ends is not None else None
            if pub is not None:
                pub.put(payload)

        return put

    # --- bus workers ----------------------------------------------------------------------------
    def _puts(self, d: DeviceBase) -> tuple[Publish, Publish | None, Publish]:
        n = d.name
        truth = self._put(n, KIND_TRUTH) if _has_truth(d) else None
        return self._put(n, KIND_DATA), truth, self._put(n, KIND_RAW)

    def _spec(self, cfg: ImudConfig) -> dict[str, Any]:
        return {
            "config": cfg.model_dump(mode="json"),
            "offset_ns": self.offset_ns,
            "log_level": logging.getLevelName(logging.getLogger().getEffectiveLevel()),
        }

    def _make_workers(
        self, cfg: ImudConfig, buses: dict[str, list[DeviceBase]]
    ) -> list[BusWorker | BusProcess]:
        """Workers for `buses` (bus key -> its devices in `cfg`): one child process per bus, or
        threads here (`[daemon] bus_processes = false`)."""
        if self.cfg.daemon.bus_processes:
            spec = self._spec(cfg)
            return [
                BusProcess(key, ds, spec, [self._puts(d) for d in ds]) for key, ds in buses.items()
            ]
        publisher = self.publisher
        if publisher is None:
            rt = self.cfg.daemon.realtime_priority
            publisher = self.publisher = PublisherThread(
                realtime_priority=max(1, rt - 1) if rt else None
            )
            publisher.start()

        def publish_for(_: int, d: DeviceBase, kind: int, on_drop: Callable[[], None]) -> Publish:
            put = self._put(d.name, kind)
            return lambda payload: publisher.submit(put, payload, on_drop)

        workers: list[BusWorker | BusProcess] = []
        for key in buses:
            for w in build_workers(cfg, self.clock, self.offset_ns, publish_for, only_bus=key):
                for r in w.runners:
                    r.want_raw(r.cfg.name in self._raw_on)
                workers.append(w)
        return workers

    def _start_worker(self, w: BusWorker | BusProcess) -> None:
        assert self._tg is not None
        self._tg.start_soon(anyio.to_thread.run_sync, w.run)

    def _answer(self, q: zenoh.Query, body: dict[str, Any]) -> None:
        with q:
            q.reply(q.key_expr, json.dumps(body), encoding=zenoh.Encoding.APPLICATION_JSON)

    def _device_answer(self, name: str) -> Callable[[zenoh.Query], None]:
        def answer(q: zenoh.Query) -> None:
            r = self._runner(name)
            if r is not None:  # gone in a reload: no answer, as for any unknown device
                self._answer(q, r.status())

        return answer

    async def run(self) -> int:
        z = self.cfg.zenoh
        log.info(
            "imud %s starting: %d device(s), Zenoh %s on %s",
            __version__,
            len(self.cfg.device),
            z.mode,
            ", ".join(z.listen) or "(no listener)",
        )
        self.session = await anyio.to_thread.run_sync(zenoh.open, daemon_config(z))
        try:
            self.offset_ns = epoch_offset_ns()
            self._declare_all(self.session, self.cfg)
            buses: dict[str, list[DeviceBase]] = {}
            for d in self.cfg.device:
                buses.setdefault(d.bus.key, []).append(d)
            self.workers = self._make_workers(self.cfg, buses)
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
                self._tg = tg
                for w in self.workers:
                    self._start_worker(w)
                tg.start_soon(self._supervise)
                tg.start_soon(self._watch_config)
                await self._wait_for_stop()
                self.notifier.notify("STOPPING=1")
                for w in self.workers:
                    w.stop.set()
                tg.cancel_scope.cancel()  # workers finish their current step and return
            if self.publisher is not None:
                await anyio.to_thread.run_sync(self.publisher.stop)
            for ends in self._ends.values():
                ends.undeclare()
        finally:
            await anyio.to_thread.run_sync(self.session.close)
        log.info("imud stopped")
        return 0

    # --- reload ---------------------------------------------------------------------------------
    async def _watch_config(self) -> None:
        """Reload on SIGHUP (`request_reload`) and when the file's content changes."""
        watch = ConfigFile(self.config_path) if self.config_path is not None else None
        next_poll = time.monotonic()
        while True:
            await anyio.sleep(0.05)
            if self._reload_requested.is_set():
                self._reload_requested.clear()
                if watch is not None:
                    watch.changed()  # this reload reads it: not again at the next poll
                await self.reload("SIGHUP")
            elif watch is not None and time.monotonic() >= next_poll:
                next_poll = time.monotonic() + RELOAD_POLL_S
                if watch.changed():
                    await self.reload(f"{watch.path} changed")

    async def reload(self, why: str) -> bool:
        """Load and validate the config file, then apply what changed; a config that does not
        load leaves the running one as it is, with `config_error` in status. True if applied."""
        if self.config_path is None:
            log.warning("%s: no config file to reload (the daemon was given a config object)", why)
            return False
        usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        self.notifier.notify("RELOADING=1", f"MONOTONIC_USEC={usec}", "STATUS=reloading config")
        try:
            applied = await self._reload(why)
        finally:
            self.notifier.notify("READY=1", f"STATUS={self._reload_status()}")
        return applied

    def _reload_status(self) -> str:
        if self.config_error is not None:
            return f"config reload failed, running the previous config: {self.config_error}"
        return self._summary()

    def _refused(self, msg: str) -> bool:
        self.config_error, self.config_error_at = msg, time.time()
        log.error("config reload: %s; still running the previous config", msg.replace("\n", "; "))
        return False

    async def _reload(self, why: str) -> bool:
        assert self.config_path is not None
        try:
            new = await anyio.to_thread.run_sync(load_config, self.config_path)
            daemon_config(new.zenoh)  # the `options` are Zenoh's to judge: before anything moves
        except (ConfigError, ZenohSetupError) as e:
            return self._refused(str(e))
        plan = plan_reload(self.cfg, new)
        log.info("config reload (%s): %s", why, plan.describe())
        if plan.zenoh_changed:
            refused = await self._reopen(new)
            if refused is not None:
                return self._refused(refused)
        else:
            assert self.session is not None
            prefix = new.zenoh.prefix
            for d in new.device:
                ends = self._ends.get(d.name)
                if ends is None:  # added
                    self._ends[d.name] = self._declare(self.session, prefix, d)
                elif _has_truth(d) and KIND_TRUTH not in ends.pubs:
                    ends.pubs[KIND_TRUTH] = _declare_publisher(
                        self.session, _key(prefix, d, KIND_TRUTH)
                    )
                # a changed device keeps its publishers: its last batches and its successor's
                # first go out on the same ones, none dropped in between (a truth publisher it no
                # longer feeds just stays quiet)
        self._apply_buses(new, plan)
        for name in plan.removed:
            gone = self._ends.pop(name, None)
            if gone is not None:
                gone.undeclare()
            self._raw_on.discard(name)
        self.cfg = self.cfg.model_copy(update={"device": new.device, "zenoh": new.zenoh})
        self.restart_needed = (
            "[daemon] settings changed: they take effect when the daemon restarts"
            if new.daemon != self.cfg.daemon
            else None
        )
        self.config_error = self.config_error_at = None
        self.reloads += 1
        self.last_reload_at = time.time()
        return True

    async def _close_session(self) -> None:
        session, ends, q = self.session, self._ends, self._daemon_q
        self._ends, self._daemon_q = {}, None
        for e in ends.values():
            e.undeclare()
        if q is not None:
            with contextlib.suppress(zenoh.ZError):
                q.undeclare()
        if session is not None:
            await anyio.to_thread.run_sync(session.close)

    async def _reopen(self, new: ImudConfig) -> str | None:
        """A `[zenoh]` change: a new session with the new settings, every publisher and
        queryable declared on it; None, or why not (the old session then stays, or is back).

        A listen endpoint both sessions share can only be bound once: the old session closes
        first, and batches published in between reach nobody (subscribers reconnect to the new
        session as after any broken link; their seq shows what they missed). Otherwise the new
        session is opened first and the workers switch to it between two batches."""
        old = self.cfg
        shared = set(old.zenoh.listen) & set(new.zenoh.listen)
        if shared:
            await self._close_session()
        try:
            session = await anyio.to_thread.run_sync(zenoh.open, daemon_config(new.zenoh))
        except Exception as e:  # e.g. a new listen port is taken
            why = f"[zenoh]: cannot open the new session: {describe(e, new.zenoh.listen)}"
            if shared:  # back to the old settings, which held until a moment ago
                back = await anyio.to_thread.run_sync(zenoh.open, daemon_config(old.zenoh))
                self._declare_all(back, old)
            return why
        if shared:
            self._declare_all(session, new)
            return None
        old_session, old_ends, old_q = self.session, self._ends, self._daemon_q
        self._declare_all(session, new)
        for gone in old_ends.values():
            gone.undeclare()
        with contextlib.suppress(zenoh.ZError):
            old_q.undeclare()
        if old_session is not None:
            await anyio.to_thread.run_sync(old_session.close)
        return None

    def _apply_buses(self, new: ImudConfig, plan: ReloadPlan) -> None:
        config = new.model_dump(mode="json")
        for w in [w for w in self.workers if w.key in plan.stop]:
            w.stop.set()  # its thread puts its devices to sleep and returns
            self.workers.remove(w)
        for w in self.workers:
            devices = plan.reconfigure.get(w.key)
            if devices is None:
                continue
            if isinstance(w, BusProcess):
                w.reconfigure(devices, config, [self._puts(d) for d in devices], self._raw_on)
            else:
                w.reconfigure(devices)
        for w in self._make_workers(new, plan.start):
            self.workers.append(w)
            self._start_worker(w)

    async def _wait_for_stop(self) -> None:
        async with anyio.create_task_group() as tg:

            async def signals() -> None:
                with anyio.open_signal_receiver(signal.SIGTERM, signal.SIGINT, signal.SIGHUP) as s:
                    async for sig in s:
                        if sig == signal.SIGHUP:
                            self.request_reload()
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
