"""The white noise a calibration measures in its still data (imud/calib/noise.py), which the
ROS 2 covariances use in place of a datasheet's figure.

Checked on a process built here with a known density (white noise through a first-order filter,
plus a slow random walk that a still pose's mean would count as noise), and on real hardware data
(imu_tk's Xsens recording, its first 50 s still) against allantools' overlapping Allan deviation:
for white noise of one-sided density D, sigma_A(tau)^2 = D^2 / (2 tau)."""

from __future__ import annotations

import gzip
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from imud.calib.file import (
    CalibrationError,
    CalibrationFile,
    parse_calibration,
    read_calibration,
    write_calibration,
)
from imud.calib.noise import measured_density
from imud.calib.procedure import run_gyro
from imud.calib.recording import Recording
from imud.calib.still import interval_stats

DATA = Path(__file__).parent / "data" / "xsens" / "xsens_imu_tk.csv.gz"
# imu_tk's own calibration of this recording (tests/data/xsens/README.md): counts per unit
ACC_COUNTS = np.array([414.459, 412.010, 414.649])  # per m/s^2
GYR_COUNTS = np.array([4777.96, 4764.21, 4773.66])  # per rad/s


def xsens() -> Recording:
    """The recording's first 50 s, which it holds still (tests/data/xsens/README.md)."""
    with gzip.open(DATA, "rt") as f:
        rows = np.loadtxt(f, delimiter=",", skiprows=1)
    rows = rows[rows[:, 0] <= rows[0, 0] + 50.0]
    t_ns = np.round(rows[:, 0] * 1e9).astype(np.int64)
    accel = (rows[:, 1:4] - 32768.0) / ACC_COUNTS
    gyro = (rows[:, 4:7] - 32768.0) / GYR_COUNTS
    return Recording(t_ns, accel, gyro, source=DATA.name)


def synthetic(density: np.ndarray, seconds: float, rate: float, walk: float) -> Recording:
    """White noise of one-sided density `density` (per axis; per-sample sigma D sqrt(rate/2))
    through a first-order low-pass at 20 Hz (unit DC gain: the density below it is kept), plus a
    random walk of `walk` units per sqrt(second)."""
    rng = np.random.default_rng(7)
    n = int(seconds * rate)
    white = rng.standard_normal((n, 3)) * density * math.sqrt(rate / 2.0)
    a = math.exp(-2.0 * math.pi * 20.0 / rate)
    out = np.empty_like(white)
    y = np.zeros(3)
    for i in range(n):  # a test's reference filter, written as its difference equation
        y = a * y + (1.0 - a) * white[i]
        out[i] = y
    out += np.cumsum(rng.standard_normal((n, 3)), axis=0) * walk / math.sqrt(rate)
    t_ns = (np.arange(n) * (1e9 / rate)).astype(np.int64)
    return Recording(t_ns, out + np.array([0.0, 0.0, 9.81]), out.copy(), source="synthetic")


def test_the_density_of_filtered_white_noise_with_a_slow_wander() -> None:
    density = np.array([1e-3, 2e-3, 4e-3])
    rec = synthetic(density, seconds=60.0, rate=1000.0, walk=2e-3)
    whole = interval_stats(rec, 0, rec.n)
    got = measured_density(rec, [whole], "gyro")
    assert got is not None and got.tau_s == pytest.approx(0.1)
    # 599 differences: ~6 % on the variance, ~3 % on the density
    np.testing.assert_allclose(got.density, density, rtol=0.12)
    # the whole interval's mean is far noisier than white noise says: the wander
    from_mean = np.sqrt(2.0 * 60.0 * np.diag(whole.gyro_cov))
    assert np.all(from_mean > 1.5 * density)


def test_too_little_still_data_is_said_and_keeps_the_datasheet() -> None:
    rec = synthetic(np.array([1e-3] * 3), seconds=5.0, rate=200.0, walk=0.0)
    assert measured_density(rec, [interval_stats(rec, 0, rec.n)], "accel") is None
    out = run_gyro(rec, full_turns=False)
    assert out.report["noise"]["measured"] is False
    assert "s of still data, about 10 s needed" in out.report["noise"]["reason"]


@pytest.mark.extra  # allantools
def test_a_real_xsens_recording_agrees_with_allantools() -> None:
    allantools = pytest.importorskip("allantools")
    rec = xsens()
    assert rec.n == 5001 and rec.rate_hz == pytest.approx(100.0, rel=1e-3)
    out = run_gyro(rec, full_turns=False)
    noise = out.report["noise"]
    assert noise["measured"] and noise["tau_s"] == pytest.approx(0.1)
    accel = measured_density(rec, [interval_stats(rec, 0, rec.n)], "accel")
    assert accel is not None
    for got, x in ((np.array(noise["density"]), rec.gyro), (accel.density, rec.accel)):
        for axis in range(3):
            taus, adev, _, _ = allantools.oadev(
                x[:, axis], rate=100.0, data_type="freq", taus=np.array([0.1])
            )
            want = adev[0] * math.sqrt(2.0 * taus[0])
            assert got[axis] == pytest.approx(want, rel=0.08), (axis, got, want)


def test_the_file_carries_the_noise_and_reads_it_back(tmp_path: Path) -> None:
    rec = xsens()
    out = run_gyro(rec, full_turns=False)
    cf = out.update(CalibrationFile(chip="mpu6050", device="imu0"), DATA.name)
    path = tmp_path / "imu0.cal.toml"
    write_calibration(path, cf)
    back = read_calibration(path)
    assert back.gyro is not None and back.gyro.noise is not None
    assert list(back.gyro.noise.density) == out.report["noise"]["density"]
    text = path.read_text()
    assert "[gyro.noise]" in text and "tau_s = 0.1" in text
    # a later calibration without enough still data keeps the measured noise
    short = synthetic(np.array([1e-3] * 3), seconds=3.0, rate=200.0, walk=0.0)
    again = run_gyro(short, full_turns=False).update(back, "short")
    assert again.gyro is not None and again.gyro.noise == back.gyro.noise


def test_a_bad_noise_table_is_named() -> None:
    raw = tomllib.loads(
        "[gyro]\nbias = [0.0, 0.0, 0.0]\n"
        "[gyro.noise]\ndensity = [1e-3, -1e-3, 1e-3]\ntau_s = 0.1\ndifferences = 400\n"
        "still_s = 40.0\n"
    )
    with pytest.raises(CalibrationError, match=r"gyro\.noise.*every axis must be above zero"):
        parse_calibration(raw)
