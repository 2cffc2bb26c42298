"""Shared test plumbing: a simulated MPU6050 on a simulated bus at virtual time."""

from __future__ import annotations

import socket
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from imud.channels import Channel
from imud.clock import VirtualClock
from imud.config import parse_config
from imud.device import DeviceRunner
from imud.sim.i2c import SimI2CBus
from imud.wire import Batch, decode
from imud.wiring import connect


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Rig:
    cfg: Any
    clock: VirtualClock
    bus: SimI2CBus
    sim: Any
    driver: Any
    runner: DeviceRunner
    out: list[bytes] = field(default_factory=list)
    truth: list[bytes] = field(default_factory=list)

    def run(self, seconds: float, jitter_ns: int = 0, seed: int = 0) -> None:
        """Let the runner schedule itself, at virtual time, for `seconds`."""
        rng = np.random.default_rng(seed)
        end = self.clock.now_ns() + int(seconds * 1e9)
        while self.clock.now_ns() < end:
            self.runner.step()
            wait = max(0, self.runner.next_due_ns - self.clock.now_ns())
            self.clock.advance(wait + (int(rng.integers(0, jitter_ns)) if jitter_ns else 0))

    def batches(self) -> list[Batch]:
        return [decode(b) for b in self.out]

    def truth_batches(self) -> list[Batch]:
        return [decode(b) for b in self.truth]


def make_rig(device: dict[str, Any], sim: dict[str, Any] | None = None) -> Rig:
    """Any chip on a simulated I2C bus, or on SPI with `"bus": {"kind": "sim", "transport":
    "spi"}`, wired as the daemon wires it and driven by its DeviceRunner at virtual time."""
    d = {"name": "t0", "chip": "mpu6050", "bus": {"kind": "sim"}, **device}
    d["sim"] = {"truth": True, **(sim or {})}
    cfg: Any = parse_config({"device": [d]}).device[0]
    clock = VirtualClock()
    bus = SimI2CBus()
    driver, chip = connect(cfg, bus, clock)
    rig = Rig(cfg, clock, bus, chip, driver, None, [], [])  # type: ignore[arg-type]
    rig.runner = DeviceRunner(
        cfg,
        driver,
        None,
        rig.out.append,
        0,
        sim=chip,
        publish_truth=rig.truth.append,
        now_ns=clock.now_ns,
    )
    return rig


def concat(batches: list[Batch]) -> dict[str, np.ndarray]:
    """Measured or truth batches joined: seq, t_ns, flags and the accel/gyro/temperature arrays
    (float64)."""

    def cat(ch: Channel) -> np.ndarray:
        return np.concatenate([b.channels[ch] for b in batches]).astype(np.float64)

    return {
        "seq": np.concatenate([b.seq for b in batches]),
        "t_ns": np.concatenate([b.t_ns for b in batches]),
        "flags": np.concatenate([b.sample_flags for b in batches]),
        "accel": cat(Channel.ACCEL),
        "gyro": cat(Channel.GYRO),
        "temp": cat(Channel.TEMPERATURE),
    }


def match_truth(meas: dict[str, np.ndarray], truth: dict[str, np.ndarray]) -> np.ndarray:
    """Index into truth of the true sample nearest in time to each measured sample."""
    tt = truth["t_ns"]
    i = np.clip(np.searchsorted(tt, meas["t_ns"]), 1, len(tt) - 1)
    return np.where(np.abs(tt[i] - meas["t_ns"]) < np.abs(tt[i - 1] - meas["t_ns"]), i, i - 1)


def run_in_process(daemon: Any, drive: Any) -> None:
    """Run `daemon` (an `imud.daemon.Daemon`) on this thread's event loop while `drive()` runs
    in another thread; `drive` must end with `daemon.request_stop()`. Restores what the daemon
    changes process-wide (the GIL switch interval, the frozen GC generation)."""
    import gc
    import sys
    import threading

    import anyio

    switch = sys.getswitchinterval()
    t = threading.Thread(target=drive)
    t.start()
    try:
        assert anyio.run(daemon.run) == 0
    finally:
        t.join()
        sys.setswitchinterval(switch)
        gc.unfreeze()


def in_process_runners(daemon: Any) -> list[Any]:
    """The device runners of a daemon whose bus workers run in-process (`bus_processes =
    false`), as they are now (a worker not yet started has none)."""
    out: list[Any] = []
    for link in daemon.links:
        worker = getattr(link.transport, "worker", None)
        out.extend(worker.runners if worker is not None else [])
    return out


def native_means(payloads: list[bytes], k: int) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """What a k-sample averaging output should send, from the native stream's batches: for each
    complete group of seq k*m .. k*m+k-1, keyed by its members' mean stamp (integer ns, floor),
    the group's mean gyro and mean accelerometer (float64)."""
    from imud.wire import decode

    batches = [decode(p) for p in payloads]
    seq = np.concatenate([b.seq for b in batches])
    stamps = np.concatenate([b.t_ns for b in batches])
    gyro = np.concatenate([b.gyro for b in batches]).astype(np.float64)
    accel = np.concatenate([b.accel for b in batches]).astype(np.float64)
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for g in np.unique(seq // k):
        sel = seq // k == g
        if sel.sum() == k:
            mean_t = int(stamps[sel].astype(object).sum() // k)
            out[mean_t] = (gyro[sel].mean(axis=0), accel[sel].mean(axis=0))
    return out


def status_after(d: Any, batches: list[Any], device: int = 0, timeout: float = 20.0) -> Any:
    """The device's status once its snapshot was taken after the last of `batches` was
    published (a bus process reports status periodically, so a snapshot taken just after the
    batches arrived can lag them): its samples and lost samples reach that batch's seq end."""
    import time

    end_seq = batches[-1].first_seq + batches[-1].count if batches else 0
    until = time.monotonic() + timeout  # a bound for a broken daemon
    while True:
        st = d.status()["devices"][device]
        if st["samples"] + st["lost_samples"] >= end_seq or time.monotonic() > until:
            return st
        time.sleep(0.05)
