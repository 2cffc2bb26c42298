"""Serial link damage (`[device.sim.serial]`: corrupted, dropped and inserted bytes) through the
real daemon, in this process (`bus_processes = false`, so the simulators are reachable), to a
real Zenoh subscriber over loopback.

STIM300: every datagram carries a CRC and a sample counter, so exactly the datagrams the link
damaged are lost: the daemon's `lost_samples` equals the seq numbers the subscriber never got,
and equals the simulator's own count of datagrams it damaged. BNO055 over its UART: its answers
carry no checksum (a flipped data bit is undetectable), and a damaged answer is retried within
the sample period, so damage costs no fixed number of samples; what holds is the accounting (every
seq gap counted) and that a dropped byte or a garbage burst is noticed by the UART layer.

Found here: a STIM300 read that came late (a busy machine) overcounted the gap after a damaged
datagram (the batch after the gap was not the newest of its read, and was placed by that read's
bracket, off by the backlog); the last test pins the fix at virtual time.

The damage runs in a window with a clean link on both sides, so that the counts at its edges are
settled: the config's rates are switched off once the devices run, then on for a few seconds,
then off again. A window in which the pty itself overran (its reader late by more than the
kernel's buffer, a scheduler matter) can lose more than the damage: then the STIM300 check is
the bound that each extra lost datagram took at least one overrun byte."""

from __future__ import annotations

import itertools
import time
from pathlib import Path
from typing import Any

import pytest

import imud.client as ic
import imud.sim.pty
from imud.config import load_config
from imud.daemon import Daemon
from imud.sim.settings import SerialFaults
from tests.helpers import free_port, in_process_runners, run_in_process
from tests.streams import Stream, mark
from tests.test_stim300_sim import rig as stim_rig

CONFIG = """
[daemon]
bus_processes = false

[zenoh]
listen = ["{endpoint}"]

[[device]]
name = "stim"
chip = "stim300"
bus = {{ kind = "sim", bus = "rs422", transport = "serial", baud = 1843200 }}
datagram = "rate_acc_incl_temp"
odr_hz = 500                    # not 2000: this process also runs the pty pumps, on 2 cores
[device.sim]
seed = 21
serial = {{ corrupt_rate = 2e-4, drop_rate = 1e-4, garbage_rate = 5e-3, garbage_bytes = 23 }}

[[device]]
name = "bno"
chip = "bno055"
bus = {{ kind = "sim", bus = "uart0", transport = "serial", baud = 115200 }}
offsets_file = "{offsets}"
[device.sim]
seed = 22
serial = {{ corrupt_rate = 2e-4, drop_rate = 1e-3, garbage_rate = 3e-2 }}
"""
DAMAGE_S = 3.0


@pytest.mark.slow  # clean, damaged and clean windows of real serial traffic
def test_serial_damage_through_the_daemon(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    links: list[imud.sim.pty.PtyLink] = []
    init = imud.sim.pty.PtyLink.__init__

    def record(self: imud.sim.pty.PtyLink, *a: Any, **kw: Any) -> None:
        init(self, *a, **kw)
        links.append(self)

    monkeypatch.setattr(imud.sim.pty.PtyLink, "__init__", record)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    path = tmp_path / "c.toml"
    path.write_text(CONFIG.format(endpoint=endpoint, offsets=tmp_path / "bno.offsets.toml"))
    daemon = Daemon(load_config(path))
    got: dict[str, Any] = {}

    def drive() -> None:
        try:
            deadline = time.monotonic() + 30.0  # a bound for a broken daemon
            while daemon.session is None and time.monotonic() < deadline:
                time.sleep(0.05)  # its Zenoh listener is not up yet
            with ic.open_session(endpoint) as s:
                streams = {n: Stream(s, n) for n in ("stim", "bno")}
                while time.monotonic() < deadline and not (
                    len(in_process_runners(daemon)) == 2
                    and all(r.state == "running" for r in in_process_runners(daemon))
                    and all(st.batches for st in streams.values())
                ):
                    time.sleep(0.1)
                    for st in streams.values():
                        st.drain()
                time.sleep(1.0)  # past the STIM300's 0.7 s start-up
                runners: dict[str, Any] = {r.cfg.name: r for r in in_process_runners(daemon)}
                stim, bno = runners["stim"].sim, runners["bno"].sim.dies[0]
                rates = stim.faults, bno.faults
                stim.faults = bno.faults = SerialFaults()  # clean: settle the counts
                _settle(runners["stim"])
                got["before"] = _snapshot(daemon, stim, bno, links)
                stim.faults, bno.faults = rates  # the config's damage
                time.sleep(DAMAGE_S)
                stim.faults = bno.faults = SerialFaults()
                _settle(runners["stim"])
                got["after"] = _snapshot(daemon, stim, bno, links)
                time.sleep(0.3)  # the batches after the last mark
                for st in streams.values():
                    st.drain()
                got["streams"] = streams
        finally:
            daemon.request_stop()

    run_in_process(daemon, drive)
    assert "after" in got, "the devices never ran"
    b0, b1 = got["before"], got["after"]
    streams: dict[str, Stream] = got["streams"]
    for name in ("stim", "bno"):
        st = streams[name]
        assert b1[name]["state"] == "running"
        # the wire passed both marks
        assert st.end() >= mark(b1[name]) > mark(b0[name]), (name, st.end(), b0[name], b1[name])
        lost = b1[name]["lost_samples"] - b0[name]["lost_samples"]
        # every seq the subscriber never got is a sample the daemon counted as lost ...
        missing = st.missing(mark(b0[name]), mark(b1[name]))
        assert missing == lost, (name, missing, lost)
        # ... announced in the batch right after the gap
        for (f0, n0, _), (f1, _, gap) in itertools.pairwise(st.batches):
            assert f1 - (f0 + n0) == gap >= 0, name

    damaged = b1["stim_damaged"] - b0["stim_damaged"]
    lost = b1["stim"]["lost_samples"] - b0["stim"]["lost_samples"]
    # the window had damage
    assert damaged > 10 and b1["stim_garbage"] > b0["stim_garbage"], (damaged, b0, b1)
    crc = b1["stim"]["chip_counters"]["crc_errors"] - b0["stim"]["chip_counters"]["crc_errors"]
    # each CRC failure is a damaged datagram, or a garbage burst that began with the datagram's
    # identifier where a datagram was due (on the wire the two look alike: ~1 in 256 bursts)
    like = b1["stim_garbage_like"] - b0["stim_garbage_like"]
    assert 0 < crc <= damaged + like, (crc, damaged, like)
    noticed = b1["bno_noticed"] - b0["bno_noticed"]
    assert b1["bno_damage"] > b0["bno_damage"]  # bytes dropped or garbage sent in the window
    assert noticed > 0, b1["bno"]["chip_status"]  # ... which the UART layer caught and retried

    # exactly the damaged datagrams are lost, nothing else (each extra one took an overrun byte)
    overrun = b1["stim_overrun"] - b0["stim_overrun"]
    assert damaged <= lost <= damaged + overrun, (lost, damaged, overrun)
    if overrun == 0:
        assert lost == damaged


@pytest.mark.parametrize("late_ms", [80, 300])
def test_late_read_after_a_damaged_datagram_counts_only_the_damage(late_ms: int) -> None:
    """At virtual time: the link damages datagrams while every 40th poll comes `late_ms` late (a
    busy machine; the unit's bytes wait in the UART meanwhile, none is lost). Every datagram
    carries its 8-bit counter (128 ms of samples per wrap at 2000/s), so a gap is countable
    exactly, even behind a backlog of more than two wraps, and
    lost_samples must equal the damaged datagrams, as it does with punctual polls
    (tests/test_stim300_sim.py). A batch after a gap that is not the newest of its read is placed
    only by an upper bound (its read's, less a period for each datagram after it); the counter
    gives the count where one count alone fits below it."""
    faults = {"corrupt_rate": 2e-4, "drop_rate": 1e-4, "garbage_rate": 5e-3, "garbage_bytes": 23}
    _, clock, sim, _, runner, _, _ = stim_rig({"seed": 21, "serial": faults})
    polls = 0
    end = clock.now_ns() + 2_000_000_000
    while clock.now_ns() < end:
        runner.step()
        polls += 1
        late = late_ms * 1_000_000 if polls % 40 == 0 else 0
        clock.advance(max(1, runner.next_due_ns - clock.now_ns()) + late)
    sim.faults = SerialFaults()  # a clean tail: every damaged datagram followed by a good one
    end = clock.now_ns() + 200_000_000
    while clock.now_ns() < end:
        runner.step()
        clock.advance(max(1, runner.next_due_ns - clock.now_ns()))
    assert sim.damaged > 10
    assert runner.status().lost_samples == sim.damaged


def _settle(runner: Any) -> None:
    """Until the STIM300's driver has taken in every datagram sent before the link turned clean
    (a loaded machine leaves them in the pty for a while), and read a clean one after them: then
    each damaged datagram's loss has been counted, and no loss is being counted."""
    time.sleep(0.05)  # the simulator's 10 ms lookahead out; 25 clean datagrams sent
    deadline = time.monotonic() + 20.0  # a bound for a stuck driver
    while runner.driver.port.in_waiting > 2 * 59 and time.monotonic() < deadline:
        time.sleep(0.01)
    published = runner.samples
    while runner.samples == published and time.monotonic() < deadline:
        time.sleep(0.01)  # a read that ended after the pty was drained


def _snapshot(
    daemon: Daemon, stim: Any, bno: Any, links: list[imud.sim.pty.PtyLink]
) -> dict[str, Any]:
    # from the runners themselves: the daemon's status is their last report, up to 0.2 s old
    devs = {r.cfg.name: r.status().to_json() for r in in_process_runners(daemon)}
    uart = devs["bno"]["chip_status"]["uart"]
    return {
        **devs,
        "stim_damaged": stim.damaged,
        "stim_garbage": stim.garbage_bursts,
        "stim_garbage_like": stim.garbage_like_datagrams,
        "stim_overrun": sum(x.overrun_bytes for x in links if x.die is stim),
        "bno_damage": bno.dropped + bno.garbage_bursts,
        "bno_noticed": uart["retries"] + uart["timeouts"] + uart["bad_frames"],
    }
