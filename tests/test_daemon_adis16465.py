"""The daemon streaming an ADIS16465 at 1000 Hz with its delta outputs over simulated SPI in real
time, with a real Zenoh subscriber: continuous but for counted gaps, at the chip's own rate, in
SI units, 100 deg/s about z reads 1.745 rad/s and each delta angle the rotation over its
sample interval, the oscillator's 2 % taken out.

The chip has no FIFO, so what a busy machine loses depends on the machine: this test asserts
that every gap the subscriber sees is one the daemon counted, never a loss rate."""

from __future__ import annotations

import itertools
import math
import time
from pathlib import Path

import numpy as np
import pytest

import imud.client as ic
from imud.channels import Channel, SampleFlag
from tests.daemon_fixture import DaemonProc
from tests.helpers import status_after

CONFIG = """
[[device]]
name = "adis"
chip = "adis16465"
bus = { kind = "sim", bus = "spi2", transport = "spi", cs = 0, speed_hz = 2000000 }
model = 2
odr_hz = 1000
[device.sim]
seed = 21
clock_error = 0.02
motion = { kind = "tumble", rate_dps = [0.0, 0.0, 100.0] }
errors = { ideal = true }
"""
G = 9.80665


def test_adis16465_streams_rates_and_deltas(tmp_path: Path) -> None:
    d = DaemonProc(tmp_path, CONFIG)
    try:
        d.wait_started()
        time.sleep(1.0)  # the driver's rate estimate gets its baseline
        batches = [ic.decode(x) for x in d.collect("imud/adis/imu", 3.0, depth=16384)]
        # the bus process reports status periodically: wait for its snapshot to count the
        # samples already received, or its counters lag the batches compared with them
        st = status_after(d, batches)
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    assert st["state"] == "running" and st["chip"] == "adis16465", st
    assert batches
    # every gap the subscriber sees is one the daemon counted, in the batch right after it
    for prev, b in itertools.pairwise(batches):
        assert b.first_seq - (prev.first_seq + prev.count) == b.lost_before
    seen_lost = sum(b.lost_before for b in batches[1:])
    assert st["lost_samples"] >= seen_lost
    assert st["chip_status"]["samples_skipped"] >= seen_lost  # counted from DATA_CNTR
    seq = np.concatenate([b.seq for b in batches])
    t = np.concatenate([b.t_ns for b in batches])
    assert np.all(np.diff(seq) >= 1) and np.all(np.diff(t) > 0)
    rate = (seq[-1] - seq[0]) / ((t[-1] - t[0]) / 1e9)  # the chip's clock, gaps or not
    assert rate == pytest.approx(1020.0, rel=1e-3)
    assert st["chip_rate_hz"] == pytest.approx(1020.0, rel=1e-3)
    assert st["chip_status"]["odr_estimate_hz"] == pytest.approx(1020.0, rel=1e-3)

    def cat(c: Channel) -> np.ndarray:
        return np.concatenate([b.channels[c] for b in batches]).astype(np.float64)

    assert set(batches[0].channels) == {Channel.ACCEL, Channel.GYRO, Channel.TEMPERATURE,
                                        Channel.DELTA_ANGLE, Channel.DELTA_VELOCITY}  # fmt: skip
    w = math.radians(100.0)
    assert cat(Channel.GYRO)[:, 2].mean() == pytest.approx(w, abs=1e-3)  # rad/s
    assert cat(Channel.ACCEL)[:, 2].mean() == pytest.approx(G, abs=0.01)  # m/s^2, z up
    assert cat(Channel.TEMPERATURE).mean() == pytest.approx(25.0, abs=0.2)  # degC
    # deltas: rad and m/s over 2 internal samples at 2040 Hz; NaN exactly where flagged
    da, dv = cat(Channel.DELTA_ANGLE), cat(Channel.DELTA_VELOCITY)
    flags = np.concatenate([b.sample_flags for b in batches])
    raced = (flags & SampleFlag.DELTA_ANGLE_INVALID) != 0
    assert np.array_equal(np.isnan(da).any(axis=1), raced)
    assert np.array_equal(np.isnan(dv).any(axis=1), raced)
    # enough valid deltas for the means (which reads race the chip's update is the scheduler's)
    assert np.count_nonzero(~raced) > 100
    assert da[~raced, 2].mean() == pytest.approx(w * 2 / 2040, rel=2e-3)
    assert dv[~raced, 2].mean() == pytest.approx(G * 2 / 2040, rel=2e-3)
