"""ROS 2 messages across what restarts a stream: a bus process killed (the daemon starts another),
and a config edit that restarts the device with new settings. A ROS subscriber sees stamps that
never step back and, per publisher, attachment numbers that go up by one a message (rmw_zenoh
counts any other step as lost messages)."""

from __future__ import annotations

import os
import signal
import struct
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

import imud.client as ic
from tests.daemon_fixture import DaemonProc

pytestmark = pytest.mark.slow  # a bus process killed and a reload: ~10 s of real time

IMU_HASH = "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b"
KEY = f"0/imu0/imu/data_raw/sensor_msgs::msg::dds_::Imu_/{IMU_HASH}"


def body(odr: int) -> str:
    return f"""
[ros2]
enabled = true
domain_id = 0
rate_hz = 100
connect = []

[[device]]
name = "imu0"
chip = "mpu6050"
bus = {{ kind = "sim", bus = "simQ", address = 0x68 }}
odr_hz = {odr}
"""


def _stamp(cdr: bytes) -> int:
    sec, nanosec = struct.unpack_from("<iI", cdr, 4)
    return int(sec) * 10**9 + int(nanosec)


def test_stamps_never_step_back_and_numbers_go_on(tmp_path: Path) -> None:
    d = DaemonProc(tmp_path, body(500))
    got: list[tuple[int, int]] = []  # (stamp, attachment sequence number)
    try:
        d.wait_started()
        with ic.open_session(d.endpoint) as s:
            sub = s.declare_subscriber(KEY, zenoh.handlers.FifoChannel(100_000))

            def take(n: int) -> None:
                end = time.monotonic() + 30  # a bound for a broken daemon
                want = len(got) + n
                while len(got) < want and time.monotonic() < end:
                    m = sub.try_recv()
                    if m is None:
                        time.sleep(0.01)
                        continue
                    att = m.attachment
                    assert att is not None
                    (seq,) = struct.unpack_from("<q", att.to_bytes())
                    got.append((_stamp(m.payload.to_bytes()), seq))
                assert len(got) >= want, (len(got), want)

            take(100)
            pid = d.status()["buses"][0]["pid"]
            os.kill(pid, signal.SIGKILL)  # the bus process dies; the daemon starts another
            take(100)
            assert d.status()["buses"][0]["pid"] != pid
            d.config.write_text(d.config.read_text().replace("odr_hz = 500", "odr_hz = 200"))
            end = time.monotonic() + 30
            while d.status()["reloads"] < 1 and time.monotonic() < end:
                time.sleep(0.1)
            take(100)
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    stamps = np.array([g[0] for g in got])
    seqs = np.array([g[1] for g in got])
    assert np.all(np.diff(stamps) > 0)
    assert np.all(np.diff(seqs) == 1), np.flatnonzero(np.diff(seqs) != 1)
    # the stream went on at its new rate: 100 Hz out of 200 (k = 2) as out of 500 (k = 5)
    assert abs(np.median(np.diff(stamps[-50:])) - 10e6) < 0.05 * 10e6
