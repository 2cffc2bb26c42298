"""A bus that will not open (i2c-dev not loaded yet, adapter unplugged) is retried with backoff;
once it opens, its devices start without a daemon restart."""

from __future__ import annotations

import errno
import itertools
from typing import Any

from imud.clock import VirtualClock
from imud.config import parse_config
from imud.busworker import BusWorker, connector
from imud.device import DeviceRunner
from imud.sim.i2c import SimI2CBus


def test_bus_reopened_with_backoff_then_devices_start() -> None:
    cfg = parse_config(
        {
            "device": [
                {
                    "name": "a",
                    "chip": "mpu6050",
                    "bus": {"kind": "sim"},
                    "sim": {"errors": {"ideal": True}},
                }
            ]
        }
    ).device[0]
    clock = VirtualClock()
    attempts: list[int] = []

    def opener() -> Any:
        attempts.append(clock.now_ns())
        if len(attempts) < 4:
            raise OSError(errno.ENOENT, "No such file or directory: '/dev/i2c-1'")
        return SimI2CBus()

    out: list[bytes] = []
    runner = DeviceRunner(cfg, None, None, out.append, 0, now_ns=clock.now_ns)
    w = BusWorker("sim:x", [runner], [_connector(cfg, clock)], opener, clock)
    for _ in range(2000):  # what run() does, at virtual time
        now = clock.now_ns()
        if w._ensure_bus(now):
            if runner.next_due_ns <= now:
                runner.step()
            clock.advance(max(1, runner.next_due_ns - clock.now_ns()))
        else:
            assert runner.state == "error" and "/dev/i2c-1" in (runner.last_error or "")
            clock.advance(w._reopen_ns - now)
    gaps = [b - a for a, b in itertools.pairwise(attempts)]
    assert gaps == sorted(gaps) and gaps[0] > 0  # backing off, not spinning
    assert runner.state == "running" and runner.samples > 0 and out
