"""The daemon: one anyio event loop for supervision, one worker per bus for blocking I/O.

Each bus's worker runs behind a socket, relayed to Zenoh by a `BusLink` thread here; it runs in a
process of its own (the default) or, with `[daemon] bus_processes = false`, in a thread of this
one (`imud.buslink`: the transport is the only difference). The event loop answers signals and
status queries, and tells systemd how things are: READY=1 once every device has either started
or failed its first attempt (a failed device keeps retrying, and status says why), WATCHDOG=1
while the daemon itself is alive and serving. A bus process that crashes or hangs is restarted
by its link and does not stop the watchdog; an in-process worker that hangs, which nothing can
restart, does.
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
from imud.buslink import (
    BusLink,
    DeviceView,
    ProcessTransport,
    Put,
    Puts,
    ThreadTransport,
    Transport,
    ZygoteTransport,
)
from imud.busmsg import Stream
from imud.chips.api import DeviceBase
from imud.clock import epoch_offset_ns
from imud.config import ImudConfig, load_config
from imud.errors import ConfigError
from imud.reload import ConfigFile, ReloadPlan, by_bus, plan_reload
from imud.ros2.output import DomainError, Ros2Output, domain_id
from imud.sdnotify import Notifier
from imud.status import DeviceState
from imud.wire import VERSION
from imud.zerrors import ZenohSetupError, describe
from imud.zsession import daemon_config
from imud.zygote import Zygote

log = logging.getLogger("imud.daemon")

RELOAD_POLL_S = 1.0  # how often the config file's stat is looked at
ROS2_TICK_S = 1.0  # /diagnostics once a second, as diagnostic_updater publishes
READY_TIMEOUT_S = 30.0  # READY=1 at the latest this long after start, whatever is still starting


def _declare_publisher(session: zenoh.Session, key: str) -> zenoh.Publisher:
    # BLOCK: subscribers get every batch through transient stalls. It runs on a link's relay
    # thread, never on a bus worker, so acquisition never waits for the network.
    return session.declare_publisher(
        key,
        encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM.with_schema(f"imud.batch.v{VERSION}"),
        congestion_control=zenoh.CongestionControl.BLOCK,
        priority=zenoh.Priority.DATA_HIGH,
    )


def _key(prefix: str, d: DeviceBase, stream: Stream) -> str:
    return f"{prefix}/{d.name}/{stream.key}"


def _streams(d: DeviceBase) -> tuple[Stream, ...]:
    return (
        (Stream.DATA, Stream.RAW, Stream.TRUTH) if d.publishes_truth else (Stream.DATA, Stream.RAW)
    )


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
    """A device's side of the Zenoh session: its publishers by stream, the raw stream's
    matching listener and its status queryable."""

    pubs: dict[Stream, zenoh.Publisher]
    others: list[Any]

    def undeclare(self) -> None:
        for x in [*self.pubs.values(), *self.others]:
            with contextlib.suppress(zenoh.ZError):
                x.undeclare()


class Daemon:
    def __init__(
        self, cfg: ImudConfig, config_path: Path | None = None, zygote: Zygote | None = None
    ) -> None:
        self.cfg = cfg
        self.zygote = zygote  # forks the bus processes; None: a fork server does
        self.config_path = config_path  # watched for edits, re-read on SIGHUP; None: neither
        self.started = time.monotonic()
        self.notifier = Notifier()
        self.links: list[BusLink] = []
        self.ready = False
        # a link's relay silent this long ([daemon] hung_after_s): not serving
        self.stall_ns = int(cfg.daemon.hung_after_s * 1e9)
        self._stop_requested = threading.Event()
        self._reload_requested = threading.Event()
        self.session: zenoh.Session | None = None
        self._ends: dict[str, _Endpoints] = {}
        self._daemon_q: list[Any] = []  # the daemon's own queryables (status, config)
        self._raw_on: set[str] = set()  # devices whose raw stream has a subscriber
        self.offset_ns = 0
        self._tg: TaskGroup | None = None
        # what the last reload said: shown in status until a later one succeeds
        self.config_error: str | None = None
        self.config_error_at: float | None = None
        self.reloads = 0
        self.last_reload_at: float | None = None
        self.restart_needed: str | None = None
        self.ros2: Ros2Output | None = None  # the ROS 2 output, when [ros2] is on
        self.ros2_error: str | None = None  # why it is not running although on

    def request_stop(self) -> None:
        """Stop as on SIGTERM (for embedding and tests); safe from any thread."""
        self._stop_requested.set()

    def request_reload(self) -> None:
        """Reload the config file as on SIGHUP; safe from any thread."""
        self._reload_requested.set()

    @property
    def views(self) -> list[DeviceView]:
        return [v for link in self.links for v in link.views]

    def _view(self, name: str) -> DeviceView | None:
        return next((v for v in self.views if v.cfg.name == name), None)

    def status(self) -> dict[str, Any]:
        buses = [
            {
                "bus": w.key,
                "pid": w.pid,
                "restarts": w.restarts,
                "last_error": w.last_error,
                "cpu_s": w.cpu_s,
                "sim_cpu_s": w.sim_cpu_s,
            }
            for w in self.links
        ]
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
            "devices": [v.status().to_json() for v in self.views],
            "ros2": self._ros2_status(),
        }

    def _ros2_status(self) -> dict[str, Any] | None:
        r = self.cfg.ros2
        if not r.enabled:
            return None
        out = self.ros2
        return {
            "profiles": list(r.profiles),
            "domain_id": out.domain if out is not None else None,
            "node": r.node,
            "topics": out.topics() if out is not None else [],
            "messages": out.messages() if out is not None else {},
            "dropped": out.dropped() if out is not None else {},
            "error": self.ros2_error or (out.error if out is not None else None),
        }

    def _start_ros2(self, session: zenoh.Session, cfg: ImudConfig) -> None:
        """The ROS 2 output on `session` for `cfg` (closing the one before): off when `[ros2]`
        is; when it cannot start, the daemon runs on without it and says why in status."""
        if self.ros2 is not None:
            self.ros2.close()
            self.ros2 = None
        self.ros2_error = None
        if not cfg.ros2.enabled:
            return
        try:
            self.ros2 = Ros2Output(cfg, session)
        except (DomainError, zenoh.ZError) as e:
            self.ros2_error = str(e)
            log.error("ROS 2 output not started: %s", e)

    # --- Zenoh side -----------------------------------------------------------------------------
    def _declare(self, session: zenoh.Session, prefix: str, d: DeviceBase) -> _Endpoints:
        name = d.name
        pubs = {k: _declare_publisher(session, _key(prefix, d, k)) for k in _streams(d)}
        # the raw stream is computed only while someone subscribes
        listener = _on_matching(pubs[Stream.RAW], lambda on: self._want_raw(name, on))
        q = session.declare_queryable(f"{prefix}/{name}/status", self._device_answer(name))
        return _Endpoints(pubs, [listener, q])

    def _declare_all(self, session: zenoh.Session, cfg: ImudConfig) -> None:
        """Everything the daemon declares, on `session`: the daemon's status queryable and each
        device's endpoints; the workers publish there from the moment this returns."""
        prefix = cfg.zenoh.prefix
        q = session.declare_queryable(
            f"{prefix}/daemon/status", lambda q: self._answer(q, self.status())
        )
        c = session.declare_queryable(
            f"{prefix}/daemon/config", lambda q: self._answer(q, self.config_view())
        )
        ends = {d.name: self._declare(session, prefix, d) for d in cfg.device}
        self.session, self._daemon_q, self._ends = session, [q, c], ends

    def _want_raw(self, name: str, on: bool) -> None:
        (self._raw_on.add if on else self._raw_on.discard)(name)
        for link in self.links:
            link.want_raw(name, on)

    def _put(self, name: str, stream: Stream) -> Put:
        """Publish on the device's current publisher: a reload that reopens the session swaps
        publishers under the links without them noticing."""

        def put(payload: bytes) -> None:
            ends = self._ends.get(name)
            pub = ends.pubs.get(stream) if ends is not None else None
            if pub is not None:
                pub.put(payload)
            out = self.ros2
            if out is not None and stream is Stream.DATA:
                try:
                    out.batch(name, payload)
                except Exception:  # a bug there must not cost the native stream
                    log.exception("%s: ROS 2 output failed on a batch", name)

        return put

    # --- bus workers ----------------------------------------------------------------------------
    def _puts(self, d: DeviceBase) -> Puts:
        return {s: self._put(d.name, s) for s in _streams(d)}

    def _spec(self, cfg: ImudConfig) -> dict[str, Any]:
        return {
            "config": cfg.model_dump(mode="json"),
            "offset_ns": self.offset_ns,
            "log_level": logging.getLevelName(logging.getLogger().getEffectiveLevel()),
        }

    def _make_links(self, cfg: ImudConfig, buses: dict[str, list[DeviceBase]]) -> list[BusLink]:
        """Links for `buses` (bus key -> its devices in `cfg`), each worker in a process of its
        own, or in a thread here (`[daemon] bus_processes = false`)."""
        spec = self._spec(cfg)
        zygote = self.zygote
        transport: Callable[[], Transport] = ThreadTransport
        if self.cfg.daemon.bus_processes:
            if zygote is not None and zygote.alive:
                transport = lambda: ZygoteTransport(zygote)  # noqa: E731
            else:
                transport = ProcessTransport
        return [
            BusLink(key, ds, spec, [self._puts(d) for d in ds], transport, self._raw_on)
            for key, ds in buses.items()
        ]

    def _start_link(self, w: BusLink) -> None:
        assert self._tg is not None
        self._tg.start_soon(anyio.to_thread.run_sync, w.run)

    def config_view(self) -> dict[str, Any]:
        """What the daemon runs, for a recorder to keep beside the data and to build the same
        ROS 2 messages from: the config as loaded, its file's text, each device's calibration
        file's text (None where it cannot be read: its status says why)."""
        cfg = self.cfg
        return {
            "path": None if self.config_path is None else str(self.config_path),
            "text": _text(self.config_path),
            "config": cfg.model_dump(mode="json"),
            "calibration": {
                d.name: {"path": str(d.calibration), "text": _text(d.calibration)}
                for d in cfg.device
                if d.calibration is not None
            },
        }

    def _answer(self, q: zenoh.Query, body: dict[str, Any]) -> None:
        with q:
            q.reply(q.key_expr, json.dumps(body), encoding=zenoh.Encoding.APPLICATION_JSON)

    def _device_answer(self, name: str) -> Callable[[zenoh.Query], None]:
        def answer(q: zenoh.Query) -> None:
            v = self._view(name)
            if v is not None:  # gone in a reload: no answer, as for any unknown device
                self._answer(q, v.status().to_json())

        return answer

    async def run(self) -> int:
        z = self.cfg.session_settings()
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
            # the links first: they hold the devices' status, and from the moment the status
            # queryable is declared an answer must list every configured device (a client
            # waiting for "no device starting" would otherwise take an empty list for done)
            self.links = self._make_links(self.cfg, by_bus(self.cfg))
            self._declare_all(self.session, self.cfg)
            self._start_ros2(self.session, self.cfg)
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
                for w in self.links:
                    self._start_link(w)
                tg.start_soon(self._supervise)
                tg.start_soon(self._watch_config)
                tg.start_soon(self._ros2_ticks)
                await self._wait_for_stop()
                self.notifier.notify("STOPPING=1")
                for w in self.links:
                    w.stop.set()
                tg.cancel_scope.cancel()  # workers finish their current step and return
            for ends in self._ends.values():
                ends.undeclare()
        finally:
            if self.ros2 is not None:
                self.ros2.close()
            await anyio.to_thread.run_sync(self.session.close)
            if self.zygote is not None:
                self.zygote.close()
        log.info("imud stopped")
        return 0

    async def _ros2_ticks(self) -> None:
        """The ROS 2 output's once-a-second work: /diagnostics from the devices' status, and a
        calibration file's measured noise into the covariances."""
        while True:
            await anyio.sleep(ROS2_TICK_S)
            out = self.ros2
            if out is None:
                continue
            try:
                out.tick([v.status().to_json() for v in self.views], ROS2_TICK_S)
            except Exception:  # a bug there must not stop the daemon
                log.exception("ROS 2 output: diagnostics failed")

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
            if new.ros2.enabled:
                domain_id(new.ros2)  # $ROS_DOMAIN_ID too: before anything moves
        except (ConfigError, ZenohSetupError, DomainError) as e:
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
                elif d.publishes_truth and Stream.TRUTH not in ends.pubs:
                    ends.pubs[Stream.TRUTH] = _declare_publisher(
                        self.session, _key(prefix, d, Stream.TRUTH)
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
        ros2_was = self.cfg.ros2
        self.cfg = self.cfg.model_copy(
            update={"device": new.device, "zenoh": new.zenoh, "ros2": new.ros2}
        )
        assert self.session is not None
        if plan.zenoh_changed or new.ros2 != ros2_was or self.ros2 is None:
            self._start_ros2(self.session, self.cfg)
        else:
            self.ros2.reconfigure(self.cfg)
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
        self._ends, self._daemon_q = {}, []
        if self.ros2 is not None:
            self.ros2.close()
            self.ros2 = None
        for e in ends.values():
            e.undeclare()
        for one in q:
            with contextlib.suppress(zenoh.ZError):
                one.undeclare()
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
            session = await anyio.to_thread.run_sync(
                zenoh.open, daemon_config(new.session_settings())
            )
        except Exception as e:  # e.g. a new listen port is taken
            why = f"[zenoh]: cannot open the new session: {describe(e, new.zenoh.listen)}"
            if shared:  # back to the old settings, which held until a moment ago
                back = await anyio.to_thread.run_sync(
                    zenoh.open, daemon_config(old.session_settings())
                )
                self._declare_all(back, old)
            return why
        if shared:
            self._declare_all(session, new)
            return None
        old_session, old_ends, old_q = self.session, self._ends, self._daemon_q
        self._declare_all(session, new)
        for gone in old_ends.values():
            gone.undeclare()
        for one in old_q:
            with contextlib.suppress(zenoh.ZError):
                one.undeclare()
        if old_session is not None:
            await anyio.to_thread.run_sync(old_session.close)
        return None

    def _apply_buses(self, new: ImudConfig, plan: ReloadPlan) -> None:
        config = new.model_dump(mode="json")
        for w in [w for w in self.links if w.key in plan.stop]:
            w.stop.set()  # its worker puts its devices to sleep and returns
            self.links.remove(w)
        for w in self.links:
            bus_plan = plan.reconfigure.get(w.key)
            if bus_plan is not None:
                puts = [self._puts(s.device) for s in bus_plan.slots]
                w.reconfigure(bus_plan, config, puts)
        for w in self._make_links(new, plan.start):
            self.links.append(w)
            self._start_link(w)

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
        sts = [v.status() for v in self.views]
        running = sum(s.state == DeviceState.RUNNING for s in sts)
        lost = sum(s.lost_samples for s in sts)
        rate = sum(s.measured_rate_hz for s in sts)
        return f"{running}/{len(sts)} devices running, {rate:.0f} samples/s, {lost} lost"

    def _ready_line(self) -> str:
        sts = [v.status() for v in self.views]
        running = sum(s.state == DeviceState.RUNNING for s in sts)
        text = f"{running}/{len(sts)} devices running"
        down = [s for s in sts if s.state != DeviceState.RUNNING]
        if down:
            text += "; " + "; ".join(f"{s.name}: {s.state}: {s.last_error or '-'}" for s in down)
        return text

    def _serving(self, now_ns: int) -> list[str]:
        """What keeps the daemon from serving: links whose relay stopped making progress (or
        whose in-process worker hangs, which nothing can restart)."""
        return [w.key for w in self.links if now_ns - w.heartbeat_ns > self.stall_ns]

    async def _supervise(self) -> None:
        deadline = time.monotonic() + READY_TIMEOUT_S
        while (
            any(v.status().state == DeviceState.STARTING for v in self.views)
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


def _text(path: Path | None) -> str | None:
    """A small text file's content, or None where it cannot be read."""
    if path is None:
        return None
    try:
        return path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
