"""The daemon's side of a bus worker: start it, relay its batches to Zenoh, keep its devices'
status, and restart it when it dies or hangs.

A worker runs behind a socket (`imud.buschild`), in a process of its own (`ProcessTransport`, the
default) or in a thread of the daemon (`ThreadTransport`, `[daemon] bus_processes = false`); the
relay, the status, the reload and the restart are the same for both. A worker that keeps
crashing is restarted with capped backoff (0.5 s ... 10 s, reset once it has run for 10 s) and
shown in status (state `error`, `restarts`, `last_error`); the daemon, its watchdog and the other
buses go on. One that stops reporting progress for `[daemon] hung_after_s` (a driver stuck inside
a bus call) is killed and restarted the same way; a thread cannot be killed, so an in-process
worker that hangs stops this relay's heartbeat instead, and the watchdog with it, until it moves
again. Counters in status add up over a worker's lives, and a restarted worker continues each
device's `seq` from where the relayed stream stopped, counting the samples the outage held as
lost.
"""

from __future__ import annotations

import contextlib
import json
import logging
import mmap
import multiprocessing
import os
import signal
import socket
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from imud.backoff import Backoff
from imud.busmsg import (
    APPLIED,
    GENERATION,
    HEADER,
    PUBLISH,
    RAW_WANTED,
    RECONFIGURE,
    RECV_MAX,
    STATUS,
    Stream,
)
from imud.chips.api import DeviceBase

if TYPE_CHECKING:
    from imud.busworker import BusWorker
    from imud.zygote import Zygote
from imud.device import initial_status
from imud.reload import Action, BusPlan
from imud.status import DeviceState, DeviceStatus
from imud.wire import peek

log = logging.getLogger("imud.buslink")

RESTART_MIN_NS = 500_000_000
RESTART_MAX_NS = 10_000_000_000
STABLE_NS = 10_000_000_000  # a worker that ran this long starts its backoff over
# a bus process that ended cleanly (exit 0: it was sent SIGTERM) most likely got the signal with
# the daemon (systemd's KillMode=control-group, `timeout`, `kill -- -PGID`): the daemon's own
# stop is given this long to arrive before the end is taken for a crash and restarted
SIGNALLED_GRACE_S = 1.0
HUNG_S = 10.0  # default `[daemon] hung_after_s`: no worker progress this long, kill and restart
# a worker's first report may take this long (imports, opening the bus; seven processes starting
# at once on a busy 2-core machine took 6-10 s): only then does `hung_after_s` apply
START_S = 30.0
MEASURED_SAMPLES = 1000  # the relayed stream's period is trusted over at least this many

Put = Callable[[bytes], Any]
Puts = dict[Stream, Put]  # one device's publishers, by stream


def _recv_buffer() -> mmap.mmap:
    """A relay's receive buffer, big enough for any message (`RECV_MAX`), allocated once.

    Not `sock.recv(RECV_MAX)`: CPython mallocs RECV_MAX bytes for every message and shrinks the
    block to the message's size. Once one such block is freed whole, glibc raises its dynamic
    mmap threshold above it, and from then on every message's 1 MiB comes out of a heap shared
    with Zenoh's and Python's allocations; the small blocks left in the holes fragment it for
    good (the daemon's RSS grew by 33 MB in 30 minutes; docs/reliability.md, "Soak";
    bench/recv_heap.py shows the pattern alone). An anonymous private mapping costs RSS only for
    the pages messages touch (a batch is a few kB)."""
    return mmap.mmap(-1, RECV_MAX, flags=mmap.MAP_PRIVATE)


class DeviceView:
    """What the daemon knows of a device its bus worker runs: the worker's last status snapshot
    with the counters of its earlier lives added, and where its stream has got to."""

    def __init__(self, cfg: DeviceBase, raw_wanted: bool = False) -> None:
        self.cfg = cfg
        self._status = initial_status(cfg)
        self._earlier = initial_status(cfg)  # counters of the worker's earlier lives
        self.next_seq: int | None = None
        self.last_t_ns = 0
        self._first: tuple[int, int] | None = None  # (seq, stamp) of the first sample relayed
        self.raw_wanted = raw_wanted
        # what this life of the worker published, counted here from the relayed batches: a
        # worker that dies publishes for up to a status period after its last report
        self._relayed = 0
        self._relayed_lost = 0

    def status(self) -> DeviceStatus:
        return self._status.plus(self._earlier)

    def update(self, status: DeviceStatus) -> None:
        self._status = status

    def down(self, msg: str) -> None:
        """The worker died: keep its counters, show the error until a new one reports."""
        last = self._status
        last.samples = max(last.samples, self._relayed)
        last.lost_samples = max(last.lost_samples, self._relayed_lost)
        self._relayed = self._relayed_lost = 0
        self._earlier = last.plus(self._earlier)
        self._earlier.restarts += 1
        self._status = initial_status(self.cfg)
        self._status.state = DeviceState.ERROR
        self._status.last_error, self._status.last_error_at = msg, time.time()

    def continues(self, prev: DeviceView) -> None:
        """This device replaces `prev` (restarted with new settings): its stream goes on."""
        self.next_seq, self.last_t_ns = prev.next_seq, prev.last_t_ns

    def saw_batch(self, payload: bytes | memoryview) -> None:
        """Where the relayed stream has got to: a restarted worker continues from there."""
        first_seq, n, t_first, t_last, lost = peek(payload)
        self._relayed += n
        self._relayed_lost += lost
        if n:
            self.next_seq = first_seq + n
            self.last_t_ns = t_last
            if self._first is None:
                self._first = (first_seq, t_first)

    @property
    def period_ns(self) -> float | None:
        """The chip's sample period as the relayed stream measured it, over everything relayed
        (seq counts chip samples, gaps included): a restarted worker counts the gap of its
        predecessor's death with it, not with the nominal period."""
        if self._first is None or self.next_seq is None:
            return None
        samples = self.next_seq - 1 - self._first[0]
        return (self.last_t_ns - self._first[1]) / samples if samples >= MEASURED_SAMPLES else None

    @property
    def resume(self) -> list[Any] | None:
        """What a new worker continues this device's stream from (its spec's `resume`)."""
        if self.next_seq is None:
            return None
        return [self.next_seq, self.last_t_ns, self.period_ns]


class Transport(Protocol):
    """How a bus worker is run: a process of its own, or a thread of the daemon."""

    killable: bool

    def start(self, theirs: socket.socket, spec: dict[str, Any]) -> None:
        """Start the worker on its end of the socket."""

    def end(self, kill: bool) -> int | None:
        """Stop it (`kill`: it hangs) and wait; its exit code (0: ended cleanly), None when it
        is still running (a hung thread, which nothing can kill)."""

    @property
    def pid(self) -> int | None:
        """Its process, while it runs (None in-process)."""


_FORKSERVER: Any = None


def _forkserver() -> Any:
    """The context bus processes are forked from: a server process, started once (a fresh
    interpreter, not a fork of this threaded one), that has imported the bus worker and
    everything below it. A bus process then starts in milliseconds instead of the ~0.9 s an
    interpreter takes to import NumPy, pydantic and the chips (a restart after a crash, and
    every bus of a daemon starting), and shares those pages with its siblings."""
    global _FORKSERVER
    if _FORKSERVER is None:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(["imud.buschild"])
        _FORKSERVER = ctx
    return _FORKSERVER


class ProcessTransport:
    killable = True  # a hung worker is killed and restarted

    def __init__(self) -> None:
        self.proc: Any = None  # a multiprocessing Process

    def start(self, theirs: socket.socket, spec: dict[str, Any]) -> None:
        from imud.buschild import child_main

        self.proc = _forkserver().Process(
            target=child_main, args=(theirs, spec), name=f"imud bus {spec['bus']}"
        )
        self.proc.start()

    def end(self, kill: bool, grace_s: float = 3.0) -> int | None:
        p = self.proc
        if p is None:
            return None
        if p.is_alive():
            if kill:
                p.kill()
            else:
                p.terminate()
            p.join(grace_s)
            if p.is_alive():
                p.kill()
                p.join()
        else:
            p.join()
        code: int | None = p.exitcode
        return code

    @property
    def pid(self) -> int | None:
        p = self.proc
        return p.pid if p is not None and p.is_alive() else None


class ZygoteTransport:
    """A process of its own, forked by the daemon's zygote (`imud.zygote`)."""

    killable = True

    def __init__(self, zygote: Zygote) -> None:
        self.zygote = zygote
        self._pid: int | None = None

    def start(self, theirs: socket.socket, spec: dict[str, Any]) -> None:
        self._pid = self.zygote.spawn(theirs, spec)

    def end(self, kill: bool, grace_s: float = 3.0) -> int | None:
        pid = self._pid
        if pid is None:
            return None
        if not self.zygote.ended(pid):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL if kill else signal.SIGTERM)
        code = self.zygote.wait(pid, grace_s)
        if code is None and not self.zygote.ended(pid):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            code = self.zygote.wait(pid, grace_s)
        return code

    @property
    def pid(self) -> int | None:
        pid = self._pid
        return pid if pid is not None and not self.zygote.ended(pid) else None


class ThreadTransport:
    killable = False  # a thread stuck in a bus call cannot be stopped from outside

    def __init__(self) -> None:
        self._thread: threading.Thread | None = None
        self.worker: BusWorker | None = None  # the worker itself: in-process, it can be looked at
        self._failed = False

    def start(self, theirs: socket.socket, spec: dict[str, Any]) -> None:
        from imud.buschild import build, serve

        sock = socket.socket(fileno=socket.dup(theirs.fileno()))
        worker = build(sock, spec)
        self.worker, self._failed = worker, False

        def run() -> None:
            try:
                serve(sock, worker)
            except Exception:
                self._failed = True
                log.exception("bus worker %s failed", spec["bus"])
            finally:
                sock.close()

        self._thread = threading.Thread(target=run, name=f"bus {spec['bus']}", daemon=True)
        self._thread.start()

    def end(self, kill: bool, grace_s: float = 3.0) -> int | None:
        if self._thread is None or self.worker is None:
            return None
        self.worker.stop.set()
        self._thread.join(0.0 if kill else grace_s)
        if self._thread.is_alive():
            return None
        return 1 if self._failed else 0

    @property
    def pid(self) -> int | None:
        return None


class BusLink:
    """Runs one bus's worker through its transport, relays its batches and keeps its devices'
    status. `run()` blocks (a thread of the daemon); setting `stop` ends it and the worker."""

    def __init__(
        self,
        key: str,
        devices: list[DeviceBase],
        spec: dict[str, Any],
        puts: list[Puts],
        transport: Callable[[], Transport],
        raw_on: set[str],
    ) -> None:
        self.key = key
        self.views = [DeviceView(d, d.name in raw_on) for d in devices]
        self.spec = {**spec, "bus": key}
        self.hung_s = float(spec["config"].get("daemon", {}).get("hung_after_s", HUNG_S))
        self.puts = puts  # per device, by stream
        self.transport_factory = transport
        self.transport: Transport | None = None
        # a reload's views and publishers, until the worker says it applied the plan
        self._pending: tuple[list[DeviceView], list[Puts]] | None = None
        self._generation = 0  # of the worker's device list the relay maps indices with
        self._sock: socket.socket | None = None
        self.stop = threading.Event()
        self.heartbeat_ns = time.monotonic_ns()  # the relay's own progress
        self.worker_heartbeat_ns = 0  # the worker's, from its status reports
        self._reported = False  # the current worker has sent a status report
        self.backoff = Backoff(RESTART_MIN_NS, RESTART_MAX_NS)
        self.restarts = 0
        self.last_error: str | None = None
        self.cpu_s: float | None = None  # the bus process's CPU time, as it last reported
        self.sim_cpu_s: float | None = None  # the simulators' part of it
        self._recv_buf = _recv_buffer()

    @property
    def pid(self) -> int | None:
        return self.transport.pid if self.transport is not None else None

    def index(self, name: str) -> int | None:
        return next((i for i, v in enumerate(self.views) if v.cfg.name == name), None)

    def want_raw(self, name: str, on: bool) -> None:
        """Someone started or stopped subscribing to a device's raw stream: tell the worker (a
        worker started later is told in its spec; a reload's new list, once applied)."""
        i = self.index(name)
        if i is None:
            return
        self.views[i].raw_wanted = on
        sock = self._sock
        if sock is not None and self._pending is None:
            # a worker that is gone or going cannot hear it: its successor reads the spec
            with contextlib.suppress(OSError):
                sock.send(HEADER.pack(RAW_WANTED, i, int(on)), socket.MSG_DONTWAIT)

    def reconfigure(self, plan: BusPlan, config: dict[str, Any], puts: list[Puts]) -> None:
        """A reload's plan for this bus (`config`, JSON-ready, is the new config): the worker
        applies it; batches keep the old device indices until it acknowledges. A worker started
        from now on gets the new config in its spec."""
        views: list[DeviceView] = []
        for slot in plan.slots:
            prev = self.views[slot.was] if slot.was is not None else None
            if slot.action is Action.KEEP and prev is not None:
                views.append(prev)
                continue
            v = DeviceView(slot.device, prev.raw_wanted if prev is not None else False)
            if slot.action is Action.RESTART and prev is not None:
                v.continues(prev)
            views.append(v)
        self._pending = (views, puts)
        self.spec["config"] = config
        self.hung_s = float(config.get("daemon", {}).get("hung_after_s", HUNG_S))
        sock = self._sock
        if sock is not None:
            body = {"config": config, "plan": plan.to_json()}
            with contextlib.suppress(OSError):  # gone: its successor starts from the spec
                sock.send(RECONFIGURE + json.dumps(body).encode())

    def _take_pending(self, generation: int) -> None:
        pending, self._pending = self._pending, None
        self._generation = generation
        if pending is None:
            return
        self.views, self.puts = pending
        sock = self._sock
        for i, v in enumerate(self.views):  # the worker's new runners start without raw
            if v.raw_wanted and sock is not None:
                with contextlib.suppress(OSError):
                    sock.send(HEADER.pack(RAW_WANTED, i, 1), socket.MSG_DONTWAIT)

    def _spawn(self) -> socket.socket:
        self._take_pending(0)  # a new worker starts from the spec's config, generation 0
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        resume = {str(i): v.resume for i, v in enumerate(self.views) if v.resume is not None}
        raw = [i for i, v in enumerate(self.views) if v.raw_wanted]
        self.transport = self.transport_factory()
        try:
            with theirs:
                self.transport.start(theirs, {**self.spec, "resume": resume, "raw": raw})
        except BaseException:
            ours.close()
            raise
        self.heartbeat_ns = self.worker_heartbeat_ns = time.monotonic_ns()
        self._reported = False
        return ours

    def _relay(self, sock: socket.socket) -> str | None:
        """Until the worker ends (None) or hangs (why).

        Messages are received into this relay's own buffer (`_recv_buffer`), and each batch is
        copied out at its size."""
        sock.settimeout(0.5)
        buf = self._recv_buf
        view = memoryview(buf)
        killable = self.transport is None or self.transport.killable
        hung_logged = False
        while not self.stop.is_set():
            now = time.monotonic_ns()
            limit = self.hung_s if self._reported else max(self.hung_s, START_S)
            hung = now - self.worker_heartbeat_ns > limit * 1e9
            why = f"bus worker made no progress for {limit:g} s (stuck in a bus call?)"
            if hung and killable:
                return why
            if killable or not self._reported:
                self.heartbeat_ns = now
            else:
                # nothing can restart a thread: the daemon sees this link as far as its worker
                # got, so a worker stuck in a bus call stops the watchdog until it moves again
                self.heartbeat_ns = self.worker_heartbeat_ns
                if hung and not hung_logged:
                    log.error("bus %s: %s; an in-process worker cannot be restarted", self.key, why)
                hung_logged = hung
            try:
                n = sock.recv_into(buf)
            except TimeoutError:
                continue
            if not n:
                return None  # the worker ended
            tag = buf[:1]
            if tag == PUBLISH:
                _, index, stream = HEADER.unpack_from(buf)
                payload = view[HEADER.size : n].tobytes()
                if stream == Stream.DATA:
                    self.views[index].saw_batch(payload)
                put = self.puts[index].get(Stream(stream))
                if put is not None:
                    try:
                        put(payload)
                    except Exception:  # a closing session at shutdown: log, go on
                        log.exception("publishing failed")
            elif tag == STATUS:
                body = json.loads(view[1:n].tobytes())
                self.worker_heartbeat_ns = int(body["heartbeat_ns"]) or time.monotonic_ns()
                self.cpu_s, self.sim_cpu_s = body.get("cpu_s"), body.get("sim_cpu_s")
                self._reported = True
                if int(body.get("generation", 0)) == self._generation:
                    for v, st in zip(self.views, body["devices"], strict=True):
                        v.update(DeviceStatus.from_json(st))
            elif tag == APPLIED:
                (generation,) = GENERATION.unpack_from(buf, 1)
                self._take_pending(generation)
        return None

    def run(self) -> None:
        while not self.stop.is_set():
            started = time.monotonic_ns()
            why: str | None = None
            code: int | None = None
            try:
                sock = self._spawn()
            except Exception as e:
                why = f"cannot start the bus worker: {type(e).__name__}: {e}"
            else:
                self._sock = sock
                try:
                    why = self._relay(sock)
                except Exception as e:  # a malformed message: a bug; restart the worker
                    log.exception("relaying bus %s failed", self.key)
                    why = f"relay failed: {type(e).__name__}: {e}"
                finally:
                    self._sock = None
                    sock.close()
                    code = self._end(kill=why is not None)
            if self.stop.is_set() or (code == 0 and self.stop.wait(SIGNALLED_GRACE_S)):
                return
            now = time.monotonic_ns()
            if now - started >= STABLE_NS:
                self.backoff.reset()
            wait = self.backoff.failed(now)
            msg = f"bus worker for {self.key} {why or f'exited with code {code}'}"
            self.restarts += 1
            self.last_error = msg
            log.error("%s; restarting it in %.1f s", msg, wait / 1e9)
            for v in self.views:
                v.down(msg)
            self._sleep(wait)

    def _end(self, kill: bool) -> int | None:
        t = self.transport
        return t.end(kill) if t is not None else None

    def _sleep(self, ns: int) -> None:
        """Wait before a restart, still showing the daemon that this relay is alive."""
        end = time.monotonic_ns() + ns
        while not self.stop.is_set() and (left := end - time.monotonic_ns()) > 0:
            self.heartbeat_ns = time.monotonic_ns()
            self.stop.wait(min(left, 500_000_000) / 1e9)
