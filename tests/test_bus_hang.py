"""A bus worker that hangs inside a bus call (alive, not crashed) is detected, reported and
restarted, while a device on another bus streams on without a gap and the daemon keeps petting
systemd's watchdog.

The hang is the simulator's stall fault: now and then a transfer blocks the bus call for 10 s, as
a stuck controller does. With `[daemon] hung_after_s = 2` the daemon kills that bus process once
its worker has made no progress for 2 s and starts a new one, whose simulator replays the same
seeded schedule (so it hangs again after as many transfers: the test sees several cycles). Thread
mode's counterpart (a hung worker stops the petting, since it cannot be restarted) is
tests/test_watchdog.py.

Nothing here asserts a duration: the loop below only waits (with a generous bound) for things to
happen, and checks what happened."""

from __future__ import annotations

import itertools
import time
from pathlib import Path
from typing import Any

import pytest

import imud.client as ic
from imud.config import parse_config
from tests.daemon_fixture import DaemonProc
from tests.streams import Stream, mark

pytestmark = pytest.mark.slow  # a hung worker waited out, in real time

HUNG_AFTER_S = 2.0
CONFIG = f"""
[daemon]
hung_after_s = {HUNG_AFTER_S}

[[device]]
name = "stuck"                  # its controller now and then blocks a call for 10 s
chip = "mpu6050"
bus = {{ kind = "sim", bus = "simA", address = 0x68 }}
odr_hz = 200
[device.sim]
seed = 11                       # its first stall is the 285th transfer: ~2 s into streaming
faults = {{ stall_rate = 2e-3, stall_ms = 10000.0 }}

[[device]]
name = "steady"                 # another bus: never affected
chip = "mpu6050"
bus = {{ kind = "sim", bus = "simB", address = 0x68 }}
odr_hz = 50                     # its 1 kB FIFO holds 1.7 s: no scheduler delay overflows it
"""


def _restarted_and_passed(marks: list[tuple[int, dict[str, dict[str, Any]]]], end: int) -> bool:
    """A snapshot taken after a restart that followed the first snapshot, of the device
    streaming again with the hang's gap counted, which the wire has passed: enough to judge."""
    lost0 = marks[0][1]["stuck"]["lost_samples"]
    return any(
        r > marks[0][0]
        and m["stuck"]["state"] == "running"
        and m["stuck"]["lost_samples"] > lost0
        and mark(m["stuck"]) < end
        for r, m in marks
    )


def test_hung_after_s_is_validated() -> None:
    dev = {"name": "a", "chip": "mpu6050", "bus": {"kind": "sim"}}
    assert parse_config({"device": [dev]}).daemon.hung_after_s == 10.0
    with pytest.raises(ValueError, match="hung_after_s"):
        parse_config({"daemon": {"hung_after_s": 0.5}, "device": [dev]})


def test_a_hung_bus_worker_is_restarted_and_nothing_else_notices(tmp_path: Path) -> None:
    d = DaemonProc(tmp_path, CONFIG)
    pets: list[int] = []  # per WATCHDOG=1: how many restarts of the hung bus status showed then
    seen_error: list[str] = []  # the hung device's last_error while it was down
    marks: list[tuple[int, dict[str, dict[str, Any]]]] = []  # (bus restarts, devices' status)
    try:
        restarts = notes = 0
        with d.answering_session() as s:
            stuck, steady = Stream(s, "stuck"), Stream(s, "steady")
            deadline = time.monotonic() + 90.0  # a bound for a broken daemon, not a measurement
            while time.monotonic() < deadline:
                st = ic.get_status(s, timeout=5.0)
                devs = {x["name"]: x for x in st["devices"]}
                restarts = next(b["restarts"] for b in st["buses"] if b["bus"] == "sim:simA")
                if devs["stuck"]["state"] == "error":
                    seen_error.append(str(devs["stuck"]["last_error"]))
                stuck.drain()
                steady.drain()
                msgs = d.drain_notify()
                pets += [restarts for m in msgs[notes:] if m == "WATCHDOG=1"]
                notes = len(msgs)
                if stuck.batches and steady.batches:
                    marks.append((restarts, devs))
                done = marks and seen_error and _restarted_and_passed(marks, stuck.end())
                if done and pets and pets[-1] > marks[0][0]:  # and a pet since that restart
                    break
                time.sleep(0.1)
            stuck.drain()
            steady.drain()
            st = ic.get_status(s, timeout=5.0)
    finally:
        d.stop()
    log = d.log.read_text()
    assert marks, log
    bus_a = next(b for b in st["buses"] if b["bus"] == "sim:simA")
    bus_b = next(b for b in st["buses"] if b["bus"] == "sim:simB")
    devs = {x["name"]: x for x in st["devices"]}

    # detected and reported: the bus says why, and its device said so while it was down
    assert bus_a["restarts"] >= 1, log
    assert "made no progress" in bus_a["last_error"], bus_a
    assert seen_error and all("made no progress" in e for e in seen_error), seen_error
    assert "made no progress" in log
    assert devs["stuck"]["restarts"] >= 1
    # ... restarted: the device streams again, its seq going on, each gap announced in the
    # batch after it, and every seq the wire skipped counted in lost_samples, exactly (from the
    # first snapshot to the last one the wire has passed)
    for (f0, n0, _), (f1, _, lost) in itertools.pairwise(stuck.batches):
        assert f1 - (f0 + n0) == lost >= 0
    r0, first = marks[0]
    r1, last = [(r, m) for r, m in marks if mark(m["stuck"]) <= stuck.end()][-1]
    assert r1 > r0  # a restart between the two snapshots
    gaps = stuck.missing(mark(first["stuck"]), mark(last["stuck"]))
    assert gaps > 0  # the hang cost samples
    assert gaps == last["stuck"]["lost_samples"] - first["stuck"]["lost_samples"]
    # the other bus never noticed: no restart, no gap, nothing lost
    assert bus_b["restarts"] == 0 and bus_b["last_error"] is None
    for (f0, n0, _), (f1, _, _) in itertools.pairwise(steady.batches):
        assert f1 == f0 + n0
    assert devs["steady"]["lost_samples"] == 0 and devs["steady"]["state"] == "running"
    # and the daemon went on petting the watchdog, also once the hang had been dealt with
    assert "not serving" not in log
    assert pets[-1] > r0
