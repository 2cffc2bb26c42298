"""Where one bus worker's own CPU goes, stage by stage, paced in real time as the daemon runs it.

The worker of one bus of a config is built as a bus process builds it (`build_worker`, batches
sent on a socket whose other end a thread drains) and run in this process's main thread on the
monotonic clock for `--seconds`. Each stage (the runner's step, the driver's read, the
pipeline, the sample clock, the emitter, the wire encode) is wrapped to add up the thread CPU
time spent inside it, less what the simulators spent inside it (`imud.sim.cpu`): imud's own
cost, per call and per sample. Wrapping costs about 1 us a call, so the totals are a little
above an unwrapped run's (bench/config_cpu.py measures those).

    .venv/bin/python bench/bus_stages.py --config configs/sim.toml --bus sim:spi0
    PYTHONPATH=/tmp/before .venv/bin/python bench/bus_stages.py --config configs/sim.toml \\
        --bus sim:spi0     # another tree, side by side
    .venv/bin/python bench/bus_stages.py --config configs/sim.toml --bus sim:sim0 \\
        --wrap imud.orient.stage:OrientationStage.run     # more stages
"""

from __future__ import annotations

import argparse
import functools
import importlib
import socket
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import imud.sim.cpu as simcpu
from imud import device, emit, pipeline, timestamps
from imud.buschild import _outlet
from imud.busworker import BusWorker, build_worker
from imud.chips.api import DeviceBase
from imud.clock import MonotonicClock
from imud.config import load_config

Totals = dict[str, list[int]]  # stage -> [own ns, calls]


def _own(totals: Totals, label: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    """`fn`, adding its own CPU time (simulators' excluded) to `totals[label]`."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t0, s0 = time.thread_time_ns(), simcpu.total_ns()
        try:
            return fn(*args, **kwargs)
        finally:
            row = totals.setdefault(label, [0, 0])
            row[0] += time.thread_time_ns() - t0 - (simcpu.total_ns() - s0)
            row[1] += 1

    return wrapper


def paced_worker(
    key: str, devices: list[DeviceBase], realtime_priority: int | None
) -> tuple[BusWorker, threading.Event]:
    """The worker of bus `key` as a bus process builds it, on the monotonic clock, its batches
    sent on a socket whose other end a thread drains; run it with `worker.run()` until the
    event is set."""
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)

    def drain() -> None:
        while theirs.recv(1 << 20):
            pass

    threading.Thread(target=drain, daemon=True).start()
    stop = threading.Event()
    worker = build_worker(key, devices, MonotonicClock(), 0, _outlet(ours, stop), realtime_priority)
    worker.stop = stop
    return worker, stop


def _wrap_method(totals: Totals, cls: type, name: str, label: str) -> None:
    setattr(cls, name, _own(totals, label, getattr(cls, name)))


def _wrap_named(totals: Totals, spec: str) -> None:
    """Time `module:function` or `module:Class.method` as a stage of its own."""
    module_name, _, attr = spec.partition(":")
    module = importlib.import_module(module_name)
    owner: Any = module
    *path, name = attr.split(".")
    for part in path:
        owner = getattr(owner, part)
    setattr(owner, name, _own(totals, spec, getattr(owner, name)))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", type=Path, required=True)
    p.add_argument("--bus", required=True, help="the bus key, as `imud status` names it")
    p.add_argument("--seconds", type=float, default=15.0)
    p.add_argument(
        "--wrap",
        nargs="*",
        default=[],
        metavar="MODULE:NAME",
        help="more stages to time: a function (imud.pipeline:to_si) or a method "
        "(imud.orient.stage:OrientationStage.run)",
    )
    args = p.parse_args()
    cfg = load_config(args.config)
    devices = [d for d in cfg.device if d.bus.key == args.bus]
    if not devices:
        keys = sorted({d.bus.key for d in cfg.device})
        print(f"no device on bus {args.bus!r}; the config's buses: {', '.join(keys)}")
        return 2
    worker, stop = paced_worker(args.bus, devices, cfg.daemon.realtime_priority)
    totals: Totals = {}
    _wrap_method(totals, BusWorker, "run_once", "worker: one scheduling decision")
    _wrap_method(totals, device.DeviceRunner, "step", "runner: one step")
    _wrap_method(totals, pipeline.Pipeline, "run", "pipeline (sample clock included)")
    _wrap_method(totals, timestamps.SampleClock, "update", "sample clock")
    _wrap_method(totals, emit.Emitter, "emit", "emitter (encode and send included)")
    emit.encode = _own(totals, "wire encode", emit.encode)
    for spec in args.wrap:
        _wrap_named(totals, spec)
    wrapped: set[type] = set()
    attach = device.DeviceRunner.attach

    def attach_and_wrap(self: device.DeviceRunner, driver: Any, sim: Any = None) -> None:
        cls = type(driver)
        if cls not in wrapped:
            wrapped.add(cls)
            _wrap_method(totals, cls, "read", f"driver: {cls.__name__}.read")
        attach(self, driver, sim)

    device.DeviceRunner.attach = attach_and_wrap  # type: ignore[method-assign]
    threading.Timer(args.seconds, stop.set).start()
    t0, s0 = time.thread_time_ns(), simcpu.total_ns()
    worker.run()
    cpu, sim = time.thread_time_ns() - t0, simcpu.total_ns() - s0
    n = max(1, sum(r.samples for r in worker.runners))
    print(" ".join(sys.argv))
    print(
        f"{args.bus}: {n} samples in {args.seconds:g} s; worker thread CPU {cpu / 1e6:.0f} ms, "
        f"simulators {sim / 1e6:.0f} ms, imud's own {(cpu - sim) / 1e6:.0f} ms = "
        f"{(cpu - sim) / n / 1e3:.2f} us a sample"
    )
    head = ("stage (own CPU)", "ms", "calls", "us a call", "us a sample")
    print("  {:40s} {:>8s} {:>8s} {:>10s} {:>12s}".format(*head))
    for label, (ns, calls) in sorted(totals.items(), key=lambda kv: -kv[1][0]):
        print(
            f"  {label:40s} {ns / 1e6:8.1f} {calls:8d} {ns / max(calls, 1) / 1e3:10.1f} "
            f"{ns / n / 1e3:12.2f}"
        )
    for r in worker.runners:
        print(f"  {r.cfg.name}: lost {r.lost_samples}, published {r.samples}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
