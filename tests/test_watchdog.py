"""systemd's watchdog, through a fake NOTIFY_SOCKET, with the daemon in this process.

WATCHDOG=1 means the daemon itself is alive and serving. In thread mode a bus worker stuck
inside a driver call cannot be restarted, so the daemon stops petting and lets systemd restart
it; a bus process that crashes is restarted instead and the petting goes on
(tests/test_bus_process.py)."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import imud.busworker
import imud.reload
from imud.chips.api import DeviceBase, Driver, RawBatch
from imud.clock import Clock
from imud.config import load_config
from imud.daemon import Daemon
from imud.sim.api import SimChip
from imud.wiring import connect
from tests.helpers import free_port, run_in_process

pytestmark = pytest.mark.slow  # watchdog silences waited out, in real time


class Hanging:
    """A real driver whose read blocks once `hang` is set: a chip that holds the bus."""

    def __init__(self, inner: Driver, hang: threading.Event, release: threading.Event) -> None:
        self.inner, self.hang, self.release = inner, hang, release
        self.nominal_period_ns = inner.nominal_period_ns
        self.poll_interval_ns = inner.poll_interval_ns
        self.fifo_capacity = inner.fifo_capacity
        self.group_delay_ns = inner.group_delay_ns
        self.counters = inner.counters

    @property
    def next_poll_ns(self) -> int | None:
        return self.inner.next_poll_ns

    def start(self) -> Iterator[int]:
        return self.inner.start()

    def read(self) -> RawBatch:
        if self.hang.is_set():
            self.release.wait(30)
        return self.inner.read()

    def stop(self) -> None:
        self.inner.stop()

    def chip_status(self) -> dict[str, Any]:
        return {}


def test_a_hung_worker_stops_the_watchdog_in_thread_mode(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp_path / "notify"))
    notify.settimeout(0.05)
    monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "notify"))
    monkeypatch.setenv("WATCHDOG_USEC", "400000")  # petted every 0.2 s
    hang, release = threading.Event(), threading.Event()

    def hanging_connector(d: DeviceBase, clock: Clock) -> Any:
        def make(shared: Any) -> tuple[Driver, SimChip | None]:
            driver, sim = connect(d, shared, clock)
            return Hanging(driver, hang, release), sim

        return make

    monkeypatch.setattr(imud.busworker, "connector", hanging_connector)
    cfg_path = tmp_path / "c.toml"
    cfg_path.write_text(
        f'[daemon]\nbus_processes = false\n[zenoh]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n'
        '[[device]]\nname = "a"\nchip = "mpu6050"\nbus = { kind = "sim" }\n'
    )
    daemon = Daemon(load_config(cfg_path))
    daemon.stall_ns = 1_000_000_000
    log: list[tuple[float, str]] = []

    def listen(until: float) -> None:
        while time.monotonic() < until:
            with contextlib.suppress(TimeoutError):
                log.append((time.monotonic(), notify.recv(4096).decode()))

    marks: dict[str, float] = {}

    def drive() -> None:
        try:
            listen(time.monotonic() + 2.0)  # started and petting
            marks["hang"] = time.monotonic()
            hang.set()
            listen(time.monotonic() + 3.0)  # stall_ns (1 s) later the petting stops
            release.set()
            listen(time.monotonic() + 2.0)  # the worker moves again: petting resumes
        finally:
            release.set()
            daemon.request_stop()

    try:
        run_in_process(daemon, drive)
    finally:
        notify.close()
    h = marks["hang"]
    pets = [at for at, m in log if m == "WATCHDOG=1"]
    assert any("READY=1" in m for _, m in log)
    assert [p for p in pets if p < h], "petted while serving"
    # from a second after the stall threshold until the worker was released: no pet at all
    silent = [p for p in pets if h + 2.0 < p < h + 3.0]
    assert not silent, silent
    assert [p for p in pets if p > h + 3.5], "petting resumed once the worker moved again"


def test_a_frozen_event_loop_stops_the_watchdog(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """WATCHDOG=1 comes from the event loop itself, never from a thread of its own: a loop that
    blocks (here the config file's poll hangs for 2 s, as a stat on a dead network mount does)
    sends nothing for as long, five times the 0.4 s watchdog, so systemd would restart the
    daemon; once the loop moves again the petting resumes."""
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp_path / "notify"))
    notify.settimeout(0.05)
    monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "notify"))
    monkeypatch.setenv("WATCHDOG_USEC", "400000")  # petted every 0.2 s
    freeze = threading.Event()
    frozen: list[float] = []
    changed = imud.reload.ConfigFile.changed

    def hanging_changed(self: imud.reload.ConfigFile) -> bool:
        if freeze.is_set() and not frozen:
            frozen.append(time.monotonic())
            time.sleep(2.0)  # on the event loop's thread: nothing else of the loop runs
            frozen.append(time.monotonic())
        return changed(self)

    monkeypatch.setattr(imud.reload.ConfigFile, "changed", hanging_changed)
    cfg_path = tmp_path / "c.toml"
    cfg_path.write_text(
        f'[daemon]\nbus_processes = false\n[zenoh]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n'
        '[[device]]\nname = "a"\nchip = "mpu6050"\nbus = { kind = "sim" }\n'
    )
    daemon = Daemon(load_config(cfg_path), config_path=cfg_path)
    log: list[tuple[float, str]] = []

    def listen(until: float) -> None:
        while time.monotonic() < until:
            with contextlib.suppress(TimeoutError):
                log.append((time.monotonic(), notify.recv(4096).decode()))

    def drive() -> None:
        try:
            listen(time.monotonic() + 2.0)  # started and petting
            freeze.set()  # the next poll of the file (within a second) hangs
            listen(time.monotonic() + 4.0)
        finally:
            daemon.request_stop()

    try:
        run_in_process(daemon, drive)
    finally:
        notify.close()
    assert len(frozen) == 2, "the loop polled the config file"
    start, end = frozen
    pets = [at for at, m in log if m == "WATCHDOG=1"]
    assert [p for p in pets if p < start], "petted before the freeze"
    during = [p for p in pets if start + 0.05 < p < end - 0.05]
    assert not during, during
    before = max(p for p in pets if p <= start + 0.05)
    after = min(p for p in pets if p >= end - 0.05)
    assert after - before >= 2.0 > 0.4  # the watchdog's 0.4 s passed without a pet
    assert len([p for p in pets if p > end + 0.3]) >= 2, "petting resumed"
