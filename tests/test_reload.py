"""Config reload: the plan (pure), the file watch, and the real daemon reloading while a real
subscriber watches every device's stream.

What must hold through a reload (issue 10): unchanged devices keep streaming with no sequence
gap; changed ones restart with their new settings (their seq continues, the gap counted); added
and removed devices start and stop; an invalid file leaves the old config running with
`config_error` in status naming the field; SIGHUP and an edit of the file both reload; systemd
hears RELOADING=1 (with MONOTONIC_USEC) then READY=1.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

import imud.client as ic
from imud.config import parse_config
from imud.reload import Action, BusPlan, ConfigFile, plan_reload
from tests.daemon_fixture import DaemonProc

# three slow MPU6050s (a FIFO of 1024 bytes, 12 per sample: 85 samples = 1.7 s at 50 Hz, so a
# busy machine cannot overflow it during the test): a and b share one simulated I2C bus, c is
# alone on another
DEVICE = """[[device]]
name = "{name}"
chip = "mpu6050"
bus = {{ kind = "sim", bus = "{bus}", address = {address} }}
odr_hz = {odr}
dlpf_hz = 20
[device.sim]
seed = {seed}
"""
# name: (bus, address, odr, seed)
DEVICES = {
    "a": ("s0", "0x68", 50, 1),
    "b": ("s0", "0x69", 50, 2),
    "c": ("s1", "0x68", 50, 3),
    "d": ("s1", "0x69", 100, 4),
    "e": ("s2", "0x68", 50, 5),
}


def body(*names: str, b_odr: int = 50) -> str:
    def one(n: str) -> str:
        bus, address, odr, seed = DEVICES[n]
        odr = b_odr if n == "b" else odr
        return DEVICE.format(name=n, bus=bus, address=address, odr=odr, seed=seed)

    return "\n".join(one(n) for n in names)


def cfg(*names: str, b_odr: int = 50, zenoh_prefix: str = "imud", rt: int = 0) -> Any:
    import tomllib

    daemon = f"[daemon]\nrealtime_priority = {rt}\n" if rt else ""
    raw = tomllib.loads(f'{daemon}[zenoh]\nprefix = "{zenoh_prefix}"\n' + body(*names, b_odr=b_odr))
    return parse_config(raw)


# --- the plan -------------------------------------------------------------------------------------
def test_plan_same_config_is_empty() -> None:
    p = plan_reload(cfg("a", "b", "c"), cfg("a", "b", "c"))
    assert p.empty
    assert p.unchanged == ["a", "b", "c"]
    assert p.describe() == "unchanged: a, b, c"


def test_plan_changed_added_removed() -> None:
    p = plan_reload(cfg("a", "b", "c"), cfg("a", "b", "d", b_odr=100))
    assert p.changed == ["b"] and p.added == ["d"] and p.removed == ["c"]
    assert p.unchanged == ["a"]
    # bus s0 keeps a and restarts b; s1 loses c and gains d; nothing starts or stops whole
    s0, s1 = p.reconfigure["sim:s0"], p.reconfigure["sim:s1"]
    assert [(s.device.name, s.action, s.was) for s in s0.slots] == [
        ("a", Action.KEEP, 0),
        ("b", Action.RESTART, 1),
    ]
    assert not s0.removed
    assert [(s.device.name, s.action, s.was) for s in s1.slots] == [("d", Action.START, None)]
    assert s1.removed == [0]  # c
    assert not p.start and not p.stop


def test_a_bus_plan_survives_its_trip_to_the_worker() -> None:
    """The daemon sends the plan as JSON; the worker rebuilds it over the new config's devices
    on its bus and applies it by index: the same plan on both sides."""
    new = cfg("a", "b", "d", b_odr=100)
    p = plan_reload(cfg("a", "b", "c"), new).reconfigure["sim:s0"]
    back = BusPlan.from_json(json.loads(json.dumps(p.to_json())), [d for d in new.device][:2])
    assert back == p


def test_plan_buses_start_and_stop() -> None:
    p = plan_reload(cfg("a", "b", "c"), cfg("a", "b", "e"))
    assert list(p.start) == ["sim:s2"] and p.stop == ["sim:s1"]
    assert not p.reconfigure  # s0 is exactly as it was


def test_plan_zenoh_and_daemon_sections() -> None:
    p = plan_reload(cfg("a"), cfg("a", zenoh_prefix="robot"))
    assert p.zenoh_changed and not p.daemon_changed and not p.empty
    p = plan_reload(cfg("a"), cfg("a", rt=10))
    assert p.daemon_changed and "next restart" in p.describe()


def test_bus_keys_are_what_the_plan_uses() -> None:
    c = cfg("a", "c")
    assert [d.bus.key for d in c.device] == ["sim:s0", "sim:s1"]


# --- the file watch -------------------------------------------------------------------------------
def test_config_file_sees_content_changes_only(tmp_path: Path) -> None:
    f = tmp_path / "imud.toml"
    f.write_text("x = 1\n")
    w = ConfigFile(f)
    assert not w.changed()
    st = f.stat()
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 5_000_000_000))  # touch: same content
    assert not w.changed()
    f.write_text("x = 2\n")
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 10_000_000_000))
    assert w.changed()
    assert not w.changed()  # once per change
    tmp = tmp_path / "new.toml"  # an editor's save: a new file renamed over the old
    tmp.write_text("x = 3\n")
    tmp.replace(f)
    assert w.changed()
    f.unlink()
    assert w.changed()  # gone: the reload says so


# --- the daemon -----------------------------------------------------------------------------------
class Watcher:
    """A subscriber to every device's stream for the whole test, keeping raw payloads."""

    def __init__(self, endpoint: str) -> None:
        self.got: list[bytes] = []
        self._lock = threading.Lock()
        self.session = ic.open_session(endpoint)
        self.sub = self.session.declare_subscriber("imud/*/imu", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.got.append(sample.payload.to_bytes())

    def batches(self, device: str) -> list[ic.Batch]:
        with self._lock:
            raw = list(self.got)
        return [b for b in map(ic.decode, raw) if b.device == device]

    def close(self) -> None:
        self.sub.undeclare()  # type: ignore[no-untyped-call]
        self.session.close()  # type: ignore[no-untyped-call]


def wait_for(what: str, cond: Callable[[], Any], timeout: float = 30.0) -> Any:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        got = cond()
        if got:
            return got
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what}")


def edit(d: DaemonProc, text: str) -> None:
    """Write the config as an editor does: a whole new file renamed over the old one."""
    head = d.config.read_text().split("[[device]]", 1)[0]
    tmp = d.config.with_suffix(".new")
    tmp.write_text(head + text)
    tmp.replace(d.config)


def assert_unbroken(bs: list[ic.Batch], name: str) -> None:
    assert bs, f"{name}: no batches"
    seq = np.concatenate([b.seq for b in bs])
    assert np.all(np.diff(seq) == 1), f"{name}: sequence gap at {np.flatnonzero(np.diff(seq) != 1)}"
    assert all(b.lost_before == 0 for b in bs), name


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[DaemonProc]:
    d = DaemonProc(tmp_path, body("a", "b", "c"))
    d.wait_started()
    yield d
    d.stop()


def status(d: DaemonProc) -> dict[str, Any]:
    d.drain_notify()  # as we go: a datagram socket's queue holds only a few
    return d.status()


def device(st: dict[str, Any], name: str) -> dict[str, Any] | None:
    return next((x for x in st["devices"] if x["name"] == name), None)


def test_reload_applies_the_difference_with_no_gap_for_unchanged_devices(
    daemon: DaemonProc,
) -> None:
    d = daemon
    w = Watcher(d.endpoint)
    try:
        wait_for("a, b and c streaming", lambda: all(w.batches(n) for n in "abc"))
        # b's rate changes (same bus as a), c is removed, d joins c's old bus: an edit of the file
        edit(d, body("a", "b", "d", b_odr=100))
        st = wait_for("the reload", lambda: (s := status(d))["reloads"] == 1 and s)
        assert st["config_error"] is None
        assert [x["name"] for x in st["devices"]] == ["a", "b", "d"]
        assert device(st, "b")["odr_hz"] == 100.0  # type: ignore[index]
        wait_for("d streaming", lambda: len(w.batches("d")) >= 5)
        wait_for("b at its new rate", lambda: (x := device(status(d), "b")) and x["samples"] > 50)
        n_c = len(w.batches("c"))
        # an invalid edit: the old config keeps running, status names the field
        edit(d, body("a", "b", "d", b_odr=100).replace("odr_hz = 100\n", 'odr_hz = "fast"\n', 1))
        st = wait_for("config_error", lambda: (s := status(d))["config_error"] and s)
        assert "odr_hz" in st["config_error"] and "device[1]" in st["config_error"]
        assert st["reloads"] == 1
        assert [x["name"] for x in st["devices"]] == ["a", "b", "d"]
        r = d.cli("status", "--connect", d.endpoint)
        assert r.returncode == 0 and "odr_hz" in r.stdout, r.stdout  # the table shows it too
        # fixed by hand, then SIGHUP (`systemctl reload imud`): error cleared, nothing restarted
        edit(d, body("a", "b", "d", b_odr=100))
        d.proc.send_signal(signal.SIGHUP)
        st = wait_for("the error to clear", lambda: (s := status(d))["config_error"] is None and s)
        time.sleep(1.0)  # a few more batches after the last reload
        a_bs, b_bs = w.batches("a"), w.batches("b")
    finally:
        w.close()
    assert_unbroken(a_bs, "a")  # a shared its bus with a changed device and never noticed
    assert device(st, "a")["lost_samples"] == 0  # type: ignore[index]
    assert device(st, "a")["restarts"] == 0  # type: ignore[index]
    # b restarted: its seq went on from where it was; the gap it left is counted as lost
    seq = np.concatenate([b.seq for b in b_bs])
    assert np.all(np.diff(seq) > 0)
    lost_on_wire = int(np.sum(np.diff(seq) - 1))
    assert lost_on_wire == sum(b.lost_before for b in b_bs[1:]) == device(st, "b")["lost_samples"]  # type: ignore[index]
    assert len(w.batches("c")) == n_c  # removed: nothing since
    notes = "\n".join(d.drain_notify())
    assert notes.count("RELOADING=1") >= 3
    assert "MONOTONIC_USEC=" in notes
    log = d.log.read_text()
    assert "restarted with new settings: b" in log and "added: d" in log and "removed: c" in log


def test_zenoh_change_reopens_the_session(tmp_path: Path) -> None:
    d = DaemonProc(tmp_path, body("a"))
    try:
        d.wait_started()
        text = d.config.read_text().replace('prefix = "imud"', 'prefix = "robot"')
        d.config.write_text(text)
        d.proc.send_signal(signal.SIGHUP)

        def robot_status() -> dict[str, Any] | None:
            try:
                with ic.open_session(d.endpoint) as s:
                    return ic.get_status(s, "robot", timeout=1.0)
            except ic.NoDaemon:  # the session is being reopened, or still the old prefix
                return None

        got = wait_for("the new prefix", robot_status)
        assert got["reloads"] == 1
        with ic.open_session(d.endpoint) as s:
            bs = []
            for b in ic.batches(s, "a", prefix="robot", timeout=5.0):
                bs.append(b)
                if len(bs) >= 3:
                    break
        assert bs and bs[0].device == "a"
    finally:
        d.stop()


def test_reload_in_thread_mode(tmp_path: Path) -> None:
    """`bus_processes = false`: the same difference applied to worker threads in the daemon
    process, where the runners themselves can be looked at."""
    from imud.config import load_config
    from imud.daemon import Daemon
    from tests.helpers import free_port, in_process_runners, run_in_process

    path = tmp_path / "imud.toml"
    head = f'[daemon]\nbus_processes = false\n[zenoh]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n'
    path.write_text(head + body("a", "b", "c"))
    daemon = Daemon(load_config(path), config_path=path)
    seen: dict[str, Any] = {}

    def runner(name: str) -> Any:
        return next((r for r in in_process_runners(daemon) if r.cfg.name == name), None)

    def drive() -> None:
        try:
            wait_for(
                "a, b, c running",
                lambda: len(in_process_runners(daemon)) == 3 and runner("b").samples,
            )
            seen["a"], seen["b"] = runner("a"), runner("b")
            path.write_text(head + body("a", "b", "e", b_odr=100))  # c out, e on a new bus
            daemon.request_reload()
            wait_for("the reload", lambda: daemon.reloads == 1)
            wait_for("b restarted and e running", lambda: runner("e") and runner("e").samples)
            wait_for("b at 100 Hz", lambda: runner("b").samples > 20)
            seen["after"] = {r.cfg.name: r for r in in_process_runners(daemon)}
            seen["buses"] = sorted(w.key for w in daemon.links)
            seen["status"] = daemon.status()
        finally:
            daemon.request_stop()

    run_in_process(daemon, drive)
    after = seen["after"]
    assert sorted(after) == ["a", "b", "e"]
    assert after["a"] is seen["a"]  # the very same runner: never stopped
    assert after["b"] is not seen["b"] and after["b"].cfg.odr_hz == 100
    assert seen["b"].state == "stopped"
    assert seen["buses"] == ["sim:s0", "sim:s2"]  # s1 had only c: its worker stopped
    assert seen["status"]["config_error"] is None and seen["status"]["reloads"] == 1
