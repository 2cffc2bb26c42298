"""Issue 10: the daemon keeps serving while the Zenoh network around it changes.

A real daemon (two simulated MPU6050s on one simulated bus, the bus in its own process as by
default) runs in this process on loopback endpoints, next to a Zenoh router in a child process (no
`zenohd` binary is needed: a Python session in `router` mode routes the same way). While it
runs, subscribers open and close sessions over and over (some close cleanly, some vanish with
SIGKILL), a peer joins and leaves, and the router is killed and started again on the same port.
Afterwards a fresh subscriber behind the router receives batches again, the sample numbers go on
from where they were (the device never restarted), the status query answers and every device is
still running.

The daemon is tried both ways a deployment connects it: as a peer that listens for local clients
and also connects to the router, and as a client of the router only. Every wait has a generous
deadline so a stuck daemon fails the test instead of hanging it; no assertion depends on how long
anything took.
"""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

import imud.client as ic
from imud.config import parse_config
from imud.daemon import Daemon
from tests.helpers import free_port, run_in_process

pytestmark = pytest.mark.slow  # sessions churned and a router restarted, in real time

DEADLINE_S = 20.0  # a bound against hanging, far above what any step needs on a loaded machine
DEVICES = ("imu0", "imu1")

# A Zenoh router in its own process, on loopback, multicast scouting off. It prints "ready" once
# its listener is open and lives until stdin closes or it is killed.
ROUTER = """
import json, sys, zenoh
conf = {"mode": "router", "listen": {"endpoints": [sys.argv[1]]},
        "scouting": {"multicast": {"enabled": False}}}
session = zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))
print("ready", flush=True)
sys.stdin.read()
"""

# A subscriber process that is killed while connected: its session never says goodbye.
DOOMED_SUBSCRIBER = """
import json, sys, zenoh
conf = {"mode": "client", "connect": {"endpoints": [sys.argv[1]]},
        "scouting": {"multicast": {"enabled": False}}}
session = zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))
sub = session.declare_subscriber(sys.argv[2], zenoh.handlers.FifoChannel(64))
sub.recv()
print("got", flush=True)
sys.stdin.read()
"""


class Router:
    """A killable, restartable Zenoh router on one fixed loopback endpoint."""

    def __init__(self) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.proc: subprocess.Popen[str] | None = None
        self.starts = 0

    def start(self) -> None:
        end = time.monotonic() + DEADLINE_S
        while True:  # the killed router's port can take a moment to be free again
            proc = subprocess.Popen(
                [sys.executable, "-c", ROUTER, self.endpoint],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                text=True,
            )
            assert proc.stdout is not None
            if proc.stdout.readline().strip() == "ready":
                self.proc = proc
                self.starts += 1
                return
            proc.wait()
            assert time.monotonic() < end, "the router did not start"
            time.sleep(0.2)

    def kill(self) -> None:
        assert self.proc is not None and self.proc.poll() is None, "the router died on its own"
        self.proc.kill()
        self.proc.wait()
        self.proc = None

    def close(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture
def router() -> Iterator[Router]:
    r = Router()
    r.start()
    try:
        yield r
    finally:
        r.close()


def daemon_for(mode: str, listen: str, router: Router) -> Daemon:
    devices = [
        {
            "name": name,
            "chip": "mpu6050",
            "bus": {"kind": "sim", "bus": "simZ", "address": address},
            "odr_hz": 200,
            "sim": {"seed": i + 1, "errors": {"ideal": True}},
        }
        for i, (name, address) in enumerate(zip(DEVICES, (0x68, 0x69), strict=True))
    ]
    zen: dict[str, Any] = {"mode": mode, "connect": [router.endpoint], "listen": []}
    if mode == "peer":
        zen["listen"] = [listen]
    return Daemon(parse_config({"zenoh": zen, "device": devices}))


def open_client(endpoint: str) -> zenoh.Session:
    """A client session, retried while the far end is not (yet, or again) there."""
    end = time.monotonic() + DEADLINE_S
    while True:
        try:
            return ic.open_session(endpoint)
        except ic.NoDaemon:
            assert time.monotonic() < end, f"nothing to connect to at {endpoint}"
            time.sleep(0.1)


def open_peer(endpoint: str) -> zenoh.Session:
    """A peer that listens on its own loopback port and connects to `endpoint`."""
    conf = {
        "mode": "peer",
        "listen": {"endpoints": [f"tcp/127.0.0.1:{free_port()}"]},
        "connect": {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}},
    }
    return zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))


def receive(session: zenoh.Session, device: str, n: int) -> list[ic.Batch]:
    """The first `n` batches a new subscriber in `session` gets."""
    got = list(ic.batches(session, device, limit=n, timeout=DEADLINE_S))
    assert len(got) == n, f"{device}: {len(got)} of {n} batches arrived"
    return got


def status_when_ready(session: zenoh.Session) -> dict[str, Any]:
    end = time.monotonic() + DEADLINE_S
    while True:
        try:
            st = ic.get_status(session, timeout=2.0)
            if st["ready"]:
                return st
        except ic.NoDaemon:
            pass
        assert time.monotonic() < end, "the daemon never answered ready"
        time.sleep(0.1)


def assert_all_running(st: dict[str, Any]) -> None:
    assert [d["name"] for d in st["devices"]] == list(DEVICES)
    for d in st["devices"]:
        assert d["state"] == "running", d
        assert d["restarts"] == 0 and d["unexpected_errors"] == 0, d
    assert all(b["restarts"] == 0 and b["pid"] is not None for b in st["buses"]), st["buses"]


def churn(entry: str) -> None:
    """24 subscriber sessions from 4 threads at once, each waiting for one batch before it goes:
    half close their session cleanly, half drop it without undeclaring anything; plus one
    subscriber process killed while connected."""
    failures: list[BaseException] = []

    def worker(k: int) -> None:
        try:
            for i in range(6):
                s = open_client(entry)
                device = DEVICES[(k + i) % 2]
                if (k + i) % 2:
                    receive(s, device, 1)
                else:  # the subscriber is still declared when the session goes
                    sub = s.declare_subscriber(ic.data_key(device), zenoh.handlers.FifoChannel(8))
                    assert sub.recv() is not None
                s.close()  # type: ignore[no-untyped-call]
        except BaseException as e:  # reported by the caller
            failures.append(e)

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    doomed = subprocess.Popen(
        [sys.executable, "-c", DOOMED_SUBSCRIBER, entry, ic.data_key(DEVICES[0])],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert doomed.stdout is not None
        assert doomed.stdout.readline().strip() == "got"
    finally:
        doomed.kill()
        doomed.wait()
    for t in threads:
        t.join()
    assert not failures, failures


def peer_visits(entry: str) -> None:
    """A peer joins, takes data, leaves; twice."""
    for _ in range(2):
        with open_peer(entry) as p:
            receive(p, DEVICES[1], 2)


@pytest.mark.parametrize("mode", ["peer", "client"])
def test_daemon_survives_churn_and_a_router_restart(mode: str, router: Router) -> None:
    listen = f"tcp/127.0.0.1:{free_port()}"
    # a peer daemon takes local clients itself; a client daemon is reachable through the router
    entry = listen if mode == "peer" else router.endpoint
    daemon = daemon_for(mode, listen, router)
    seen: dict[str, int] = {}
    after: dict[str, list[ic.Batch]] = {}
    final: dict[str, Any] = {}
    failure: list[BaseException] = []

    def drive() -> None:
        try:
            with open_client(entry) as s:
                assert_all_running(status_when_ready(s))
            churn(entry)
            peer_visits(entry)
            with open_client(router.endpoint) as s:  # data reaches the router's side
                for name in DEVICES:
                    last = receive(s, name, 2)[-1]
                    seen[name] = last.first_seq + last.count
            router.kill()
            if mode == "peer":  # the local side goes on while the router is away
                with open_client(entry) as s:
                    receive(s, DEVICES[0], 2)
            router.start()
            with open_client(router.endpoint) as s:  # a fresh subscriber behind the new router
                for name in DEVICES:
                    after[name] = receive(s, name, 3)
                final.update(status_when_ready(s))
        except BaseException as e:  # reported by the test body
            failure.append(e)
        finally:
            daemon.request_stop()

    run_in_process(daemon, drive)
    assert not failure, failure
    assert router.starts == 2
    for name in DEVICES:
        batches = after[name]
        # sample numbers go on: nothing restarted from zero, and the new subscriber's stream
        # is continuous or counts what it missed
        assert batches[0].first_seq >= seen[name], (name, batches[0].first_seq, seen[name])
        for prev, b in itertools.pairwise(batches):
            assert b.first_seq - (prev.first_seq + prev.count) == b.lost_before
    assert_all_running(final)
