"""Each bus runs in its own process: the daemon relays it, survives it crashing again and again,
restarts it with capped backoff and shows that in status; the other bus and the watchdog never
notice. `bus_processes = false` keeps the single-process mode working."""

from __future__ import annotations

import itertools
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from imud.wire import decode
from tests.daemon_fixture import DaemonProc

TWO_BUSES = """
[[device]]
name = "a"
chip = "mpu6050"
bus = { kind = "sim", bus = "simA", address = 0x68 }
odr_hz = 500
[[device]]
name = "b"
chip = "mpu6050"
bus = { kind = "sim", bus = "simB", address = 0x68 }
odr_hz = 500
"""


def _children(pid: int) -> list[int]:
    out = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                fields = (p / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(p.name))
    return out


def _descendants(pid: int) -> set[int]:
    out: set[int] = set()
    todo = [pid]
    while todo:
        kids = _children(todo.pop())
        out.update(kids)
        todo += kids
    return out


def _bus_children(d: DaemonProc) -> dict[str, int]:
    """{bus key: pid} of the daemon's bus processes, from what the daemon says and /proc: each
    is a process of the daemon's tree (forked by its fork server, a child of the daemon)."""
    tree = _descendants(d.proc.pid)
    return {b["bus"]: b["pid"] for b in d.status()["buses"] if b["pid"] in tree}


def _wait(d: DaemonProc, cond: object, timeout: float = 60.0) -> dict[str, dict[str, object]]:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        st = {x["name"]: x for x in d.status()["devices"]}
        if cond(st):  # type: ignore[operator]
            return st
        time.sleep(0.1)
    raise AssertionError(f"timed out: {st}\n{d.log.read_text()}")


@pytest.mark.slow  # a crash loop of three kills, with restarts backed off, in real time
def test_a_bus_process_killed_repeatedly_is_restarted_and_nothing_else_notices(
    tmp_path: Path,
) -> None:
    d = DaemonProc(tmp_path, TWO_BUSES)
    raw: dict[str, list[bytes]] = {}
    try:
        d.wait_started()
        kids = _bus_children(d)
        assert set(kids) == {"sim:simA", "sim:simB"}
        # a subscriber per device for the whole crash loop
        threads = [
            threading.Thread(target=lambda n=n: raw.__setitem__(n, d.collect(f"imud/{n}/imu", 9.0)))
            for n in ("a", "b")
        ]
        for t in threads:
            t.start()
        time.sleep(1.0)
        d.drain_notify()
        d.messages.clear()
        for i in range(3):  # a bus process that keeps dying (a bug, the OOM killer)
            pid = _bus_children(d)["sim:simA"]
            os.kill(pid, signal.SIGKILL)
            st = _wait(d, lambda s, i=i: s["a"]["restarts"] == i + 1)
            assert "exited with code -9" in str(st["a"]["last_error"])
            _wait(d, lambda s: s["a"]["state"] == "running")
        pets = [m for m in d.drain_notify() if m == "WATCHDOG=1"]
        for t in threads:
            t.join()
        # status counts over all the process's lives: at least what the subscriber got across
        # them, once its snapshot has caught up with the batches already delivered
        got_a = sum(decode(x).count for x in raw["a"])
        st = _wait(d, lambda s: s["a"]["samples"] >= got_a, timeout=20.0)
        buses = {b["bus"]: b for b in d.status()["buses"]}
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    # the daemon kept petting the watchdog through the crash loop (every 0.5 s with 1 s)
    assert len(pets) >= 4, d.log.read_text()
    assert buses["sim:simA"]["restarts"] == 3 and buses["sim:simB"]["restarts"] == 0
    assert st["b"]["restarts"] == 0 and st["b"]["state"] == "running"
    assert "restarting it" in d.log.read_text()
    for name in ("a", "b"):
        batches = [decode(x) for x in raw[name]]
        assert batches, name
        # seq never goes back, across restarts too; every gap is counted in the batch after it
        for prev, b in itertools.pairwise(batches):
            assert b.first_seq >= prev.first_seq + prev.count, name
            assert b.first_seq - (prev.first_seq + prev.count) == b.lost_before, name
    gaps_a = sum(b.lost_before for b in (decode(x) for x in raw["a"]))
    assert gaps_a > 0  # the outages cost samples, and they are on the wire ...
    assert st["a"]["lost_samples"] >= gaps_a  # ... and in status, which adds up over lives
    assert st["a"]["samples"] >= got_a
    assert not any(Path(f"/proc/{k}").exists() for k in kids.values())  # none orphaned


def _thread_names(pid: int) -> set[str]:
    return {
        (t / "comm").read_text().strip().rstrip("0123456789")
        for t in Path(f"/proc/{pid}/task").iterdir()
    }


def test_bus_process_runs_no_network_thread(tmp_path: Path) -> None:
    """What a running bus process runs: the bus worker and its reporting threads; none of the
    threads Zenoh's runtime runs in the daemon (its library is mapped, forked with the
    daemon's imports, but never started there), nor the event loop's."""
    d = DaemonProc(tmp_path, TWO_BUSES)
    try:
        d.wait_started()
        pids = _bus_children(d)
        assert set(pids) == {"sim:simA", "sim:simB"}
        zenoh_threads = _thread_names(d.proc.pid) - {"python", "python3"}
        assert zenoh_threads  # the check sees the daemon's network threads ...
        for pid in pids.values():
            assert not _thread_names(pid) & zenoh_threads  # ... and a bus process has none
            assert len(list(Path(f"/proc/{pid}/task").iterdir())) <= 4  # worker, status, control
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()


def test_a_bus_process_reports_its_cpu_and_the_simulators_part(tmp_path: Path) -> None:
    """Each bus process reports its CPU time and the part its simulators spent (what imud's own
    cost leaves out). The simulators' part is within the process's; the process's is what /proc
    says it used by then; and both grow while it runs."""
    d = DaemonProc(tmp_path, TWO_BUSES)
    try:
        d.wait_started()
        time.sleep(1.5)  # past a status report or two
        first = {b["bus"]: b for b in d.status()["buses"]}
        ticks = {key: _cpu_s(b["pid"]) for key, b in first.items()}
        time.sleep(1.5)
        later = {b["bus"]: b for b in d.status()["buses"]}
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    assert set(first) == {"sim:simA", "sim:simB"}
    for key, b in first.items():
        assert 0.0 < b["sim_cpu_s"] <= b["cpu_s"], b
        # the report came before /proc was read, and /proc counts in 10 ms ticks
        assert b["cpu_s"] <= ticks[key] + 0.02, (b, ticks[key])
        assert later[key]["sim_cpu_s"] > b["sim_cpu_s"] and later[key]["cpu_s"] > b["cpu_s"]


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def test_single_process_mode_streams_too(tmp_path: Path) -> None:
    d = DaemonProc(tmp_path, "[daemon]\nbus_processes = false\n" + TWO_BUSES)
    try:
        d.wait_started()
        assert not _children(d.proc.pid)
        time.sleep(1.0)
        st = d.status()["devices"]
        assert all(x["state"] == "running" and x["samples"] > 200 for x in st), st
    finally:
        code, _ = d.stop()
    assert code == 0


FAST_CHIP = """
[[device]]
name = "fast"
chip = "mpu6050"
bus = { kind = "sim", bus = "simA", address = 0x68 }
odr_hz = 1000
[device.sim]
seed = 4
clock_error = 0.02
"""


@pytest.mark.slow  # a thousand samples measured, a kill, the restart's gap measured again
def test_a_restarted_bus_process_counts_the_gap_at_the_chips_measured_period(
    tmp_path: Path,
) -> None:
    """A chip 2 % fast: the samples it latched while its bus process was dead are the gap's
    duration over its real period, 1e9 / 1020 ns; the new process knows that period from the
    stream relayed before (at the nominal one, a 1.5 s outage would be miscounted by 30)."""
    d = DaemonProc(tmp_path, FAST_CHIP)
    raw: list[bytes] = []
    try:
        d.wait_started()
        done = threading.Event()  # the collection ends once the restarted stream flows
        t = threading.Thread(
            target=lambda: raw.extend(d.collect("imud/fast/imu", 120.0, until=done))
        )
        t.start()
        time.sleep(3.0)  # > 1000 samples relayed: the period is measured
        os.kill(_bus_children(d)["sim:simA"], signal.SIGKILL)
        st = _wait(d, lambda s: s["fast"]["restarts"] == 1 and s["fast"]["state"] == "running")
        n = int(st["fast"]["samples"])  # type: ignore[call-overload]
        _wait(d, lambda s: s["fast"]["samples"] > n + 300)  # published after the restart
        time.sleep(0.5)  # ... and on the wire to the subscriber
        done.set()
        t.join()
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    batches = [decode(x) for x in raw]
    gaps = [(a, b) for a, b in itertools.pairwise(batches) if b.lost_before > 100]
    assert len(gaps) == 1, [b.lost_before for b in batches if b.lost_before]
    a, b = gaps[0]
    true_period = 1e9 / 1020.0
    slots = (int(b.t_ns[0]) - int(a.t_ns[-1])) / true_period - 1
    # stamps at either edge may be off by a sample or two; a nominal-period count is off by 2 %
    assert abs(b.lost_before - slots) <= 3 + 0.003 * slots, (b.lost_before, slots)


def test_signalling_the_whole_process_group_is_a_clean_stop(tmp_path: Path) -> None:
    """systemd's default KillMode (control-group), `timeout` and `kill -- -PGID` send SIGTERM to
    the daemon and every bus process at once, and on a busy machine the bus processes may end
    before the daemon has even handled it (here: they get it 0.3 s before the daemon does). That
    is the stop arriving, not a crash: nothing is restarted or logged as an error, and the
    daemon exits 0 with every child gone."""
    d = DaemonProc(tmp_path, TWO_BUSES, session=True)
    try:
        d.wait_started()
        kids = _bus_children(d)
        assert len(kids) == 2
        for pid in kids.values():
            os.kill(pid, signal.SIGTERM)
        time.sleep(0.3)
        os.killpg(d.proc.pid, signal.SIGTERM)
        code = d.proc.wait(timeout=15)
    finally:
        d.stop()
    log = d.log.read_text()
    assert code == 0, log
    assert "restarting it" not in log and " ERROR " not in log, log
    for pid in kids.values():
        assert not Path(f"/proc/{pid}").exists() or "Z" in _state(pid), pid


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"
