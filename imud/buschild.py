"""A bus worker's end of its socket to the daemon: one `BusWorker`, its batches and status
snapshots out, the daemon's requests in (`imud.busmsg`).

It runs as a process of its own (`child_main`, the default: no other bus, nor Zenoh, nor the
event loop can hold its interpreter lock; measured on a 2-vCPU machine, a SCHED_FIFO worker
sharing a process waited 3-6 ms for the GIL now and then, longer than a 32 kHz FIFO lasts,
docs/performance.md) or as a thread of the daemon (`[daemon] bus_processes = false`).
Both run this same code over the same socket; only how it is started and stopped differs
(`imud.buslink`). It never blocks on the daemon: a full socket drops the batch and counts it
(`publish_dropped`). It imports neither Zenoh nor the event loop.

The daemon sends a spec (JSON): the config, the clock offset, the log level, which bus, for each
device the sequence number, last stamp and measured period it had reached (a restarted worker
continues the stream's `seq`, counting the samples lost meanwhile), and whose raw stream is
wanted.
"""

from __future__ import annotations

import contextlib
import gc
import json
import signal
import socket
import sys
import threading
import time
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
    Stream,
)
from imud.busworker import BusWorker, build_worker
from imud.clock import MonotonicClock
from imud.config import parse_config
from imud.emit import Publish
from imud.logsetup import setup_logging
from imud.reload import BusPlan
from imud.sim.cpu import total_ns as sim_cpu_ns

STATUS_EVERY_S = 0.2
SNDBUF = 4 << 20


def _outlet(sock: socket.socket, stop: threading.Event) -> Any:
    def outlet(index: int, stream: Stream, on_drop: Callable[[], None]) -> Publish:
        head = HEADER.pack(PUBLISH, index, stream)

        def send(payload: bytes) -> None:
            try:
                sock.send(head + payload, socket.MSG_DONTWAIT)
            except BlockingIOError:
                on_drop()
            except OSError:  # the daemon is gone: stop
                stop.set()

        return send

    return outlet


def _report(sock: socket.socket, worker: BusWorker) -> None:
    while not worker.stop.wait(STATUS_EVERY_S):
        generation, runners = worker.generation, worker.runners
        devices = [r.status().to_json() for r in runners]
        if worker.generation != generation:  # the device list changed meanwhile: next time
            continue
        body = {
            "heartbeat_ns": worker.heartbeat_ns,
            "generation": generation,
            "devices": devices,
            # the process's CPU, and the simulators' part of it (zero on silicon): imud's own
            # cost is the difference
            "cpu_s": round(time.process_time(), 4),
            "sim_cpu_s": round(sim_cpu_ns() / 1e9, 4),
        }
        try:
            sock.send(STATUS + json.dumps(body).encode(), socket.MSG_DONTWAIT)
        except BlockingIOError:
            pass
        except OSError:
            worker.stop.set()


def _listen(sock: socket.socket, worker: BusWorker) -> None:
    """The daemon's requests, until it closes its end (which stops the worker): start or stop
    computing a device's uncorrected stream; a reload's plan for this bus."""
    while not worker.stop.is_set():
        try:
            msg = sock.recv(RECV_MAX)
        except OSError:
            msg = b""
        if not msg:
            worker.stop.set()
            return
        if msg[:1] == RAW_WANTED and len(msg) == HEADER.size:
            _, index, on = HEADER.unpack(msg)
            runners = worker.runners
            if index < len(runners):
                runners[index].want_raw(bool(on))
        elif msg[:1] == RECONFIGURE:
            body = json.loads(msg[1:])
            cfg = parse_config(body["config"])
            devices = [d for d in cfg.device if d.bus.key == worker.key]
            worker.reconfigure(BusPlan.from_json(body["plan"], devices))


def _acknowledge(sock: socket.socket) -> Callable[[BusWorker], None]:
    def applied(worker: BusWorker) -> None:
        # blocking: the daemon must see it before any batch under the new device indices
        with contextlib.suppress(OSError):
            sock.send(APPLIED + GENERATION.pack(worker.generation))

    return applied


def build(sock: socket.socket, spec: dict[str, Any]) -> BusWorker:
    """The worker a spec describes, publishing on `sock`."""
    cfg = parse_config(spec["config"])
    offset = int(spec["offset_ns"])
    devices = [d for d in cfg.device if d.bus.key == spec["bus"]]
    stop = threading.Event()
    worker = build_worker(
        spec["bus"],
        devices,
        MonotonicClock(),
        offset,
        _outlet(sock, stop),
        cfg.daemon.realtime_priority,
    )
    worker.stop = stop
    worker.on_reconfigured = _acknowledge(sock)
    for index, (next_seq, last_t_ns, period) in spec.get("resume", {}).items():
        measured = float(period) if period else None
        worker.runners[int(index)].resume(int(next_seq), int(last_t_ns) - offset, measured)
    for index in spec.get("raw", []):
        worker.runners[int(index)].want_raw(True)
    return worker


def serve(sock: socket.socket, worker: BusWorker) -> None:
    """Run the worker until it is stopped (the daemon closed its end, or asked so)."""
    threading.Thread(target=_report, args=(sock, worker), name="status", daemon=True).start()
    threading.Thread(target=_listen, args=(sock, worker), name="control", daemon=True).start()
    try:
        worker.run()
    finally:
        worker.stop.set()


def child_main(sock: socket.socket, spec: dict[str, Any]) -> None:
    """A bus process: run one bus worker until SIGTERM or the daemon's end of the socket
    closes."""
    setup_logging(spec.get("log_level", "info"))
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the daemon, which stops us
    with contextlib.suppress(OSError):
        sock.setsockopt(socket.SOL_SOCKET, 32, SNDBUF)  # SO_SNDBUFFORCE (root): room for bursts
    worker = build(sock, spec)
    signal.signal(signal.SIGTERM, lambda *_: worker.stop.set())
    gc.collect()
    gc.freeze()  # see Daemon.run: no long collections on the acquisition path
    # the worker runs at real-time priority, but another thread holding the GIL (the status
    # report, 5 a second) keeps it waiting until the interpreter's switch interval is up: a
    # chip without a FIFO at 2 kHz has about 0.45 ms to be read in, so the interval is far
    # below that (0.5 ms here lost twice the samples of 0.1 ms: docs/performance.md)
    sys.setswitchinterval(0.0001)
    serve(sock, worker)
