"""The daemon streaming an ICM-42688-P at 32 kHz over simulated SPI in real time, with a real
Zenoh subscriber: every sample delivered, continuous, in SI units, 100 deg/s reads 1.745 rad/s."""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np
import pytest

import imud.client as ic
from tests.daemon_fixture import DaemonProc

CONFIG = """
[daemon]
realtime_priority = 20

[[device]]
name = "icm"
chip = "icm42688p"
bus = { kind = "sim", bus = "spi0", transport = "spi", cs = 0, speed_hz = 10000000 }
odr_hz = 32000
gyro_range_dps = 250
accel_range_g = 4
[device.sim]
seed = 11
clock_error = 0.006
motion = { kind = "tumble", rate_dps = [0.0, 0.0, 100.0] }
errors = { ideal = true }
"""

needs_rt = pytest.mark.skipif(
    os.geteuid() != 0, reason="SCHED_FIFO needs root here (CI runs as root)"
)


@needs_rt
def test_32khz_sustained_without_a_lost_sample(tmp_path: Path) -> None:
    d = DaemonProc(tmp_path, CONFIG)
    try:
        d.wait_started()
        time.sleep(1.0)
        batches: list[ic.Batch] = []
        with ic.open_session(d.endpoint) as s:
            end = time.monotonic() + 8.0
            for b in ic.batches(s, "icm", timeout=2.0):
                batches.append(b)
                if time.monotonic() > end:
                    break
        st = d.status()["devices"][0]
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    seq = np.concatenate([b.seq for b in batches])
    t = np.concatenate([b.t_ns for b in batches])
    gyr = np.concatenate([b.gyro for b in batches]).astype(np.float64)
    acc = np.concatenate([b.accel for b in batches]).astype(np.float64)
    assert np.all(np.diff(seq) == 1), f"gaps: {np.flatnonzero(np.diff(seq) != 1)[:5]}"
    assert np.all(np.diff(t) > 0)
    rate = (len(seq) - 1) / ((t[-1] - t[0]) / 1e9)
    assert rate == pytest.approx(32000 * 1.006, rel=1e-3)
    assert len(seq) > 7.5 * 32000
    assert st["lost_samples"] == 0 and st["fifo_overflows"] == 0, (st, d.log.read_text())
    assert st["state"] == "running" and st["chip_rate_hz"] == pytest.approx(32192, rel=1e-3)
    assert gyr[:, 2].mean() == pytest.approx(math.radians(100.0), abs=1e-3)  # 1.745 rad/s
    assert np.linalg.norm(acc, axis=1).mean() == pytest.approx(9.80665, abs=0.01)
    assert "worker: SCHED_FIFO" in d.log.read_text()
