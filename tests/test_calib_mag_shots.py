"""Magnetometer shot lists (`imud calibrate mag --shots`): one reading a pose, no stream, so the
noise is what the residuals show; what the readings determine is judged from the fit's own
sigmas. Synthetic readings made here from a known hard and soft iron; a real one from the
QMC5883L session (tests/data/qmc5883l) taken as a shot list; the real CLI on a file holding
accelerometer and magnetometer readings together."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imud.calib.file import read_calibration
from imud.calib.mag import fit_mag
from imud.calib.recording import Recording
from tests.test_calib_real import QMC_TESLA, qmc

FIELD = 50e-6  # tesla
SOFT = np.array([[1.05, 0.02, 0.01], [0.02, 0.97, 0.03], [0.01, 0.03, 1.02]])  # symmetric
HARD = np.array([12e-6, -7e-6, 20e-6])


def directions(rng: np.random.Generator, n: int, cap_deg: float = 180.0) -> np.ndarray:
    """n unit vectors, uniform over the sphere or over a cap about +z."""
    z = rng.uniform(np.cos(np.radians(cap_deg)), 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    r = np.sqrt(1 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def shots(m: np.ndarray) -> Recording:
    n = m.shape[0]
    nan = np.full((n, 3), np.nan)
    return Recording(np.arange(n, dtype=np.int64), nan, nan, mag=m, source="shots.csv")


def readings(rng: np.random.Generator, d: np.ndarray, noise: float = 0.2e-6) -> np.ndarray:
    """What a magnetometer with SOFT and HARD reads for field directions d (its own frame)."""
    out: np.ndarray = (d * FIELD) @ SOFT.T + HARD + rng.standard_normal(d.shape) * noise
    return out


def test_the_hard_iron_of_a_shot_list_and_its_sigma() -> None:
    """Over 100 shot lists of 40 readings: the centre is the true one, and its reported sigma
    is the scatter it really has (mean z^2 near 1: neither over- nor under-confident)."""
    rng = np.random.default_rng(5)
    z2, refused = [], 0
    for _ in range(100):
        est = fit_mag(shots(readings(rng, directions(rng, 40))), shots=True).estimate
        refused += not est.verdict.accepted  # the outlier test's 1 % of clean lists
        sigma = np.sqrt(np.diag(est.fit.covariance)[:3])
        z2.extend(((est.bias - HARD) / sigma) ** 2)
    mean = float(np.mean(z2))
    assert 0.7 < mean < 1.35, mean  # 300 z^2: the mean's own sd is 0.08
    assert refused <= 5  # P(more than 5 of 100 at 1 %) < 1e-3


def test_readings_in_one_cap_of_directions_name_what_they_leave_open() -> None:
    """Within 60 deg of one direction: the fit runs, and its sigmas name what it leaves open
    and which directions to add; within 35 deg there is no ellipsoid to fit at all."""
    from imud.calib.still import CalibrationRefused

    rng = np.random.default_rng(6)
    est = fit_mag(shots(readings(rng, directions(rng, 40, cap_deg=60))), shots=True).estimate
    assert not est.verdict.accepted
    reason = est.verdict.reasons[0]
    assert "bias_z" in reason and "undetermined" in reason and "along -z" in reason, reason
    with pytest.raises(CalibrationRefused, match="rotate the device through all directions"):
        fit_mag(shots(readings(rng, directions(rng, 40, cap_deg=35))), shots=True)
    half = fit_mag(shots(readings(rng, directions(rng, 40, cap_deg=90))), shots=True).estimate
    assert half.verdict.accepted, half.verdict.reasons  # a hemisphere determines it here


def test_a_reading_off_the_ellipsoid_is_named() -> None:
    rng = np.random.default_rng(7)
    m = readings(rng, directions(rng, 40))
    m[22] *= 1.15  # a reading beside a motor
    est = fit_mag(shots(m), shots=True).estimate
    assert not est.verdict.accepted
    assert "reading 23 (line order)" in " ".join(est.verdict.reasons), est.verdict.reasons


def test_too_few_readings_are_refused_with_how_many_more() -> None:
    from imud.calib.still import CalibrationRefused

    rng = np.random.default_rng(8)
    with pytest.raises(CalibrationRefused, match=r"10 distinct .* at least 18 \(8 more\)"):
        fit_mag(shots(readings(rng, directions(rng, 10))), shots=True)


@pytest.mark.parametrize("k", [60, 120])
def test_a_real_session_read_as_a_shot_list(k: int) -> None:
    """The QMC5883L's filtered session, k readings spread over it: the centre lands on the
    authors' published one (their README: 6195.1, 252.1, 3477.5 counts) within three of its
    reported sigmas."""
    rec, _ = qmc("filtered")
    idx = np.linspace(0, rec.n - 1, k).round().astype(int)
    assert rec.mag is not None
    est = fit_mag(shots(rec.mag[idx]), shots=True).estimate
    assert est.verdict.accepted, est.verdict.reasons
    centre = est.bias / QMC_TESLA
    sigma = np.sqrt(np.diag(est.fit.covariance)[:3]) / QMC_TESLA
    off = centre - np.array([6195.1, 252.1, 3477.5])
    print(f"{k} shots: centre off by {np.round(off, 1)} counts, sigma {np.round(sigma, 1)}")
    assert np.all(np.abs(off) < 3 * sigma), (off, sigma)


def test_one_file_of_accel_and_mag_readings_calibrates_both(tmp_path: Path) -> None:
    """A shot list as a tool that logs a reading a button press writes it: accelerometer and
    magnetometer columns, no time, no gyro. `calibrate accel --shots` and `calibrate mag
    --shots` read the same file, each its own columns, into one calibration file."""
    rng = np.random.default_rng(9)
    n = 30
    up = directions(rng, n)  # gravity's direction in the sensor frame, pose by pose
    north = directions(rng, n)  # the field's, likewise (independent of gravity's here)
    accel = up * 9.80665 @ np.diag([1.01, 0.99, 1.0]).T + [0.05, -0.03, 0.08]
    accel += rng.standard_normal((n, 3)) * 2e-3
    mag_ut = readings(rng, north) * 1e6
    path = tmp_path / "shots.csv"
    rows = [",".join(f"{v:.6f}" for v in (*a, *m)) for a, m in zip(accel, mag_ut, strict=True)]
    path.write_text("ax,ay,az,mx,my,mz\n" + "\n".join(rows) + "\n")
    out = tmp_path / "cal.toml"
    for kind in ("accel", "mag"):
        r = subprocess.run(
            [sys.executable, "-m", "imud", "calibrate", kind, "--from", str(path), "--shots",
             "--mag-units", "uT", "--gravity", "9.80665", "--chip", "mpu6050", "--out", str(out)]
            if kind == "accel" else
            [sys.executable, "-m", "imud", "calibrate", kind, "--from", str(path), "--shots",
             "--mag-units", "uT", "--chip", "mpu6050", "--out", str(out)],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert r.returncode == 0, r.stdout + r.stderr
    cf = read_calibration(out)
    assert cf.accel is not None and cf.mag is not None
    assert np.allclose(cf.accel.bias, [0.05, -0.03, 0.08], atol=5e-3)
    assert np.allclose(cf.mag.bias, HARD, atol=0.3e-6)


def test_students_t_against_its_closed_forms() -> None:
    """One degree of freedom is Cauchy's, two have a closed form too; many tend to the normal."""
    import math

    from imud.calib.stats import t_sf_two_sided

    for t in (0.0, 0.3, 1.0, 2.5, 7.0, 40.0):
        assert t_sf_two_sided(t, 1) == pytest.approx(1 - 2 / math.pi * math.atan(t), rel=1e-12)
        assert t_sf_two_sided(t, 2) == pytest.approx(1 - t / math.sqrt(2 + t * t), rel=1e-10)
        assert t_sf_two_sided(t, 1e7) == pytest.approx(math.erfc(t / math.sqrt(2)), rel=1e-5)


@pytest.mark.extra
def test_students_t_against_scipy() -> None:
    st = pytest.importorskip("scipy.stats")
    from imud.calib.stats import t_sf_two_sided

    for t, dof in [(0.0, 5), (1.0, 1), (2.0, 5), (3.66, 30), (4.5, 8), (10.0, 2), (50.0, 100)]:
        assert t_sf_two_sided(t, dof) == pytest.approx(2 * st.t.sf(t, dof), rel=1e-9, abs=1e-300)
