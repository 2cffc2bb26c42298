"""The daemon as a ROS 2 publisher on rmw_zenoh, received by a real Zenoh subscriber on loopback
the way rmw_zenoh subscribes: its key, its attachment, its liveliness tokens, parsed here by the
test's own rules (rmw_zenoh's liveliness_utils.cpp and attachment_helpers.cpp), and each message's
CDR read by a parser written here from the sensor_msgs definitions. The messages are checked
against the native stream they come from: each is the mean of five 1 kHz samples."""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import xxhash
import zenoh

import imud.client as ic
from tests.daemon_fixture import DaemonProc
from tests.helpers import free_port, native_means

IMU_HASH = "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b"
MAG_HASH = "RIHS01_e80f32f56a20486c9923008fc1a1db07bbb273cbbf6a5b3bfa00835ee00e4dff"


def config(router_port: int) -> str:
    return f"""
[ros2]
enabled = true
domain_id = 7
namespace = "/robot1"
rate_hz = 200
connect = ["tcp/127.0.0.1:{router_port}"]   # no router there: imud runs on regardless

[[device]]
name = "imu0"
chip = "mpu6050"
bus = {{ kind = "sim", bus = "simR", address = 0x68 }}
odr_hz = 1000
dlpf_hz = 188
[device.ros2]
frame_id = "imu0_link"
[device.sim]
seed = 3
motion = {{ kind = "poses", hold_s = 0.5, move_s = 0.5, sweep_s = 0.0 }}

[[device]]
name = "compass"
chip = "bno055"
bus = {{ kind = "sim", bus = "i2cR", transport = "i2c", address = 0x28 }}
save_offsets = false
"""


def parse_imu(buf: bytes) -> dict[str, Any]:
    """sensor_msgs/msg/Imu from CDR (little-endian, 4-byte encapsulation header), by hand."""
    assert buf[:4] == b"\x00\x01\x00\x00"
    body = buf[4:]
    sec, nanosec, n = struct.unpack_from("<iII", body, 0)
    frame = body[12 : 12 + n]
    assert frame.endswith(b"\0")
    at = (12 + n + 7) // 8 * 8
    f = struct.unpack_from("<37d", body, at)
    assert at + 37 * 8 == len(body)
    return {
        "t_ns": sec * 10**9 + nanosec,
        "frame_id": frame[:-1].decode(),
        "orientation": f[0:4],
        "orientation_covariance": f[4:13],
        "gyro": f[13:16],
        "gyro_covariance": f[16:25],
        "accel": f[25:28],
        "accel_covariance": f[28:37],
    }


def parse_attachment(a: bytes) -> tuple[int, int, bytes]:
    """int64 sequence, int64 source time, then a 16-byte sequence (LEB128 length 16)."""
    assert len(a) == 33 and a[16] == 16, a.hex()
    seq, t = struct.unpack_from("<qq", a)
    return seq, t, a[17:]


def gid_of(token: str) -> bytes:
    h = xxhash.xxh3_128_intdigest(token.encode())
    return (h & (2**64 - 1)).to_bytes(8, "little") + (h >> 64).to_bytes(8, "little")


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProc]:
    d = DaemonProc(Path(tmp_path_factory.mktemp("ros2")), config(free_port()))
    d.wait_started()
    yield d
    code, _ = d.stop()
    assert code == 0, d.log.read_text()


def test_messages_on_rmw_zenohs_key_are_the_native_streams_means(daemon: DaemonProc) -> None:
    key = f"7/robot1/imu0/imu/data_raw/sensor_msgs::msg::dds_::Imu_/{IMU_HASH}"
    ros: list[tuple[bytes, bytes]] = []
    native: list[bytes] = []
    done = threading.Event()
    with ic.open_session(daemon.endpoint) as s:
        sub_ros = s.declare_subscriber(key, zenoh.handlers.FifoChannel(100_000))
        sub_nat = s.declare_subscriber("imud/imu0/imu", zenoh.handlers.FifoChannel(100_000))
        end = time.monotonic() + 30  # a bound for a broken daemon
        while len(ros) < 400 and time.monotonic() < end:
            got = False
            for sub, into in ((sub_ros, ros), (sub_nat, native)):
                sample = sub.try_recv()
                if sample is not None:
                    got = True
                    if into is ros:
                        att = sample.attachment
                        assert att is not None, "a message without attachment"
                        ros.append((sample.payload.to_bytes(), att.to_bytes()))
                    else:
                        native.append(sample.payload.to_bytes())
            if not got:
                time.sleep(0.005)
        done.set()
        tokens = [str(r.ok.key_expr) for r in s.liveliness().get("@ros2_lv/7/**") if r.ok]
    assert len(ros) >= 400, len(ros)
    msgs = [parse_imu(p) for p, _ in ros]
    atts = [parse_attachment(a) for _, a in ros]
    # the attachment: +1 a message from 1 (a subscriber that joined late sees a later start)
    seqs = [a[0] for a in atts]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    # the GID is the XXH3-128 of this topic's publisher token
    (token,) = [t for t in tokens if "/MP/" in t and "%imu0%imu%data_raw" in t]
    assert {a[2] for a in atts} == {gid_of(token)}
    assert token.split("/")[7:9] == ["%robot1", "imud"]  # the node's namespace and name
    assert any(t.endswith("/NN/%/%robot1/imud") for t in tokens), tokens
    # REP-145: no orientation, said with -1, and the frame_id of the device
    assert all(m["orientation_covariance"][0] == -1.0 for m in msgs)
    assert {m["frame_id"] for m in msgs} == {"imu0_link"}
    # the covariances (docs/ros2.md): diagonal, positive, never -1: the MPU6050's density over
    # its 188 Hz DLPF, the mean of five samples
    for key in ("gyro_covariance", "accel_covariance"):
        c = np.array([m[key] for m in msgs])
        assert np.all(c[:, [0, 4, 8]] > 0) and not np.delete(c, [0, 4, 8], axis=1).any()
        assert np.all(c == c[0])
    single = np.radians(0.005) ** 2 * 188  # one sample's variance: the mean's is below it
    assert single / 5 < msgs[0]["gyro_covariance"][0] < single
    # stamps strictly increase, 5 ms apart (five 1 kHz samples a message)
    t = np.array([m["t_ns"] for m in msgs])
    assert np.all(np.diff(t) > 0)
    assert np.median(np.diff(t)) == pytest.approx(5e6, rel=0.02)
    # each message is the mean of the native samples with seq 5m..5m+4
    by_group = native_means(native, 5)
    matched = [m for m in msgs if m["t_ns"] in by_group]
    assert len(matched) > 300, (len(matched), len(msgs))
    for m in matched:
        np.testing.assert_allclose(m["gyro"], by_group[m["t_ns"]][0], rtol=1e-6, atol=1e-9)


def test_a_chip_with_an_orientation_and_a_magnetometer_has_imu_data_and_imu_mag(
    daemon: DaemonProc,
) -> None:
    with ic.open_session(daemon.endpoint) as s:
        tokens = [str(r.ok.key_expr) for r in s.liveliness().get("@ros2_lv/7/**") if r.ok]
        got = {}
        for topic, type_name, h in [
            ("imu/data", "Imu", IMU_HASH),
            ("imu/mag", "MagneticField", MAG_HASH),
        ]:
            key = f"7/robot1/compass/{topic}/sensor_msgs::msg::dds_::{type_name}_/{h}"
            sub = s.declare_subscriber(key, zenoh.handlers.FifoChannel(1000))
            got[topic] = sub.recv()
    assert any("%robot1%compass%imu%data/sensor_msgs::msg::dds_::Imu_" in t for t in tokens)
    assert any(
        "%robot1%compass%imu%mag/sensor_msgs::msg::dds_::MagneticField_" in t for t in tokens
    )
    fused = parse_imu(got["imu/data"].payload.to_bytes())
    q = np.array(fused["orientation"])
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-3)  # a real orientation
    assert fused["orientation_covariance"] == (0.0,) * 9  # known to be there, accuracy unknown
    assert all(fused["gyro_covariance"][i] > 0 for i in (0, 4, 8))
    mag = got["imu/mag"].payload.to_bytes()[4:]
    (n,) = struct.unpack_from("<I", mag, 8)
    at = (12 + n + 7) // 8 * 8
    field = np.array(struct.unpack_from("<3d", mag, at))
    assert 20e-6 < np.linalg.norm(field) < 70e-6  # tesla: the Earth's field, not µT or gauss
    cov = np.array(struct.unpack_from("<9d", mag, at + 24))  # one 100 Hz sample a message
    np.testing.assert_allclose(cov, np.diag([0.3e-6**2] * 3).ravel(), rtol=1e-12)


def test_status_names_the_ros2_topics(daemon: DaemonProc) -> None:
    st = daemon.status()["ros2"]
    assert st["domain_id"] == 7 and st["error"] is None
    assert "/robot1/imu0/imu/data_raw" in st["topics"] and "/robot1/compass/imu/mag" in st["topics"]


@pytest.mark.extra  # rosbags
def test_rosbags_reads_every_field_of_every_topic_off_the_wire(daemon: DaemonProc) -> None:
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    topics = [
        ("imu0/imu/data_raw", "sensor_msgs/msg/Imu", IMU_HASH),
        ("compass/imu/data_raw", "sensor_msgs/msg/Imu", IMU_HASH),
        ("compass/imu/data", "sensor_msgs/msg/Imu", IMU_HASH),
        ("compass/imu/mag", "sensor_msgs/msg/MagneticField", MAG_HASH),
    ]
    with ic.open_session(daemon.endpoint) as s:
        subs = [
            (topic, type_name, s.declare_subscriber(
                f"7/robot1/{topic}/{type_name.replace('/msg/', '::msg::dds_::')}_/{h}",
                zenoh.handlers.FifoChannel(1000)))
            for topic, type_name, h in topics
        ]  # fmt: skip
        got = {topic: (type_name, sub.recv().payload.to_bytes()) for topic, type_name, sub in subs}
    for topic, (type_name, payload) in got.items():
        msg = store.deserialize_cdr(payload, type_name)
        # rosbags' own serialisation of what it read gives the same bytes: no field is off
        assert bytes(store.serialize_cdr(msg, type_name)) == payload, topic
        assert msg.header.frame_id == ("imu0_link" if topic.startswith("imu0") else "imu_link")
        assert msg.header.stamp.sec > 1_600_000_000  # the epoch, not the uptime
        if type_name.endswith("Imu"):
            raw = topic.endswith("data_raw")
            assert (msg.orientation_covariance[0] == -1.0) == raw, topic
            if not raw:
                o = msg.orientation
                assert np.hypot(np.hypot(o.x, o.y), np.hypot(o.z, o.w)) == pytest.approx(
                    1, abs=1e-3
                )
            a = msg.linear_acceleration
            assert 5.0 < np.linalg.norm([a.x, a.y, a.z]) < 15.0, topic  # m/s^2, gravity
            assert np.all(msg.angular_velocity_covariance[[0, 4, 8]] > 0)
        else:
            f = msg.magnetic_field
            assert 20e-6 < np.linalg.norm([f.x, f.y, f.z]) < 70e-6  # tesla
