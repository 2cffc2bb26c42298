"""Each bus runs in its own process: the daemon relays it, survives its crash and restarts it;
`bus_processes = false` keeps the single-process mode working."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

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


def _bus_of(pid: int) -> str:
    return (Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")).decode()


def test_one_process_per_bus_and_a_crashed_one_is_restarted(tmp_path: Path) -> None:
    d = DaemonProc(tmp_path, TWO_BUSES)
    try:
        d.wait_started()
        kids = [k for k in _children(d.proc.pid) if "imud.busproc" in _bus_of(k)]
        assert len(kids) == 2, [_bus_of(k) for k in kids]
        time.sleep(1.0)
        before = {x["name"]: x for x in d.status()["devices"]}
        os.kill(kids[0], signal.SIGKILL)  # a bus process dies (a bug, the OOM killer)
        seen_error = False
        end = time.monotonic() + 15
        while time.monotonic() < end:
            st = {x["name"]: x for x in d.status()["devices"]}
            states = {n: x["state"] for n, x in st.items()}
            if "error" in states.values():
                seen_error = True
                dead = next(x for x in st.values() if x["state"] == "error")
                assert "exited with code -9" in dead["last_error"]
            if seen_error and all(s == "running" for s in states.values()):
                break
            time.sleep(0.2)
        else:
            raise AssertionError(f"no recovery: {st}\n{d.log.read_text()}")
        # the other bus never stopped
        alive = [n for n in st if st[n]["samples"] > before[n]["samples"] + 400]
        assert alive, st
        assert d.proc.poll() is None
        new_kids = [k for k in _children(d.proc.pid) if "imud.busproc" in _bus_of(k)]
        assert len(new_kids) == 2 and kids[0] not in new_kids
    finally:
        code, _ = d.stop()
    assert code == 0
    assert "restarting it" in d.log.read_text()
    assert not [k for k in new_kids if Path(f"/proc/{k}").exists()]  # none left orphaned


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
