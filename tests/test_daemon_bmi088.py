"""The daemon streaming a BMI088 (two dies on two chip selects of a simulated SPI bus) in real
time, with a real Zenoh subscriber: at the gyro die's rate, continuous, in SI units, a constant
100 deg/s about z reads 1.745 rad/s while gravity stays on z."""

from __future__ import annotations

import itertools
import math
import time
from pathlib import Path

import numpy as np
import pytest

import imud.client as ic
from tests.daemon_fixture import DaemonProc

CONFIG = """
[[device]]
name = "bmi"
chip = "bmi088"
bus = { kind = "sim", bus = "spi1", transport = "spi", cs = 0, speed_hz = 10000000 }
gyro_bus = { kind = "sim", bus = "spi1", transport = "spi", cs = 1, speed_hz = 10000000 }
gyro_range_dps = 250
odr_hz = 2000
accel_range_g = 6
accel_odr_hz = 1600
[device.sim]
seed = 12
clock_error = -0.007
motion = { kind = "tumble", rate_dps = [0.0, 0.0, 100.0] }
errors = { ideal = true }
"""


def test_bmi088_streams_both_dies_as_one_6_axis_stream(tmp_path: Path) -> None:
    d = DaemonProc(tmp_path, CONFIG)
    try:
        d.wait_started()
        time.sleep(0.5)
        batches = [ic.decode(x) for x in d.collect("imud/bmi/imu", 3.0, depth=16384)]
        st = d.status()["devices"][0]
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    seq = np.concatenate([b.seq for b in batches])
    t = np.concatenate([b.t_ns for b in batches])
    gyr = np.concatenate([b.gyro for b in batches]).astype(np.float64)
    acc = np.concatenate([b.accel for b in batches]).astype(np.float64)
    assert st["state"] == "running" and st["chip"] == "bmi088", st
    # whatever a busy machine costs, every gap the subscriber sees is one the daemon counted
    for prev, b in itertools.pairwise(batches):
        assert b.first_seq - (prev.first_seq + prev.count) == b.lost_before
    assert np.all(np.diff(seq) >= 1) and np.all(np.diff(t) > 0)
    rate = (seq[-1] - seq[0]) / ((t[-1] - t[0]) / 1e9)  # the gyro die's clock, gaps or not
    assert rate == pytest.approx(2000 * (1 - 0.007), rel=1e-3)
    assert st["chip_rate_hz"] == pytest.approx(1986, rel=1e-3)
    assert gyr[:, 2].mean() == pytest.approx(math.radians(100.0), abs=1e-3)  # 1.745 rad/s
    assert np.abs(gyr[:, :2].mean(axis=0)).max() < 1e-3
    # accel is NaN (flagged) only where accel frames were lost around a gyro sample
    assert np.nanmean(acc[:, 2]) == pytest.approx(9.80665, abs=0.01)  # m/s^2, REP-103 z up
    assert np.abs(np.nanmean(acc[:, :2], axis=0)).max() < 0.01
    assert 20.0 < st["temperature_c"] < 30.0
