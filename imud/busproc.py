"""Each bus in its own process: no other thread of the daemon can hold its interpreter lock.

Measured on a 2-vCPU machine: with every bus worker in one process, a SCHED_FIFO worker still
waited 3-6 ms for the GIL now and then, longer than a 32 kHz FIFO lasts (docs/performance.md).
So the daemon runs each bus worker in a child process (`python -m imud.busproc`) that owns the
bus, its drivers, pipelines and simulators, and hands encoded batches and status snapshots to the
daemon over a unix SOCK_SEQPACKET socket (one message per batch, boundaries kept). The child
never blocks on the daemon: a full socket drops the batch and counts it (`publish_dropped`).
The daemon keeps Zenoh, the queryables, systemd and supervision, and restarts a child that dies.

Messages, child to daemon: b"P" + device index (u16) + kind (u8, 0 data 1 truth) + payload;
b"S" + JSON {"heartbeat_ns": int, "devices": [status, ...]}.
"""

from __future__ import annotations

import contextlib
import gc
import json
import logging
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

log = logging.getLogger("imud.busproc")

STATUS_EVERY_S = 0.2
RECV_MAX = 1 << 20
SNDBUF = 4 << 20
_HDR = struct.Struct("<cHB")
RESTART_MIN_S = 1.0
RESTART_MAX_S = 30.0


# --- child side -----------------------------------------------------------------------------
def _sender(sock: socket.socket, index: int, kind: int, on_drop: Callable[[], None]) -> Any:
    head = _HDR.pack(b"P", index, kind)

    def send(payload: bytes) -> None:
        try:
            sock.send(head + payload, socket.MSG_DONTWAIT)
        except BlockingIOError:
            on_drop()
        except OSError:  # the daemon is gone: stop
            os.kill(os.getpid(), signal.SIGTERM)

    return send


def child_main(fd: int, spec: dict[str, Any]) -> int:
    """Run one bus worker until SIGTERM (or the daemon's end of the socket closes)."""
    from imud.clock import MonotonicClock
    from imud.config import parse_config
    from imud.daemon import BusWorker, build_workers
    from imud.logsetup import setup_logging

    setup_logging(spec.get("log_level", "info"))
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the daemon, which stops us
    sock = socket.socket(fileno=fd)
    with contextlib.suppress(OSError):
        sock.setsockopt(socket.SOL_SOCKET, 32, SNDBUF)  # SO_SNDBUFFORCE (root): room for bursts
    cfg = parse_config(spec["config"])
    key = spec["bus"]

    def publish_for(index: int, _: Any, truth: bool, on_drop: Callable[[], None]) -> Any:
        return _sender(sock, index, 1 if truth else 0, on_drop)

    workers = build_workers(cfg, MonotonicClock(), spec["offset_ns"], publish_for, only_bus=key)
    worker: BusWorker = workers[0]
    signal.signal(signal.SIGTERM, lambda *_: worker.stop.set())

    def report() -> None:
        while not worker.stop.wait(STATUS_EVERY_S):
            body = {"heartbeat_ns": worker.heartbeat_ns,
                    "devices": [r.status() for r in worker.runners]}  # fmt: skip
            try:
                sock.send(b"S" + json.dumps(body).encode(), socket.MSG_DONTWAIT)
            except BlockingIOError:
                pass
            except OSError:
                worker.stop.set()

    threading.Thread(target=report, name="status", daemon=True).start()
    gc.collect()
    gc.freeze()  # see Daemon.run: no long collections on the acquisition path
    sys.setswitchinterval(0.0005)
    worker.run()
    return 0


# --- daemon side ----------------------------------------------------------------------------
class RunnerProxy:
    """What the daemon knows of a device run by a child: its last status snapshot."""

    def __init__(self, cfg: Any) -> None:
        from imud.buses.models import describe

        self.cfg = cfg
        buses = " + ".join(describe(b) for b in cfg.die_buses())
        self._status: dict[str, Any] = {
            "name": cfg.name, "chip": cfg.chip, "bus": buses, "state": "starting",
            "odr_hz": getattr(cfg, "odr_hz", None), "measured_rate_hz": 0.0, "samples": 0,
            "lost_samples": 0, "last_error": None,
        }  # fmt: skip

    def status(self) -> dict[str, Any]:
        return dict(self._status)

    def update(self, status: dict[str, Any]) -> None:
        self._status = status

    def down(self, msg: str) -> None:
        self._status = {**self._status, "state": "error", "last_error": msg,
                        "measured_rate_hz": 0.0}  # fmt: skip

    @property
    def state(self) -> str:
        return str(self._status.get("state"))

    @property
    def lost_samples(self) -> int:
        return int(self._status.get("lost_samples", 0))

    @property
    def measured_rate_hz(self) -> float:
        return float(self._status.get("measured_rate_hz", 0.0))


class BusProcess:
    """Runs one bus's child process, relays its batches to Zenoh and keeps its devices' status.
    `run()` blocks (a daemon thread); `stop` ends it and the child."""

    def __init__(
        self,
        key: str,
        devices: list[Any],
        spec: dict[str, Any],
        puts: list[tuple[Callable[[bytes], Any], Callable[[bytes], Any] | None]],
    ) -> None:
        self.key = key
        self.runners = [RunnerProxy(d) for d in devices]
        self.spec = {**spec, "bus": key}
        self.puts = puts  # per device: (data put, truth put or None)
        self.stop = threading.Event()
        self.heartbeat_ns = time.monotonic_ns()
        self.proc: subprocess.Popen[bytes] | None = None
        self._restart_s = RESTART_MIN_S

    def _spawn(self) -> socket.socket:
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        with theirs:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "imud.busproc", str(theirs.fileno())],
                stdin=subprocess.PIPE,
                pass_fds=[theirs.fileno()],
            )
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(self.spec).encode())
        self.proc.stdin.close()
        self.heartbeat_ns = time.monotonic_ns()
        return ours

    def _relay(self, sock: socket.socket) -> None:
        sock.settimeout(0.5)
        while not self.stop.is_set():
            try:
                msg = sock.recv(RECV_MAX)
            except TimeoutError:
                continue
            if not msg:
                return  # the child exited
            if msg[:1] == b"P":
                _, index, kind = _HDR.unpack_from(msg)
                put = self.puts[index][kind]
                if put is not None:
                    try:
                        put(msg[_HDR.size :])
                    except Exception:  # a closing session at shutdown: log, go on
                        log.exception("publishing failed")
            elif msg[:1] == b"S":
                body = json.loads(msg[1:])
                self.heartbeat_ns = int(body["heartbeat_ns"]) or time.monotonic_ns()
                for r, st in zip(self.runners, body["devices"], strict=True):
                    r.update(st)
                self._restart_s = RESTART_MIN_S

    def run(self) -> None:
        while not self.stop.is_set():
            sock = self._spawn()
            try:
                self._relay(sock)
            finally:
                sock.close()
                code = self._end_child()
            if self.stop.is_set():
                return
            msg = f"bus process for {self.key} exited with code {code}"
            log.error("%s; restarting it in %.0f s", msg, self._restart_s)
            for r in self.runners:
                r.down(msg)
            self.heartbeat_ns = time.monotonic_ns()
            self.stop.wait(self._restart_s)
            self._restart_s = min(2 * self._restart_s, RESTART_MAX_S)

    def _end_child(self, grace_s: float = 3.0) -> int | None:
        p = self.proc
        if p is None:
            return None
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(grace_s)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        return p.returncode


def main() -> int:
    fd = int(sys.argv[1])
    spec = json.loads(sys.stdin.buffer.read())
    return child_main(fd, spec)


if __name__ == "__main__":
    sys.exit(main())
