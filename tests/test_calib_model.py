"""The calibration model as the pipeline applies it, and the file as procedures write it.

corrected = C @ (raw - b - p(T)), p(T) = sum_k c_k (T - T_ref)^k, T clamped to the fitted span.
Expected values are worked by hand in each test.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from imud.calib.estimate import AffineEstimate, Fit, TempEstimate, Verdict
from imud.calib.file import (
    CalibrationFile,
    load_calibration,
    load_or_new,
    parse_calibration,
    to_toml,
    with_affine,
    with_temperature,
    write_calibration,
)
from imud.calib.model import CalibrationModel, SensorModel, TempPoly, apply, fill_temperature
from imud.channels import Channel

I3 = np.eye(3)


def gyro_model(
    coeffs: list[list[float]], span: tuple[float, float] = (10.0, 50.0)
) -> CalibrationModel:
    temp = TempPoly(30.0, np.array(coeffs), span)
    return CalibrationModel(Path("x.toml"), gyro=SensorModel(np.array([0.1, 0.0, 0.0]), I3, temp))


def test_temperature_polynomial_subtracted_and_clamped_at_the_span() -> None:
    # p(T) = 0.01 (T-30) + 0.001 (T-30)^2 on x; bias 0.1 on x
    cal = gyro_model([[0.01, 0.0, 0.0], [0.001, 0.0, 0.0]])
    temp = np.array([30.0, 40.0, 20.0, 60.0, 0.0])
    gyro = np.ones((5, 3))
    out, clamped = apply(cal, {Channel.GYRO: gyro}, temp, 0.001)
    # p: T=30 -> 0; 40 -> 0.1 + 0.1 = 0.2; 20 -> -0.1 + 0.1 = 0; 60 (clamped to 50) -> 0.2 + 0.4
    # = 0.6; 0 (clamped to 10) -> -0.2 + 0.4 = 0.2
    want_x = 1.0 - 0.1 - np.array([0.0, 0.2, 0.0, 0.6, 0.2])
    np.testing.assert_allclose(out[Channel.GYRO][:, 0], want_x, atol=1e-12)
    np.testing.assert_allclose(out[Channel.GYRO][:, 1:], 1.0)
    assert clamped is not None and clamped.tolist() == [False, False, False, True, True]


def test_edges_of_the_span_are_inside_it() -> None:
    cal = gyro_model([[0.01, 0.0, 0.0]])
    _, clamped = apply(cal, {Channel.GYRO: np.zeros((2, 3))}, np.array([10.0, 50.0]), 0.001)
    assert clamped is None


def test_unknown_temperature_flags_every_sample_and_leaves_the_term_out() -> None:
    cal = gyro_model([[0.01, 0.0, 0.0]])
    out, clamped = apply(cal, {Channel.GYRO: np.ones((3, 3))}, None, 0.001)
    np.testing.assert_allclose(out[Channel.GYRO][:, 0], 0.9)  # bias only
    assert clamped is not None and clamped.all()


def test_delta_channels_get_the_offsets_scaled_by_the_period() -> None:
    # a gyro bias of 0.5 rad/s over a 2 ms sample is 1 mrad of delta angle; matrix doubles z
    m = np.diag([1.0, 1.0, 2.0])
    cal = CalibrationModel(Path("x"), gyro=SensorModel(np.array([0.0, 0.0, 0.5]), m))
    delta = np.array([[0.0, 0.0, 0.003]])
    out, _ = apply(
        cal, {Channel.DELTA_ANGLE: delta, Channel.GYRO: np.array([[0, 0, 1.5]])}, None, 0.002
    )
    np.testing.assert_allclose(out[Channel.DELTA_ANGLE], [[0.0, 0.0, 2 * (0.003 - 0.001)]])
    np.testing.assert_allclose(out[Channel.GYRO], [[0.0, 0.0, 2.0]])


def test_magnetometer_hard_and_soft_iron() -> None:
    soft = np.array([[1.0, 0.1, 0.0], [0.1, 1.0, 0.0], [0.0, 0.0, 0.5]])
    cal = CalibrationModel(Path("x"), mag=SensorModel(np.array([1e-5, 0.0, 0.0]), soft))
    out, _ = apply(cal, {Channel.MAG: np.array([[3e-5, 2e-5, 4e-5]])}, None, 0.01)
    # m - h = (2, 2, 4) e-5; soft @ that = (2 + 0.2, 0.2 + 2, 2) e-5
    np.testing.assert_allclose(out[Channel.MAG], [[2.2e-5, 2.2e-5, 2e-5]], rtol=1e-12)


def test_temperature_nan_takes_the_last_valid_value_across_batches() -> None:
    t, last = fill_temperature(np.array([np.nan, 31.0, np.nan, 32.0, np.nan]), 5, 30.0)
    assert t is not None and t.tolist() == [30.0, 31.0, 31.0, 32.0, 32.0] and last == 32.0
    t, last = fill_temperature(np.array([np.nan, np.nan]), 2, 32.0)
    assert t is not None and t.tolist() == [32.0, 32.0] and last == 32.0
    t, last = fill_temperature(np.array([np.nan]), 1, None)
    assert t is None and last is None  # nothing known yet
    t, last = fill_temperature(np.array([np.nan, 33.0]), 2, None)
    assert t is not None and math.isnan(t[0]) and t[1] == 33.0 and last == 33.0


def test_a_sample_with_no_known_temperature_is_flagged_not_nan() -> None:
    cal = gyro_model([[0.01, 0.0, 0.0]])
    out, clamped = apply(cal, {Channel.GYRO: np.ones((2, 3))}, np.array([np.nan, 40.0]), 0.001)
    np.testing.assert_allclose(out[Channel.GYRO][:, 0], [0.9, 0.9 - 0.1])
    assert clamped is not None and clamped.tolist() == [True, False]
    t, last = fill_temperature(None, 3, None)
    assert t is None and last is None


# --- the file as procedures write it --------------------------------------------------------------


def _affine(sensor: str = "accel") -> AffineEstimate:
    names = ("bx", "by", "bz")
    cov = np.diag([1e-8, 2e-8, 3e-8]) + 1e-9
    fit = Fit(names, np.array([0.1, -0.2, 0.3]), cov, {"rms": 0.001, "chi2": 5.5, "dof": 3.0})
    return AffineEstimate(
        sensor,  # type: ignore[arg-type]
        "accel-9",
        np.array([0.1, -0.2, 0.3]),
        np.array([[1.01, 0.002, -0.003], [0.0, 0.99, 0.001], [0.0, 0.0, 1.0 / 3.0]]),
        fit,
        Verdict(True, ("a note",)),
        temperature_c=40.0,
        gravity=9.80123456789,
    )


def test_round_trip_is_bit_exact(tmp_path: Path) -> None:
    cf = with_affine(CalibrationFile(chip="mpu6050", device="imu0"), _affine(), "rec.csv")
    p = tmp_path / "cal.toml"
    write_calibration(p, cf)
    back = parse_calibration(tomllib.loads(p.read_text()))
    assert back.accel is not None and back.accel.matrix is not None
    assert back.accel.matrix[2][2] == 1.0 / 3.0  # repr round-trips a float exactly
    assert back.accel.gravity == 9.80123456789 and back.accel.temperature_c == 40.0
    assert back.accel.fit is not None and back.accel.fit.covariance[0][0] == 1e-8 + 1e-9
    assert back.accel.residuals["chi2"] == 5.5 and back.accel.notes == ["a note"]
    assert back.chip == "mpu6050" and back.device == "imu0" and back.written
    model = load_calibration(p, "mpu6050", Channel.ACCEL | Channel.GYRO)
    assert model.accel is not None and model.accel.bias.tolist() == [0.1, -0.2, 0.3]
    assert "# accelerometer" in p.read_text()  # the file explains itself


def test_temperature_added_later_moves_the_bias_to_the_reference(tmp_path: Path) -> None:
    # accel calibrated at 40 C without compensation: bias 0.1 on x. A temperature fit then says
    # x drifts 0.002 m/s^2 per C around 30 C. At 40 C the output must not change:
    # new bias = 0.1 - 0.002 * (40 - 30) = 0.08
    cf = with_affine(CalibrationFile(chip="mpu6050"), _affine(), "rec.csv")
    coeffs = np.array([[0.002, 0.0, 0.0]])
    fit = Fit(("c1x", "c1y", "c1z"), coeffs[0], np.eye(3) * 1e-10, {"rms": 0.001})
    est = TempEstimate("accel", 30.0, coeffs, (10.0, 50.0), fit, Verdict(True))
    cf2 = with_temperature(cf, est, "ramp.csv")
    assert cf2.accel is not None and cf2.accel.temperature is not None
    assert cf2.accel.bias[0] == pytest.approx(0.08, abs=1e-15)
    assert cf2.accel.matrix == cf.accel.matrix  # type: ignore[union-attr]
    m1 = load_calibration(_write(tmp_path / "a.toml", cf))
    m2 = load_calibration(_write(tmp_path / "b.toml", cf2))
    raw = {Channel.ACCEL: np.array([[1.0, 2.0, 9.0]])}
    before, _ = apply(m1, raw, np.array([40.0]), 0.001)
    after, _ = apply(m2, raw, np.array([40.0]), 0.001)
    np.testing.assert_allclose(after[Channel.ACCEL], before[Channel.ACCEL], atol=1e-12)


def _write(p: Path, cf: CalibrationFile) -> Path:
    write_calibration(p, cf)
    return p


def test_updating_keeps_the_other_sensors_and_refuses_another_chip(tmp_path: Path) -> None:
    p = tmp_path / "cal.toml"
    write_calibration(p, with_affine(CalibrationFile(chip="mpu6050"), _affine(), "a.csv"))
    cf = load_or_new(p, "mpu6050", "imu0")
    gyro = _affine("gyro")
    cf = with_affine(cf, gyro, "g.csv")
    assert cf.accel is not None and cf.gyro is not None
    with pytest.raises(ValueError, match="holds a calibration for a mpu6050, not a bmi088"):
        load_or_new(p, "bmi088", "imu0")
    assert load_or_new(tmp_path / "new.toml", "bmi088", "b0").accel is None


def test_text_is_toml_a_person_can_read() -> None:
    text = to_toml(with_affine(CalibrationFile(chip="mpu6050"), _affine(), "a.csv"))
    assert "[accel]" in text and "[accel.fit]" in text and "[accel.residuals]" in text
    assert 'procedure = "accel-9"' in text
    tomllib.loads(text)
