"""The daemon streaming an ICM-42688-P at 32 kHz over simulated SPI in real time, with a real
Zenoh subscriber: at rate, continuous but for counted gaps, in SI units, 100 deg/s reads
1.745 rad/s.

At 32 kHz the FIFO lasts 4 ms, and how often a machine wakes the bus worker later than that
depends on the machine and its load (bench/rt_latency.py; docs/performance.md sections 3 and 5
give the loss rates measured). So this test asserts nothing that depends on the scheduler: it
asserts that every gap the subscriber sees is one the daemon counted, and what the samples say
about the chip and the motion, whatever was lost."""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np
import pytest

import imud.client as ic
from imud.channels import Channel
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
def test_32khz_sustained_with_every_gap_counted(tmp_path: Path) -> None:
    d = DaemonProc(tmp_path, CONFIG)
    try:
        d.wait_started()
        time.sleep(1.0)
        # keep the raw payloads and decode afterwards: on a 2-vCPU machine, decoding 1000
        # batches/s in this process would compete with the daemon under test
        raw = d.collect("imud/icm/imu", 4.0)
        batches = [ic.decode(x) for x in raw]
        st = d.status()["devices"][0]
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    seq = np.concatenate([b.seq for b in batches])
    t = np.concatenate([b.t_ns for b in batches])
    gyr = np.concatenate([b.channels[Channel.GYRO] for b in batches]).astype(np.float64)
    acc = np.concatenate([b.channels[Channel.ACCEL] for b in batches]).astype(np.float64)
    # every gap the subscriber sees is one the daemon counted, in the batch right after it
    expected_next = [b.first_seq + b.count for b in batches[:-1]]
    for prev_end, b in zip(expected_next, batches[1:], strict=True):
        assert b.first_seq - prev_end == b.lost_before, (prev_end, b.first_seq, b.lost_before)
    assert np.all(np.diff(t) > 0)
    # the chip's own rate, from its sample count over the stamps' span (a gap does not change it)
    rate = (seq[-1] - seq[0]) / ((t[-1] - t[0]) / 1e9)
    assert rate == pytest.approx(32000 * 1.006, rel=1e-3), d.log.read_text()[-4000:]
    assert st["state"] == "running" and st["chip_rate_hz"] == pytest.approx(32192, rel=1e-3)
    assert gyr[:, 2].mean() == pytest.approx(math.radians(100.0), abs=1e-3)  # 1.745 rad/s
    assert np.linalg.norm(acc, axis=1).mean() == pytest.approx(9.80665, abs=0.01)
    assert "worker: SCHED_FIFO" in d.log.read_text()
