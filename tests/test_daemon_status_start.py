"""From its first answer on, the daemon's status lists every configured device.

A client that waits for "no device is starting" (`imud status --wait`-style loops, the tests'
own `wait_started`, a supervisor script) reads an empty device list as "all started". So the
daemon must not answer a status query before it holds its devices' status. The test holds the
daemon at the moment it builds its bus links and asks for its status from a second, real Zenoh
session on loopback: whatever answers there must name both devices.
"""

from __future__ import annotations

import threading
from typing import Any

import pytest

import imud.client as ic
from imud.config import parse_config
from imud.daemon import Daemon
from tests.helpers import free_port, run_in_process

DEVICES = ("imu0", "imu1")


def _daemon(endpoint: str) -> Daemon:
    devices = [
        {
            "name": name,
            "chip": "mpu6050",
            "bus": {"kind": "sim", "bus": "simS", "address": address},
            "odr_hz": 100,
            "sim": {"seed": i + 1, "errors": {"ideal": True}},
        }
        for i, (name, address) in enumerate(zip(DEVICES, (0x68, 0x69), strict=True))
    ]
    # the workers as threads: what is tested happens before any worker exists
    cfg = {"zenoh": {"listen": [endpoint]}, "device": devices, "daemon": {"bus_processes": False}}
    return Daemon(parse_config(cfg))


def _connect(endpoint: str) -> Any:
    """A session to the daemon, retried until its listener is open."""
    for _ in range(300):
        try:
            return ic.open_session(endpoint)
        except ic.NoDaemon:
            threading.Event().wait(0.1)
    raise AssertionError(f"nothing listens on {endpoint}")


def test_no_status_answer_lists_fewer_devices_than_configured(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    d = _daemon(endpoint)
    seen: list[Any] = []  # what a status query got while the links were being made
    answers: list[dict[str, Any]] = []
    make_links = d._make_links

    def held_make_links(*args: Any) -> Any:
        # the daemon's Zenoh session is open and listening here: ask it
        s = ic.open_session(endpoint)
        try:
            seen.append(ic.get_status(s, timeout=1.0))
        except ic.NoDaemon as e:
            seen.append(e)
        finally:
            s.close()
        return make_links(*args)

    monkeypatch.setattr(d, "_make_links", held_make_links)

    def drive() -> None:
        try:
            s = _connect(endpoint)
            try:
                for _ in range(50):
                    try:
                        st = ic.get_status(s, timeout=2.0)
                    except ic.NoDaemon:  # listening, its status not declared yet: no answer
                        threading.Event().wait(0.1)
                        continue
                    answers.append(st)
                    if st["ready"]:
                        break
                    threading.Event().wait(0.1)
            finally:
                s.close()
        finally:
            d.request_stop()

    run_in_process(d, drive)
    assert len(seen) == 1
    if not isinstance(seen[0], ic.NoDaemon):
        assert sorted(x["name"] for x in seen[0]["devices"]) == sorted(DEVICES), seen[0]
    assert answers, "the daemon never answered"
    for st in answers:
        assert sorted(x["name"] for x in st["devices"]) == sorted(DEVICES), st
