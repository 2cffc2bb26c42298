"""The `bridge` profile as zenoh-bridge-ros2dds receives it, beside rmw_zenoh and the native
stream: a real Zenoh subscriber on loopback on the key the bridge routes (the topic without its
'/'), the payloads decoded by rosbags, and the liveliness tokens that announce the publishers to
the bridge parsed by the bridge's own rules (liveliness_mgt.rs), written out here."""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

import imud.client as ic
from tests.daemon_fixture import DaemonProc
from tests.helpers import native_means

pytestmark = pytest.mark.extra  # rosbags (the `dev` extra)
typesys = pytest.importorskip("rosbags.typesys")
STORE = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)

CONFIG = """
[ros2]
enabled = true
profiles = ["rmw_zenoh", "bridge"]
domain_id = 3
namespace = "/robot1"
rate_hz = 200
depth = 7

[[device]]
name = "imu0"
chip = "mpu6050"
bus = { kind = "sim", bus = "simB", address = 0x68 }
odr_hz = 1000
dlpf_hz = 188
[device.sim]
seed = 5
motion = { kind = "poses", hold_s = 0.5, move_s = 0.5, sweep_s = 0.0 }

[[device]]
name = "compass"
chip = "bno055"
bus = { kind = "sim", bus = "i2cB", transport = "i2c", address = 0x28 }
save_offsets = false
"""

# zenoh-bridge-ros2dds's publisher announcement: `@/<zid>/@ros2_lv/MP/<ke>/<type>/<qos>`
TOKEN = re.compile(r"^@/(?P<zid>[^/]+)/@ros2_lv/MP/(?P<ke>[^/]+)/(?P<typ>[^/]+)/(?P<qos>[^/]+)$")


def parse_token(token: str) -> dict[str, Any]:
    m = TOKEN.match(token)
    assert m, token
    parts = m["qos"].split(":")  # [K]:rel:dur:hist,depth[:user data]
    assert len(parts) >= 4, token
    kind, depth = parts[3].split(",")
    return {
        "zid": m["zid"],
        "key": m["ke"].replace("§", "/"),
        "type": m["typ"].replace("§", "/"),
        "keyless": parts[0] == "",
        "reliability": int(parts[1]),  # Cyclone: BEST_EFFORT 0, RELIABLE 1
        "durability": int(parts[2]) if parts[2] else None,  # VOLATILE 0
        "history": (int(kind), int(depth)),  # KEEP_LAST 0
        "user_data": parts[4] if len(parts) > 4 else None,
    }


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProc]:
    d = DaemonProc(Path(tmp_path_factory.mktemp("bridge")), CONFIG)
    d.wait_started()
    yield d
    code, _ = d.stop()
    assert code == 0, d.log.read_text()


def test_the_bridge_key_carries_cdr_rosbags_reads_the_native_streams_means(
    daemon: DaemonProc,
) -> None:
    bridged: list[bytes] = []
    via_rmw = 0
    native: list[bytes] = []
    rmw_key = "3/robot1/imu0/imu/data_raw/**"
    with ic.open_session(daemon.endpoint) as s:
        sub_bridge = s.declare_subscriber(
            "robot1/imu0/imu/data_raw", zenoh.handlers.FifoChannel(100_000)
        )
        sub_rmw = s.declare_subscriber(rmw_key, zenoh.handlers.FifoChannel(100_000))
        sub_nat = s.declare_subscriber("imud/imu0/imu", zenoh.handlers.FifoChannel(100_000))
        end = time.monotonic() + 30  # a bound for a broken daemon
        while len(bridged) < 300 and time.monotonic() < end:
            got = False
            while (x := sub_bridge.try_recv()) is not None:
                bridged.append(x.payload.to_bytes())
                got = True
            while sub_rmw.try_recv() is not None:
                via_rmw += 1
                got = True
            while (x := sub_nat.try_recv()) is not None:
                native.append(x.payload.to_bytes())
                got = True
            if not got:
                time.sleep(0.005)
    assert len(bridged) >= 300, (len(bridged), daemon.log.read_text())
    assert via_rmw > 100  # both profiles at once, from the same messages
    msgs = [STORE.deserialize_cdr(p, "sensor_msgs/msg/Imu") for p in bridged]
    assert {m.header.frame_id for m in msgs} == {"imu_link"}  # the default
    assert all(m.orientation_covariance[0] == -1.0 for m in msgs)
    for m in msgs:
        for cov in (m.angular_velocity_covariance, m.linear_acceleration_covariance):
            assert np.all(cov[[0, 4, 8]] > 0) and not np.delete(cov, [0, 4, 8]).any()
    t = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs])
    assert np.all(np.diff(t) > 0)
    assert np.median(np.diff(t)) == pytest.approx(5e6, rel=0.02)
    by_group = native_means(native, 5)
    matched = [(m, by_group[int(ts)]) for m, ts in zip(msgs, t, strict=True) if ts in by_group]
    assert len(matched) > 200, (len(matched), len(msgs))
    for m, (g, a) in matched:
        av, la = m.angular_velocity, m.linear_acceleration
        np.testing.assert_allclose([av.x, av.y, av.z], g, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose([la.x, la.y, la.z], a, rtol=1e-6, atol=1e-7)


def test_every_topic_is_announced_to_the_bridge(daemon: DaemonProc) -> None:
    with ic.open_session(daemon.endpoint) as s:
        tokens = [str(r.ok.key_expr) for r in s.liveliness().get("@/*/@ros2_lv/**") if r.ok]
        mag = s.declare_subscriber("robot1/compass/imu/mag", zenoh.handlers.FifoChannel(100))
        field = STORE.deserialize_cdr(
            mag.recv().payload.to_bytes(), "sensor_msgs/msg/MagneticField"
        )
    parsed = {p["key"]: p for p in map(parse_token, tokens)}
    want = {
        "robot1/imu0/imu/data_raw": "sensor_msgs/msg/Imu",
        "robot1/compass/imu/data_raw": "sensor_msgs/msg/Imu",
        "robot1/compass/imu/data": "sensor_msgs/msg/Imu",
        "robot1/compass/imu/mag": "sensor_msgs/msg/MagneticField",
        "diagnostics": "diagnostic_msgs/msg/DiagnosticArray",  # /diagnostics, never namespaced
    }
    assert {k: p["type"] for k, p in parsed.items()} == want
    for p in parsed.values():
        assert p["keyless"] and p["reliability"] == 1 and p["durability"] == 0
        assert p["history"] == (0, 7)
        assert p["user_data"] == f"typehash={STORE.hash_rihs01(p['type'])};"
    assert len({p["zid"] for p in parsed.values()}) == 1  # the daemon's session
    b = field.magnetic_field
    assert 20e-6 < np.linalg.norm([b.x, b.y, b.z]) < 70e-6  # tesla
