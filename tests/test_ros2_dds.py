"""The `dds` profile received by a Cyclone DDS reader in a second process, the way a ROS 2 node on
rmw_cyclonedds subscribes: topic `rt/<topic>`, ROS 2's type names, final types, XCDR1, a
RELIABLE reader (which a BEST_EFFORT writer would not match). The reader's IDL types are written
in the script below from the sensor_msgs definitions, not taken from imud. Everything runs in a
private network namespace (`unshare -n`): Cyclone DDS sends a multicast probe even when told to
use loopback only. The messages are checked against the native stream they come from."""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.helpers import native_means

pytestmark = [
    pytest.mark.extra,  # cyclonedds (the `dds` extra, in `dev`)
    pytest.mark.skipif(shutil.which("unshare") is None, reason="needs unshare (util-linux)"),
]
pytest.importorskip("cyclonedds")

REPO = Path(__file__).resolve().parent.parent
IMU_HASH = "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b"

CONFIG = """
[zenoh]
listen = ["tcp/127.0.0.1:7460"]
prefix = "imud"

[ros2]
enabled = true
profiles = ["rmw_zenoh", "bridge", "dds"]  # all at once, beside the native stream
domain_id = 7
namespace = "/robot1"
rate_hz = 200

[[device]]
name = "imu0"
chip = "mpu6050"
bus = { kind = "sim", bus = "simD", address = 0x68 }
odr_hz = 1000
dlpf_hz = 188
[device.ros2]
frame_id = "imu0_link"
[device.sim]
seed = 3
motion = { kind = "poses", hold_s = 0.5, move_s = 0.5, sweep_s = 0.0 }
"""

# Run inside the namespace: the daemon as a subprocess, this process the DDS reader (and a Zenoh
# client for the native stream). Prints one JSON line.
SCRIPT = r"""
import base64, json, os, signal, subprocess, sys, time
from dataclasses import dataclass

tmp = sys.argv[1]
os.environ["CYCLONEDDS_URI"] = (
    '<General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General>"
    '<Discovery><ParticipantIndex>auto</ParticipantIndex><Peers><Peer address="127.0.0.1"/>'
    "</Peers></Discovery>"
)  # the daemon inherits it, as from a systemd unit's Environment=
log = open(os.path.join(tmp, "daemon.log"), "wb")
run = [sys.executable, "-m", "imud", "run", "--config", os.path.join(tmp, "imud.toml")]
daemon = subprocess.Popen(run, stderr=log)

import zenoh
from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.annotations import extensibility
from cyclonedds.idl.types import array, byte, float64, int32, sequence, uint32

Cov = array[float64, 9]

@extensibility("final")
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32

@extensibility("final")
@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str

@extensibility("final")
@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64

@extensibility("final")
@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64

@extensibility("final")
@dataclass
class Imu(IdlStruct, typename="sensor_msgs::msg::dds_::Imu_"):
    header: Header
    orientation: Quaternion
    orientation_covariance: Cov
    angular_velocity: Vector3
    angular_velocity_covariance: Cov
    linear_acceleration: Vector3
    linear_acceleration_covariance: Cov

@extensibility("final")
@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str

@extensibility("final")
@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: byte
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue]

@extensibility("final")
@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header
    status: sequence[DiagnosticStatus]

from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

TOPIC = "rt/robot1/imu0/imu/data_raw"
dp = DomainParticipant(7)
qos = Qos(
    Policy.Reliability.Reliable(0),
    Policy.History.KeepLast(1000),
    Policy.DataRepresentation(use_cdrv0_representation=True),
)
reader = DataReader(dp, Topic(dp, TOPIC, Imu), qos=qos)
diag_reader = DataReader(dp, Topic(dp, "rt/diagnostics", DiagnosticArray), qos=qos)
pubs = BuiltinDataReader(dp, BuiltinTopicDcpsPublication)

# the writer as discovery announces it (read before the data: its QoS is what a ROS node matches)
writers = []
end = time.monotonic() + 30
while not writers and time.monotonic() < end:
    for p in pubs.take(N=100):
        if p.topic_name == TOPIC:
            ud = p.qos[Policy.Userdata] if Policy.Userdata in p.qos else None
            rel = p.qos[Policy.Reliability] if Policy.Reliability in p.qos else None
            writers.append({
                "type": p.type_name,
                "userdata": ud.data.decode() if ud is not None else None,
                "reliable": isinstance(rel, Policy.Reliability.Reliable),
            })
    time.sleep(0.05)

conf = zenoh.Config.from_json5(json.dumps({
    "mode": "client",
    "scouting": {"multicast": {"enabled": False}},
    "connect": {"endpoints": ["tcp/127.0.0.1:7460"]},
}))
session = None
while session is None and time.monotonic() < end:
    try:
        session = zenoh.open(conf)
    except Exception:
        time.sleep(0.2)
native_sub = session.declare_subscriber("imud/imu0/imu", zenoh.handlers.FifoChannel(100000))
others = {
    name: session.declare_subscriber(key, zenoh.handlers.FifoChannel(100000))
    for name, key in [
        ("bridge", "robot1/imu0/imu/data_raw"),
        ("rmw_zenoh", "7/robot1/imu0/imu/data_raw/**"),
    ]
}
counts = dict.fromkeys(others, 0)

msgs, native = [], []
end = time.monotonic() + 30
while len(msgs) < 400 and time.monotonic() < end:
    for m in reader.take(N=1000):
        msgs.append({
            "sec": m.header.stamp.sec,
            "nanosec": m.header.stamp.nanosec,
            "frame_id": m.header.frame_id,
            "orientation": [m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w],
            "orientation_covariance": list(m.orientation_covariance),
            "gyro": [m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z],
            "gyro_covariance": list(m.angular_velocity_covariance),
            "accel": [m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z],
            "accel_covariance": list(m.linear_acceleration_covariance),
        })
    while (s := native_sub.try_recv()) is not None:
        native.append(base64.b64encode(s.payload.to_bytes()).decode())
    for name, sub in others.items():
        while sub.try_recv() is not None:
            counts[name] += 1
    time.sleep(0.01)
diagnostics = []
end = time.monotonic() + 5
while not diagnostics and time.monotonic() < end:
    for d in diag_reader.take(N=10):
        diagnostics.append([
            {"level": s.level, "name": s.name, "values": {kv.key: kv.value for kv in s.values}}
            for s in d.status
        ])
    time.sleep(0.05)
session.close()
daemon.send_signal(signal.SIGTERM)
code = daemon.wait(timeout=20)
out = {"diagnostics": diagnostics, "writers": writers, "msgs": msgs, "native": native,
       "counts": counts, "code": code}
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def received(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    tmp = tmp_path_factory.mktemp("dds")
    (tmp / "imud.toml").write_text(CONFIG)
    r = subprocess.run(
        ["unshare", "-n", "sh", "-c", 'ip link set lo up && exec "$0" -c "$1" "$2"',
         sys.executable, SCRIPT, str(tmp)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=150,
    )  # fmt: skip
    log = (tmp / "daemon.log").read_text() if (tmp / "daemon.log").exists() else ""
    assert r.returncode == 0, r.stderr + log
    out: dict[str, Any] = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["code"] == 0, log
    out["log"] = log
    return out


def test_the_writer_is_what_a_ros_2_node_on_dds_matches(received: dict[str, Any]) -> None:
    (w,) = received["writers"]
    assert w["type"] == "sensor_msgs::msg::dds_::Imu_"
    assert w["reliable"]  # a BEST_EFFORT writer does not match a RELIABLE reader
    assert w["userdata"] == f"typehash={IMU_HASH};"  # what Iron and later put there


def test_a_dds_reader_receives_the_native_streams_means(received: dict[str, Any]) -> None:
    msgs = received["msgs"]
    assert len(msgs) >= 400, (len(msgs), received["log"])
    # the same messages went out on the Zenoh profiles too
    assert received["counts"]["bridge"] > 100 and received["counts"]["rmw_zenoh"] > 100
    assert {m["frame_id"] for m in msgs} == {"imu0_link"}
    # REP-145: no orientation, said with -1 there and only there
    assert all(m["orientation_covariance"][0] == -1.0 for m in msgs)
    assert all(m["gyro_covariance"][0] > 0 and m["accel_covariance"][0] > 0 for m in msgs)
    # stamps strictly increase, 5 ms apart (five 1 kHz samples a message), none lost on the way
    t = np.array([m["sec"] * 10**9 + m["nanosec"] for m in msgs], dtype=np.int64)
    assert np.all(np.diff(t) > 0)
    assert np.median(np.diff(t)) == pytest.approx(5e6, rel=0.02)
    # each message is the mean of the native samples with seq 5m..5m+4
    by_group = native_means([base64.b64decode(p) for p in received["native"]], 5)
    matched = [(m, by_group[int(ts)]) for m, ts in zip(msgs, t, strict=True) if ts in by_group]
    assert len(matched) > 300, (len(matched), len(msgs))
    for m, (g, a) in matched:
        np.testing.assert_allclose(m["gyro"], g, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(m["accel"], a, rtol=1e-6, atol=1e-7)


def test_a_dds_reader_receives_the_diagnostics(received: dict[str, Any]) -> None:
    (first, *_) = received["diagnostics"]
    (status,) = first
    assert status["name"] == "imud: imu0" and status["values"]["state"] == "running"
    assert int(status["values"]["samples"]) > 0
