"""The daemon's side of the bus processes (`imud.buschild`): spawn one per bus, relay its batches
to Zenoh, keep its devices' status, and restart it when it dies or hangs.

A bus process that keeps crashing is restarted with capped backoff (0.5 s ... 10 s, reset once it
has run for 10 s) and shown in status (state `error`, `restarts`, `last_error`); the daemon, its
watchdog and the other buses go on. One that stops reporting progress for `[daemon]
hung_after_s` (default `HUNG_S`; a driver stuck inside a bus call) is killed and restarted the
same way. Counters in status add up over the process's lives, and a restarted process
continues each device's `seq` from where the relayed stream stopped, counting the samples the
outage held as lost.
"""

from __future__ import annotations

import contextlib
import json
import logging
import mmap
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from imud.backoff import Backoff
from imud.busmsg import (
    APPLIED,
    GENERATION,
    HEADER,
    KIND_DATA,
    PUBLISH,
    RAW_WANTED,
    RECONFIGURE,
    RECV_MAX,
    STATUS,
)
from imud.chips.api import DeviceBase
from imud.errors import BUS_ERROR_KEYS
from imud.status import DeviceState, initial_status

log = logging.getLogger("imud.busproc")

RESTART_MIN_NS = 500_000_000
RESTART_MAX_NS = 10_000_000_000
STABLE_NS = 10_000_000_000  # a process that ran this long starts its backoff over
# a bus process that ended cleanly (exit 0: it was sent SIGTERM) most likely got the signal with
# the daemon (systemd's KillMode=control-group, `timeout`, `kill -- -PGID`): the daemon's own
# stop is given this long to arrive before the end is taken for a crash and restarted
SIGNALLED_GRACE_S = 1.0
HUNG_S = 10.0  # default `[daemon] hung_after_s`: no worker progress this long, kill and restart
# a child's first report may take this long (imports, opening the bus; seven children starting
# at once on a busy 2-core machine took 6-10 s): only then does `hung_after_s` apply
START_S = 30.0
MEASURED_SAMPLES = 1000  # the relayed stream's period is trusted over at least this many
_WIRE_HEAD = struct.Struct("<6xHQI")  # name_len, first_seq, count: the head of imud.wire
_COUNTERS = (
    "samples", "lost_samples", "invalid_samples", "fifo_overflows", "bus_errors",
    "bad_registers", "restarts", "resets", "unexpected_errors", "publish_dropped",
    "calibration_outside_span", "garbled_transfers", "crc_errors", "checksum_errors",
    *BUS_ERROR_KEYS.values(),
)  # fmt: skip

Put = Callable[[bytes], Any]


def _recv_buffer() -> mmap.mmap:
    """A relay's receive buffer, big enough for any message (`RECV_MAX`), allocated once.

    Not `sock.recv(RECV_MAX)`: CPython mallocs RECV_MAX bytes for every message and shrinks the
    block to the message's size. The first such block freed whole (a receive that timed out
    while a child started) raised glibc's dynamic mmap threshold to its size (1 MiB + 4 KiB,
    read in the running daemon with gdb; the trim threshold to twice that), so from then on every
    message's 1 MiB came out of a malloc heap shared with Zenoh's and Python's allocations, each
    relay holding one while it waited in recv. The small blocks left in the holes meant that the
    next 1 MiB often had to come from fresh memory: on configs/sim.toml the daemon's RSS grew by
    15 MB in the 4 minutes after warm-up and kept growing (33 MB in 30 minutes on the soak
    config), all of it free memory inside the heaps (`malloc_trim(0)` gave back 22 MB), and
    more arenas only spread it over more heaps. Received here, the daemon stays at 66 MB
    (docs/reliability.md, "Soak"; bench/recv_heap.py shows the pattern alone). An anonymous
    private mapping costs RSS only for the pages messages touch (a batch is a few kB)."""
    return mmap.mmap(-1, RECV_MAX, flags=mmap.MAP_PRIVATE)


class RunnerProxy:
    """What the daemon knows of a device run by a child: its last status snapshot, with the
    counters of the child's earlier lives added, and where its stream has got to."""

    def __init__(self, cfg: DeviceBase) -> None:
        self.cfg = cfg
        self._status: dict[str, Any] = initial_status(cfg)
        self._base = dict.fromkeys(_COUNTERS, 0)  # counters of the earlier lives
        self._restarts = 0  # process restarts
        self.next_seq: int | None = None
        self.last_t_ns = 0
        self._first: tuple[int, int] | None = None  # (seq, stamp) of the first sample relayed
        self.raw_wanted = False
        self.on_want_raw: Callable[[bool], None] = lambda on: None

    def want_raw(self, on: bool) -> None:
        self.raw_wanted = on
        self.on_want_raw(on)

    def status(self) -> dict[str, Any]:
        st = dict(self._status)
        for k in _COUNTERS:
            st[k] = int(st.get(k, 0)) + self._base[k]
        st["restarts"] += self._restarts
        return st

    def update(self, status: dict[str, Any]) -> None:
        self._status = status

    def down(self, msg: str) -> None:
        """The child died: keep its counters, show the error until a new child reports."""
        for k in _COUNTERS:
            self._base[k] += int(self._status.get(k, 0))
        self._restarts += 1
        self._status = {
            **initial_status(self.cfg),
            "state": DeviceState.ERROR,
            "last_error": msg,
            "last_error_at": time.time(),
        }

    def saw_batch(self, payload: bytes) -> None:
        """Where the relayed stream has got to: a restarted child continues from there."""
        name_len, first_seq, n = _WIRE_HEAD.unpack_from(payload)
        if n:
            off = 32 + name_len + (-name_len) % 8 + 8 * (n - 1)
            self.next_seq = first_seq + n
            self.last_t_ns = int.from_bytes(payload[off : off + 8], "little", signed=True)
            if self._first is None:
                first = off - 8 * (n - 1)
                t0 = int.from_bytes(payload[first : first + 8], "little", signed=True)
                self._first = (first_seq, t0)

    @property
    def period_ns(self) -> float | None:
        """The chip's sample period as the relayed stream measured it, over everything relayed
        (seq counts chip samples, gaps included): a restarted child counts the gap of its
        predecessor's death with it, not with the nominal period."""
        if self._first is None or self.next_seq is None:
            return None
        samples = self.next_seq - 1 - self._first[0]
        return (self.last_t_ns - self._first[1]) / samples if samples >= MEASURED_SAMPLES else None

    @property
    def state(self) -> str:
        return str(self._status.get("state"))

    @property
    def lost_samples(self) -> int:
        return int(self._status.get("lost_samples", 0)) + self._base["lost_samples"]

    @property
    def measured_rate_hz(self) -> float:
        return float(self._status.get("measured_rate_hz", 0.0))


class BusProcess:
    """Runs one bus's child process, relays its batches and keeps its devices' status.
    `run()` blocks (a thread of the daemon); setting `stop` ends it and the child."""

    def __init__(
        self,
        key: str,
        devices: list[DeviceBase],
        spec: dict[str, Any],
        puts: list[tuple[Put, Put | None, Put]],
    ) -> None:
        self.key = key
        self.runners = self._proxies([RunnerProxy(d) for d in devices])
        self.spec = {**spec, "bus": key}
        self.hung_s = float(spec["config"].get("daemon", {}).get("hung_after_s", HUNG_S))
        self.puts = puts  # per device, by kind: (data put, truth put or None, raw put)
        # a reloaded config's device list, until the child says it applied it
        self._pending: tuple[list[RunnerProxy], list[tuple[Put, Put | None, Put]]] | None = None
        self._generation = 0  # of the child's device list the relay maps indices with
        self._sock: socket.socket | None = None
        self.stop = threading.Event()
        self.heartbeat_ns = time.monotonic_ns()  # the relay's own progress
        self.worker_heartbeat_ns = 0  # the child's bus worker's, from its status reports
        self._reported = False  # the current child has sent a status report
        self.proc: subprocess.Popen[bytes] | None = None
        self.backoff = Backoff(RESTART_MIN_NS, RESTART_MAX_NS)
        self.restarts = 0
        self.last_error: str | None = None
        self._recv_buf = _recv_buffer()

    def _proxies(self, proxies: list[RunnerProxy]) -> list[RunnerProxy]:
        for i, r in enumerate(proxies):
            r.on_want_raw = lambda on, i=i: self.want_raw(i, on)  # type: ignore[misc]
        return proxies

    def want_raw(self, index: int, on: bool) -> None:
        """Someone started or stopped subscribing to a device's raw stream: tell the child (a
        child started later is told in its spec; a reload's new list, once applied)."""
        sock = self._sock
        if sock is not None and self._pending is None:
            # a child that is gone or going cannot hear it: its successor reads the spec
            with contextlib.suppress(OSError):
                sock.send(HEADER.pack(RAW_WANTED, index, int(on)), socket.MSG_DONTWAIT)

    def reconfigure(
        self,
        devices: list[DeviceBase],
        config: dict[str, Any],
        puts: list[tuple[Put, Put | None, Put]],
        raw_on: set[str],
    ) -> None:
        """A reloaded config (`config`, JSON-ready) puts `devices` on this bus: the child keeps
        the unchanged ones running and restarts, starts or stops the rest. Its batches keep the
        old device indices until it acknowledges; a child started from now on gets the new
        config in its spec."""
        old = {r.cfg.name: r for r in self.runners}
        proxies: list[RunnerProxy] = []
        for d in devices:
            prev = old.get(d.name)
            if prev is not None and prev.cfg == d:
                proxies.append(prev)
                continue
            p = RunnerProxy(d)
            p.raw_wanted = d.name in raw_on
            if prev is not None:  # restarted: its stream's seq continues
                p.next_seq, p.last_t_ns = prev.next_seq, prev.last_t_ns
            proxies.append(p)
        self._pending = (proxies, puts)
        self.spec["config"] = config
        self.hung_s = float(config.get("daemon", {}).get("hung_after_s", HUNG_S))
        sock = self._sock
        if sock is not None:
            with contextlib.suppress(OSError):  # gone: its successor starts from the spec
                sock.send(RECONFIGURE + json.dumps({"config": config}).encode())

    def _take_pending(self, generation: int) -> None:
        pending, self._pending = self._pending, None
        self._generation = generation
        if pending is None:
            return
        proxies, self.puts = pending
        self.runners = self._proxies(proxies)
        for i, r in enumerate(self.runners):  # the child's new runners start without raw
            if r.raw_wanted:
                self.want_raw(i, True)

    def _spawn(self) -> socket.socket:
        self._take_pending(0)  # a new child starts from the spec's config, generation 0
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        resume = {
            str(i): [r.next_seq, r.last_t_ns, r.period_ns]
            for i, r in enumerate(self.runners)
            if r.next_seq is not None
        }
        with theirs:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "imud.buschild", str(theirs.fileno())],
                stdin=subprocess.PIPE,
                pass_fds=[theirs.fileno()],
            )
        assert self.proc.stdin is not None
        raw = [i for i, r in enumerate(self.runners) if r.raw_wanted]
        self.proc.stdin.write(json.dumps({**self.spec, "resume": resume, "raw": raw}).encode())
        self.proc.stdin.close()
        self.heartbeat_ns = self.worker_heartbeat_ns = time.monotonic_ns()
        self._reported = False
        return ours

    def _relay(self, sock: socket.socket) -> str | None:
        """Until the child exits (None) or hangs (why).

        Messages are received into this relay's own buffer (`_recv_buffer`), and each batch is
        copied out at its size: `sock.recv(RECV_MAX)` would malloc 1 MiB per message and shrink
        it, which fragments the daemon's heap for good (see `_recv_buffer`)."""
        sock.settimeout(0.5)
        buf = self._recv_buf
        view = memoryview(buf)
        while not self.stop.is_set():
            self.heartbeat_ns = time.monotonic_ns()
            limit = self.hung_s if self._reported else max(self.hung_s, START_S)
            if self.heartbeat_ns - self.worker_heartbeat_ns > limit * 1e9:
                return f"bus worker made no progress for {limit:g} s (stuck in a bus call?)"
            try:
                n = sock.recv_into(buf)
            except TimeoutError:
                continue
            if not n:
                return None  # the child exited
            tag = buf[:1]
            if tag == PUBLISH:
                _, index, kind = HEADER.unpack_from(buf)
                payload = view[HEADER.size : n].tobytes()
                put = self.puts[index][kind]
                if kind == KIND_DATA:
                    self.runners[index].saw_batch(payload)
                if put is not None:
                    try:
                        put(payload)
                    except Exception:  # a closing session at shutdown: log, go on
                        log.exception("publishing failed")
            elif tag == STATUS:
                body = json.loads(view[1:n].tobytes())
                self.worker_heartbeat_ns = int(body["heartbeat_ns"]) or time.monotonic_ns()
                self._reported = True
                if int(body.get("generation", 0)) == self._generation:
                    for r, st in zip(self.runners, body["devices"], strict=True):
                        r.update(st)
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
            except OSError as e:
                why = f"cannot start the bus process: {e}"
            else:
                self._sock = sock
                try:
                    why = self._relay(sock)
                except Exception as e:  # a malformed message: a bug; restart the child
                    log.exception("relaying bus %s failed", self.key)
                    why = f"relay failed: {type(e).__name__}: {e}"
                finally:
                    self._sock = None
                    sock.close()
                    code = self._end_child(kill=why is not None)
            if self.stop.is_set() or (code == 0 and self.stop.wait(SIGNALLED_GRACE_S)):
                return
            now = time.monotonic_ns()
            if now - started >= STABLE_NS:
                self.backoff.reset()
            wait = self.backoff.failed(now)
            msg = f"bus process for {self.key} {why or f'exited with code {code}'}"
            self.restarts += 1
            self.last_error = msg
            log.error("%s; restarting it in %.1f s", msg, wait / 1e9)
            for r in self.runners:
                r.down(msg)
            self._sleep(wait)

    def _sleep(self, ns: int) -> None:
        """Wait before a restart, still showing the daemon that this relay is alive."""
        end = time.monotonic_ns() + ns
        while not self.stop.is_set() and (left := end - time.monotonic_ns()) > 0:
            self.heartbeat_ns = time.monotonic_ns()
            self.stop.wait(min(left, 500_000_000) / 1e9)

    def _end_child(self, grace_s: float = 3.0, kill: bool = False) -> int | None:
        p = self.proc
        if p is None:
            return None
        if p.poll() is None:
            p.send_signal(signal.SIGKILL if kill else signal.SIGTERM)
            try:
                p.wait(grace_s)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        return p.returncode
