"""`imud noise DEVICE --duration` against the real daemon on a simulated MPU6050 (loopback Zenoh,
no multicast scouting: the DaemonProc config listens on tcp/127.0.0.1:PORT and every command's
session connects there only).

What is asserted does not depend on how fast the machine is: the figures the daemon's own config
gives (the datasheet's densities), the white noise the simulator draws coming back within a
factor of two of the datasheet's Allan N (a convention or unit slip is a factor of 1.4, 57 or
31 off: 1/sqrt(2), deg/rad, sqrt(1 kHz)), a rate within the chip's oscillator tolerance plus the
stamp estimate's settling, and no more samples than the chip can have made in the window."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from imud.chips.mpu6050.noise import noise_figures
from tests.daemon_fixture import DaemonProc

ODR, DLPF, SECONDS = 1000, 188, 6.0
CONFIG = f"""
[[device]]
name = "still0"
chip = "mpu6050"
bus = {{ kind = "sim", bus = "simN", address = 0x68 }}
odr_hz = {ODR}
dlpf_hz = {DLPF}
[device.sim]
seed = 12
motion = {{ kind = "still" }}
"""

pytestmark = pytest.mark.slow  # a daemon's start and six seconds of capture


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProc]:
    d = DaemonProc(Path(tmp_path_factory.mktemp("noise-live")), CONFIG)
    d.wait_started()
    yield d
    code, _ = d.stop()
    assert code == 0, d.log.read_text()


def test_live_noise_of_a_simulated_mpu6050(daemon: DaemonProc) -> None:
    r = daemon.cli("noise", "still0", "--duration", f"{SECONDS:g}s", "--connect",
                   daemon.endpoint, "--json", timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    out = json.loads(r.stdout)
    assert out["source"] == "live still0" and out["device"] == "still0"
    assert out["chip"] == "mpu6050"
    # the MPU6050's sample clock is within 1.5 % (the simulator draws it so); the stamps'
    # estimate settles within a few per cent in the first seconds (docs/performance.md §10)
    assert 0.93 * ODR <= out["rate_hz"] <= 1.07 * ODR, out["rate_hz"]
    # no more than the chip made while subscribed (plus one FIFO read of 85 samples)
    assert 3 <= out["samples"] <= 1.07 * ODR * SECONDS + 85, out["samples"]
    assert out["stretches"] >= 1
    sheet = noise_figures(DLPF)
    imud = out["fit"]["imud"]
    # the datasheet's figures came from the daemon's own config
    assert imud["gyro"]["datasheet_one_sided_density"] == pytest.approx(sheet.gyro_density)
    assert imud["accel"]["datasheet_one_sided_density"] == pytest.approx(sheet.accel_density)
    # six seconds are too short for the fit to resolve N apart from B and K (it says so with
    # upper bounds): the curve itself is read on its white-noise line instead, where
    # adev(tau) sqrt(tau) = N, at taus 4-25x past the 188 Hz DLPF's flattening (the first
    # 20 ms, where the filtered noise is correlated) and at most 1/12 of the record
    tau = np.array(out["tau_s"])
    on_line = (tau >= 0.08) & (tau <= 0.5)
    assert on_line.sum() >= 3, tau
    for sensor, density in (("gyro", sheet.gyro_density), ("accel", sheet.accel_density)):
        n_sheet = density / math.sqrt(2.0)  # Allan N of a one-sided density (docs/noise.md)
        adev = np.array(out[f"{sensor}_adev_{'rad_s' if sensor == 'gyro' else 'm_s2'}"])
        n = adev[on_line] * np.sqrt(tau[on_line])[:, None]
        assert (n > 0.5 * n_sheet).all() and (n < 2.0 * n_sheet).all(), (sensor, n, n_sheet)
        for axis in "xyz":  # the fit's interval or bound leaves room for the datasheet's N
            assert out["fit"][sensor][axis]["N"]["hi95"] >= 0.5 * n_sheet


def test_live_noise_of_a_device_the_daemon_does_not_run(daemon: DaemonProc) -> None:
    r = daemon.cli("noise", "nosuch0", "--duration", "1s", "--connect", daemon.endpoint,
                   timeout=60)  # fmt: skip
    assert r.returncode != 0 and "nosuch0" in r.stderr and "Traceback" not in r.stderr, r.stderr
