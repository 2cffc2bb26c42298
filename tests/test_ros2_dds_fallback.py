"""A `dds` profile that cannot start (Cyclone DDS not installed, or its configuration refused)
is named in `imud status`, and the other profiles and the native stream run on."""

from __future__ import annotations

import importlib.util
import time
from pathlib import Path

import zenoh

import imud.client as ic
from tests.daemon_fixture import DaemonProc
from tests.test_ros2_daemon import IMU_HASH

CONFIG = """
[ros2]
enabled = true
profiles = ["rmw_zenoh", "dds"]
domain_id = 6

[[device]]
name = "imu0"
chip = "mpu6050"
bus = { kind = "sim", bus = "simF", address = 0x68 }
odr_hz = 1000
"""


def test_a_dds_profile_that_cannot_start_is_named_and_the_rest_runs(tmp_path: Path) -> None:
    installed = importlib.util.find_spec("cyclonedds") is not None
    # installed: a configuration Cyclone refuses (before it opens any socket)
    env = {"CYCLONEDDS_URI": "<NoSuchElement/>"} if installed else {}
    d = DaemonProc(tmp_path, CONFIG, env=env)
    try:
        d.wait_started()
        error = d.status()["ros2"]["error"]
        assert error is not None and error.startswith("dds: "), error
        if installed:
            assert "did not start on domain 6" in error and "CYCLONEDDS_URI" in error, error
        else:
            assert "pip install 'imud[dds]'" in error, error
        key = f"6/imu0/imu/data_raw/sensor_msgs::msg::dds_::Imu_/{IMU_HASH}"
        with ic.open_session(d.endpoint) as s:
            ros = s.declare_subscriber(key, zenoh.handlers.FifoChannel(1000))
            native = s.declare_subscriber("imud/imu0/imu", zenoh.handlers.FifoChannel(1000))
            end = time.monotonic() + 20
            got_ros = got_native = 0
            while (got_ros < 10 or got_native < 3) and time.monotonic() < end:
                got_ros += ros.try_recv() is not None
                got_native += native.try_recv() is not None
                time.sleep(0.002)
        assert got_ros >= 10 and got_native >= 3
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
