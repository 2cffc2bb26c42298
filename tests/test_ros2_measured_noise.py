"""A calibration file's measured noise ([gyro.noise], imud/calib/noise.py) in the ROS 2
messages' covariances, axis by axis, and a rewritten file taken up while the daemon runs.

A variance is proportional to the density squared whatever the filter model, so the expected
values are ratios: densities 1:2:4 give variances 1:4:16, and tripling every density multiplies
them by 9. The accelerometer, which the file says nothing of, keeps the datasheet's."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

import imud.client as ic
from imud.calib.file import CalibrationFile, NoiseTable, SensorTable, write_calibration
from tests.daemon_fixture import DaemonProc
from tests.test_ros2_daemon import IMU_HASH, parse_imu

KEY = f"5/imu0/imu/data_raw/sensor_msgs::msg::dds_::Imu_/{IMU_HASH}"


def calibration(path: Path, density: tuple[float, float, float]) -> None:
    noise = NoiseTable(density=density, tau_s=0.1, differences=500, still_s=50.0)
    write_calibration(path, CalibrationFile(chip="mpu6050", gyro=SensorTable(noise=noise)))


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[tuple[DaemonProc, Path]]:
    cal = tmp_path / "imu0.cal.toml"
    calibration(cal, (1e-3, 2e-3, 4e-3))
    d = DaemonProc(
        tmp_path,
        f"""
[ros2]
enabled = true
domain_id = 5

[[device]]
name = "imu0"
chip = "mpu6050"
bus = {{ kind = "sim", bus = "simN", address = 0x68 }}
odr_hz = 1000
calibration = "{cal}"
""",
    )
    d.wait_started()
    yield d, cal
    code, _ = d.stop()
    assert code == 0, d.log.read_text()


def covariances(sub: object, want: int) -> tuple[np.ndarray, np.ndarray]:
    """The gyro and accel covariance diagonals of the next `want` messages, (want, 3) each."""
    got = []
    end = time.monotonic() + 20
    while len(got) < want and time.monotonic() < end:
        s = sub.try_recv()  # type: ignore[attr-defined]
        if s is None:
            time.sleep(0.01)
            continue
        got.append(parse_imu(s.payload.to_bytes()))
    assert len(got) == want
    g = np.array([m["gyro_covariance"] for m in got])[:, [0, 4, 8]]
    a = np.array([m["accel_covariance"] for m in got])[:, [0, 4, 8]]
    return g, a


def test_measured_noise_sets_each_axis_and_a_new_file_is_taken_up(
    daemon: tuple[DaemonProc, Path],
) -> None:
    d, cal = daemon
    with ic.open_session(d.endpoint) as s:
        sub = s.declare_subscriber(KEY, zenoh.handlers.FifoChannel(100_000))
        g, a = covariances(sub, 20)
        assert np.all(g == g[0]) and np.all(a == a[0])
        gyro, accel = g[0], a[0]
        np.testing.assert_allclose(gyro / gyro[0], [1.0, 4.0, 16.0], rtol=1e-9)
        calibration(cal, (3e-3, 3e-3, 3e-3))
        end = time.monotonic() + 20
        while time.monotonic() < end:  # the file is looked at once a second
            g, _ = covariances(sub, 1)
            if not np.array_equal(g[0], gyro):
                break
        g, a = covariances(sub, 20)
    np.testing.assert_allclose(g, np.full((20, 3), 9.0 * gyro[0]), rtol=1e-9)
    np.testing.assert_array_equal(a, np.tile(accel, (20, 1)))
