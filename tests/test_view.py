"""`imud view` as Foxglove sees it: a plain WebSocket client here speaks the `foxglove.sdk.v1`
protocol to the real CLI's server (advertise, subscribe, binary message frames) and rosbags
decodes what it receives. Live from a daemon, and from a recording, whose messages arrive as the
file holds them, byte for byte. The layout `--layout` writes plots only topics the server
advertises. Needs the view extra (foxglove-sdk) and websockets: the `extra` tier."""

from __future__ import annotations

import itertools
import json
import re
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.daemon_fixture import DaemonProc

pytestmark = pytest.mark.extra

CONFIG = """
[[device]]
name = "imu0"
chip = "mpu6050"
bus = { kind = "sim", bus = "simV", address = 0x68 }
odr_hz = 1000
dlpf_hz = 188
[device.sim]
seed = 4

[[device]]
name = "compass"
chip = "bno055"
bus = { kind = "sim", bus = "i2cV", transport = "i2c", address = 0x28 }
save_offsets = false
"""


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProc]:
    pytest.importorskip("foxglove")
    pytest.importorskip("websockets")
    d = DaemonProc(Path(tmp_path_factory.mktemp("view")), CONFIG)
    d.wait_started()
    yield d
    code, _ = d.stop()
    assert code == 0, d.log.read_text()


class Viewer:
    """`imud view` in a subprocess, on an ephemeral port it prints."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "imud", "view", "--port", "0", *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert self.proc.stderr is not None
        self.lines = []
        while True:
            line = self.proc.stderr.readline()
            assert line, f"imud view ended: {self.lines}"
            self.lines.append(line)
            m = re.search(r"ws://127\.0\.0\.1:(\d+)", line)
            if m:
                self.url = f"ws://127.0.0.1:{m.group(1)}"
                return

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(20)


def receive(
    url: str, topics: list[str], need: dict[str, int]
) -> tuple[dict[str, Any], dict[str, list[bytes]]]:
    """Connect, wait for the topics to be advertised, subscribe, collect payloads until each
    topic of `need` has that many (or 30 s have passed: how soon they come is the scheduler's
    business, not the test's)."""
    from websockets.sync.client import connect

    channels: dict[str, Any] = {}
    got: dict[str, list[bytes]] = {t: [] for t in topics}
    with connect(url, subprotocols=["foxglove.sdk.v1"]) as ws:
        end = time.monotonic() + 30
        while not set(topics) <= set(channels):
            assert time.monotonic() < end, channels
            try:
                m = ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            if isinstance(m, str) and json.loads(m)["op"] == "advertise":
                channels.update({c["topic"]: c for c in json.loads(m)["channels"]})
        subs = [{"id": k, "channelId": channels[t]["id"]} for k, t in enumerate(topics)]
        ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
        end = time.monotonic() + 30
        while time.monotonic() < end and any(len(got[t]) < k for t, k in need.items()):
            try:
                m = ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            if isinstance(m, bytes) and m[0] == 1:  # a message: sub id, log time, payload
                (sid,) = struct.unpack_from("<I", m, 1)
                got[topics[sid]].append(m[13:])
            elif isinstance(m, str):  # e.g. a subscription refused: say so, do not wait it out
                op = json.loads(m)
                assert not (op["op"] == "status" and op.get("level") == 2), op
    return channels, got


def first_advertised(url: str) -> set[str]:
    """The topics of the server's first advertisement to a new client."""
    from websockets.sync.client import connect

    with connect(url, subprotocols=["foxglove.sdk.v1"]) as ws:
        while True:
            m = ws.recv(timeout=30)
            if isinstance(m, str) and json.loads(m)["op"] == "advertise":
                return {c["topic"] for c in json.loads(m)["channels"]}


def test_live_messages_decode_and_the_status_names_the_devices(
    daemon: DaemonProc, tmp_path: Path
) -> None:
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    layout = tmp_path / "layout.json"
    v = Viewer("--connect", daemon.endpoint, "--layout", str(layout))
    try:
        topics = ["/imu0/imu/data_raw", "/compass/imu/mag", "/imud/status"]
        need = {"/imu0/imu/data_raw": 101, "/compass/imu/mag": 1, "/imud/status": 1}
        channels, got = receive(v.url, topics, need)
    finally:
        v.stop()
    c = channels["/imu0/imu/data_raw"]
    assert (c["encoding"], c["schemaName"], c["schemaEncoding"]) == (
        "cdr", "sensor_msgs/msg/Imu", "ros2msg"
    )  # fmt: skip
    imus = [store.deserialize_cdr(p, "sensor_msgs/msg/Imu") for p in got["/imu0/imu/data_raw"]]
    assert len(imus) > 100  # what it waited for: half a second of the 200 Hz stream
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in imus]
    assert all(b > a for a, b in itertools.pairwise(stamps))
    assert all(m.orientation_covariance[0] == -1.0 for m in imus)
    g = [abs(m.linear_acceleration.z) for m in imus]
    assert 8.0 < sum(g) / len(g) < 11.5  # a simulated MPU6050 lying still, in m/s^2
    mags = [
        store.deserialize_cdr(p, "sensor_msgs/msg/MagneticField") for p in got["/compass/imu/mag"]
    ]
    assert mags and all(1e-6 < abs(m.magnetic_field.x) + abs(m.magnetic_field.y)
                        + abs(m.magnetic_field.z) < 1e-3 for m in mags)  # fmt: skip  # tesla
    status = [json.loads(p) for p in got["/imud/status"]]
    assert status and {d["name"] for d in status[-1]["devices"]} == {"imu0", "compass"}
    # the layout plots topics and fields the server carries
    panels = json.loads(layout.read_text())["configById"]
    paths = [p["value"] for panel in panels.values() for p in panel["paths"]]
    assert paths and all(p.split(".")[0] in channels for p in paths), paths


def test_a_recording_is_served_as_it_was_recorded(daemon: DaemonProc, tmp_path: Path) -> None:
    from mcap.reader import make_reader

    rec = tmp_path / "r.mcap"
    r = daemon.cli(
        "record", "--connect", daemon.endpoint, "imu0", "-o", str(rec), "--duration", "2"
    )
    assert r.returncode == 0, r.stderr
    with open(rec, "rb") as f:
        in_file = [m.data for _, ch, m in make_reader(f).iter_messages()
                   if ch and ch.topic == "/imu0/imu/data_raw"]  # fmt: skip
    v = Viewer(str(rec))
    try:
        # a client that connects as soon as the address is out is told of every topic at once:
        # one that appears later may be refused by the server (foxglove-sdk 0.30's race)
        assert "/imu0/imu/data_raw" in first_advertised(v.url)
        # it plays once this client subscribes: all of the 2 s file
        need = {"/imu0/imu/data_raw": len(in_file), "/imud/status": 1}
        _, got = receive(v.url, ["/imu0/imu/data_raw", "/imud/status"], need)
    finally:
        v.stop()
    received = got["/imu0/imu/data_raw"]
    assert received == in_file, (len(received), len(in_file), len(got["/imud/status"]), v.lines)
    status = [json.loads(p) for p in got["/imud/status"]]  # from the native batches
    assert status and status[-1]["devices"][0]["name"] == "imu0"
    assert status[-1]["devices"][0]["samples"] > 0


def test_a_port_in_use_is_said(daemon: DaemonProc) -> None:
    v = Viewer("--connect", daemon.endpoint)
    try:
        port = v.url.rsplit(":", 1)[1]
        argv = [sys.executable, "-m", "imud", "view", "--port", port, "--connect", daemon.endpoint]
        r = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    finally:
        v.stop()
    assert r.returncode == 2 and "give --port" in r.stderr and "Traceback" not in r.stderr
