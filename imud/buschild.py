"""A bus process: one bus worker in a process of its own (`python -m imud.buschild FD`).

Measured on a 2-vCPU machine: with every bus worker in one process, a SCHED_FIFO worker still
waited 3-6 ms for the GIL now and then, longer than a 32 kHz FIFO lasts (docs/performance.md).
So each bus runs here, owning the bus, its drivers, pipelines and simulators, and hands encoded
batches and status snapshots to the daemon over a socket (`imud.busmsg`). It never blocks on the
daemon: a full socket drops the batch and counts it (`publish_dropped`). It imports neither Zenoh
nor the event loop: the daemon (`imud.busproc`) keeps those, and restarts this process if it dies.

The daemon sends the spec on stdin as JSON: the config, the clock offset, the log level, which
bus, and for each device the sequence number and last stamp it had reached (a restart continues
the stream's `seq`, counting the samples lost meanwhile).
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import signal
import socket
import sys
import threading
from collections.abc import Callable
from typing import Any

from imud.busmsg import (
    APPLIED,
    GENERATION,
    HEADER,
    PUBLISH,
    RAW_WANTED,
    RECONFIGURE,
    RECV_MAX,
    STATUS,
)
from imud.busworker import BusWorker, build_workers
from imud.clock import MonotonicClock
from imud.config import parse_config
from imud.logsetup import setup_logging

STATUS_EVERY_S = 0.2
SNDBUF = 4 << 20


def _sender(sock: socket.socket, index: int, kind: int, on_drop: Callable[[], None]) -> Any:
    head = HEADER.pack(PUBLISH, index, kind)

    def send(payload: bytes) -> None:
        try:
            sock.send(head + payload, socket.MSG_DONTWAIT)
        except BlockingIOError:
            on_drop()
        except OSError:  # the daemon is gone: stop
            os.kill(os.getpid(), signal.SIGTERM)

    return send


def _report(sock: socket.socket, worker: BusWorker) -> None:
    while not worker.stop.wait(STATUS_EVERY_S):
        generation, runners = worker.generation, worker.runners
        devices = [r.status() for r in runners]
        if worker.generation != generation:  # the device list changed meanwhile: next time
            continue
        body = {"heartbeat_ns": worker.heartbeat_ns, "generation": generation, "devices": devices}
        try:
            sock.send(STATUS + json.dumps(body).encode(), socket.MSG_DONTWAIT)
        except BlockingIOError:
            pass
        except OSError:
            worker.stop.set()


def _listen(sock: socket.socket, worker: BusWorker) -> None:
    """The daemon's requests: start or stop computing a device's uncorrected stream; a
    reloaded config."""
    while not worker.stop.is_set():
        try:
            msg = sock.recv(RECV_MAX)
        except OSError:
            return
        if not msg:
            return  # the daemon closed its end; the sender notices and stops us
        if msg[:1] == RAW_WANTED and len(msg) == HEADER.size:
            _, index, on = HEADER.unpack(msg)
            runners = worker.runners
            if index < len(runners):
                runners[index].want_raw(bool(on))
        elif msg[:1] == RECONFIGURE:
            cfg = parse_config(json.loads(msg[1:])["config"])
            worker.reconfigure([d for d in cfg.device if d.bus.key == worker.key])


def _acknowledge(sock: socket.socket) -> Callable[[BusWorker], None]:
    def applied(worker: BusWorker) -> None:
        # blocking: the daemon must see it before any batch under the new device indices
        with contextlib.suppress(OSError):
            sock.send(APPLIED + GENERATION.pack(worker.generation))

    return applied


def child_main(fd: int, spec: dict[str, Any]) -> int:
    """Run one bus worker until SIGTERM (or the daemon's end of the socket closes)."""
    setup_logging(spec.get("log_level", "info"))
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the daemon, which stops us
    sock = socket.socket(fileno=fd)
    with contextlib.suppress(OSError):
        sock.setsockopt(socket.SOL_SOCKET, 32, SNDBUF)  # SO_SNDBUFFORCE (root): room for bursts
    cfg = parse_config(spec["config"])
    offset = int(spec["offset_ns"])

    def publish_for(index: int, _: Any, kind: int, on_drop: Callable[[], None]) -> Any:
        return _sender(sock, index, kind, on_drop)

    (worker,) = build_workers(cfg, MonotonicClock(), offset, publish_for, only_bus=spec["bus"])
    worker.on_reconfigured = _acknowledge(sock)
    for index, (next_seq, last_t_ns, *period) in spec.get("resume", {}).items():
        measured = float(period[0]) if period and period[0] else None
        worker.runners[int(index)].resume(int(next_seq), int(last_t_ns) - offset, measured)
    for index in spec.get("raw", []):
        worker.runners[int(index)].want_raw(True)
    signal.signal(signal.SIGTERM, lambda *_: worker.stop.set())
    threading.Thread(target=_report, args=(sock, worker), name="status", daemon=True).start()
    threading.Thread(target=_listen, args=(sock, worker), name="control", daemon=True).start()
    gc.collect()
    gc.freeze()  # see Daemon.run: no long collections on the acquisition path
    sys.setswitchinterval(0.0005)
    worker.run()
    return 0


def main() -> int:
    fd = int(sys.argv[1])
    spec = json.loads(sys.stdin.buffer.read())
    return child_main(fd, spec)


if __name__ == "__main__":
    sys.exit(main())
