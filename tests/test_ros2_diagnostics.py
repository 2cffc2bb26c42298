"""/diagnostics (diagnostic_msgs/msg/DiagnosticArray): how a ROS 2 user sees a lost sample.

The encoder against rosbags byte for byte; the levels a device's status maps to; and the daemon
with a device whose bus goes dead for a while: a ROS node on rmw_zenoh's key reads the reports
with rosbags, sees the loss reported, and the total matches the native stream's own gap count
(the source of truth)."""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

import imud.client as ic
from imud.ros2 import diagnostics as diag
from imud.ros2.diagnostics import Level, Status
from imud.wire import decode
from tests.daemon_fixture import DaemonProc

DIAG_HASH = "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e"


def running(**kw: Any) -> dict[str, Any]:
    base = {"name": "imu0", "chip": "mpu6050", "bus": "sim-i2c:s@0x68", "state": "running",
            "odr_hz": 1000.0, "measured_rate_hz": 999.8, "samples": 5000,
            "lost_samples": 0}  # fmt: skip
    return {**base, **kw}


def test_a_second_with_lost_samples_is_a_warning_and_says_how_many() -> None:
    first = diag.device_status(running(lost_samples=3), None, 1.0)
    assert first.level is Level.OK  # the first report has no earlier count to compare with
    s = diag.device_status(running(lost_samples=15), 3, 1.0)
    assert s.level is Level.WARN and s.message == "12 samples lost in the last 1 s"
    values = dict(s.values)
    assert values["lost_since_last_report"] == "12" and values["lost samples"] == "15"
    assert s.name == "imud: imu0" and s.hardware_id == "mpu6050 on sim-i2c:s@0x68"
    ok = diag.device_status(running(lost_samples=15), 15, 1.0)
    assert ok.level is Level.OK and ok.message == "running at 999.8 Hz"


def test_failing_and_not_running_devices_are_error_and_stale() -> None:
    err = diag.device_status(running(state="error", last_error="bus NAK at 0x68"), 0, 1.0)
    assert err.level is Level.ERROR and err.message == "bus NAK at 0x68"
    assert diag.device_status(running(state="starting"), 0, 1.0).level is Level.STALE
    bad_cal = diag.device_status(running(calibration_error="file missing"), 0, 1.0)
    assert bad_cal.level is Level.WARN and bad_cal.message == "file missing"


text = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\0"), max_size=12)
status_st = st.builds(
    Status,
    st.sampled_from(list(Level)),
    text,
    text,
    text,
    st.lists(st.tuples(text, text), max_size=4),
)


@pytest.mark.extra  # rosbags
@settings(max_examples=200, deadline=None)
@given(
    t_ns=st.integers(0, 2**31 * 10**9 - 1),
    statuses=st.lists(status_st, max_size=4),
    frame_id=text,
)
def test_the_cdr_is_rosbags_byte_for_byte(t_ns: int, statuses: list[Status], frame_id: str) -> None:
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    T = store.types
    msg = T["diagnostic_msgs/msg/DiagnosticArray"](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
            frame_id=frame_id,
        ),
        status=[
            T["diagnostic_msgs/msg/DiagnosticStatus"](
                level=int(s.level),
                name=s.name,
                message=s.message,
                hardware_id=s.hardware_id,
                values=[T["diagnostic_msgs/msg/KeyValue"](key=k, value=v) for k, v in s.values],
            )
            for s in statuses
        ],
    )
    want = bytes(store.serialize_cdr(msg, "diagnostic_msgs/msg/DiagnosticArray"))
    assert diag.encode(t_ns, statuses, frame_id) == want


CONFIG = """
[ros2]
enabled = true
domain_id = 4

[[device]]
name = "imu0"
chip = "mpu6050"
bus = { kind = "sim", bus = "simG", address = 0x68 }
odr_hz = 1000
[device.sim]
seed = 11
[device.sim.faults]
outages = [{ at_s = 2.5, for_s = 0.6 }]
"""


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProc]:
    d = DaemonProc(Path(tmp_path_factory.mktemp("diag")), CONFIG)
    d.wait_started()
    yield d
    code, _ = d.stop()
    assert code == 0, d.log.read_text()


@pytest.mark.extra  # rosbags
def test_a_ros_node_sees_the_lost_samples_the_native_stream_counts(daemon: DaemonProc) -> None:
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    key = f"4/diagnostics/diagnostic_msgs::msg::dds_::DiagnosticArray_/{DIAG_HASH}"
    reports: list[Any] = []
    native: list[bytes] = []
    with ic.open_session(daemon.endpoint) as s:
        sub = s.declare_subscriber(key, zenoh.handlers.FifoChannel(1000))
        nat = s.declare_subscriber("imud/imu0/imu", zenoh.handlers.FifoChannel(100_000))
        tokens = [str(r.ok.key_expr) for r in s.liveliness().get("@ros2_lv/4/**") if r.ok]
        end = time.monotonic() + 40  # a bound for a broken daemon
        settled = 0
        while time.monotonic() < end and settled < 2:
            got = False
            while (x := sub.try_recv()) is not None:
                got = True
                att = x.attachment
                assert att is not None and len(att.to_bytes()) == 33
                msg = store.deserialize_cdr(x.payload.to_bytes(), diag.TYPE_NAME)
                reports.append(msg)
                (st0,) = msg.status
                values = dict((kv.key, kv.value) for kv in st0.values)
                # two reports in a row, after a loss, with the device running and nothing lost
                lost_total = int(values["lost samples"])
                quiet = values["lost_since_last_report"] == "0" and values["state"] == "running"
                settled = settled + 1 if lost_total and quiet else 0
            while (x := nat.try_recv()) is not None:
                got = True
                native.append(x.payload.to_bytes())
            if not got:
                time.sleep(0.01)
    assert any("/MP/%/%/imud/%diagnostics/diagnostic_msgs::msg::dds_::DiagnosticArray_/" in t
               for t in tokens), tokens  # fmt: skip
    assert settled == 2, [(r.status[0].level, r.status[0].message) for r in reports]
    statuses = [r.status[0] for r in reports]
    assert {s.name for s in statuses} == {"imud: imu0"}
    assert statuses[0].level == Level.OK
    levels = [s.level for s in statuses]
    assert Level.WARN in levels or Level.ERROR in levels  # the outage was reported
    lost_each = [int(dict((kv.key, kv.value) for kv in s.values)["lost_since_last_report"])
                 for s in statuses]  # fmt: skip
    for s, n in zip(statuses, lost_each, strict=True):
        if s.level == Level.OK:
            assert n == 0, s
        if s.level == Level.WARN:  # a running device that lost samples (its file is fine)
            assert n > 0 and s.message == f"{n} samples lost in the last 1 s", s
    last = dict((kv.key, kv.value) for kv in statuses[-1].values)
    # the native stream: every gap it marked, from its own sequence numbers
    batches = [decode(p) for p in native]
    seq = np.concatenate([b.seq for b in batches])
    gaps = int(np.sum(np.diff(seq) - 1))
    assert int(last["lost samples"]) == gaps > 0
    assert sum(lost_each[1:]) <= gaps  # reported as they happened
    stamps = [r.header.stamp.sec * 10**9 + r.header.stamp.nanosec for r in reports]
    assert all(b > a for a, b in itertools.pairwise(stamps))
