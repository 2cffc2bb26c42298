"""Calibration files: corrected = T @ (raw - bias) per sensor, and the file's error messages."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from imud.calib.file import CalibrationError, load_calibration
from imud.calib.model import CalibrationModel, apply
from imud.channels import Channel

F64 = np.ndarray


def _apply(cal: CalibrationModel, accel: F64, gyro: F64) -> tuple[F64, F64]:
    out, clamped = apply(cal, {Channel.ACCEL: accel, Channel.GYRO: gyro}, None, 0.001)
    assert clamped is None
    return out[Channel.ACCEL], out[Channel.GYRO]


def write(tmp_path: Path, text: str, name: str = "cal.toml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


BIAS_SCALE = """
version = 1

[accel]
bias = [0.5, -0.25, 0.125]
scale = [2.0, 0.5, 1.25]

[gyro]
bias = [0.01, 0.02, -0.03]
scale = [1.0, 1.1, 0.9]
"""

# Not symmetric, so applying T where T transpose is due gives a different answer.
MATRIX = """
version = 1

[accel]
bias = [1.0, 2.0, 3.0]
matrix = [[1.0, 0.5, 0.0],
          [0.0, 2.0, 0.25],
          [0.1, 0.0, 1.0]]
"""


def test_bias_and_scale_applied(tmp_path: Path) -> None:
    cal = load_calibration(write(tmp_path, BIAS_SCALE))
    accel = np.array([[1.5, 0.75, 9.125], [0.5, -0.25, 0.125]])
    gyro = np.array([[0.11, -0.08, 0.07]])
    a, g = _apply(cal, accel, gyro)
    # accel: (1.5-0.5)*2, (0.75+0.25)*0.5, (9.125-0.125)*1.25; second row is exactly the bias
    np.testing.assert_allclose(a, [[2.0, 0.5, 11.25], [0.0, 0.0, 0.0]], atol=1e-12)
    # gyro: (0.11-0.01)*1, (-0.08-0.02)*1.1, (0.07+0.03)*0.9
    np.testing.assert_allclose(g, [[0.1, -0.11, 0.09]], atol=1e-12)


def test_full_matrix_applied_not_transposed(tmp_path: Path) -> None:
    cal = load_calibration(write(tmp_path, MATRIX))
    accel = np.array([[2.0, 4.0, 7.0], [1.0, 2.0, 3.0]])  # raw - bias = (1, 2, 4) and (0, 0, 0)
    gyro = np.array([[0.3, -0.2, 0.1]])
    a, g = _apply(cal, accel, gyro)
    # T @ (1, 2, 4) = (1*1 + 0.5*2 + 0*4, 0*1 + 2*2 + 0.25*4, 0.1*1 + 0*2 + 1*4)
    np.testing.assert_allclose(a, [[2.0, 5.0, 4.1], [0.0, 0.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(g, gyro, atol=0)  # no [gyro] table: identity, no bias


def test_invalid_samples_stay_nan_and_touch_nothing_else(tmp_path: Path) -> None:
    # A value the chip marked invalid reaches calibration as NaN (all three axes): it must stay
    # NaN, and the full matrix must not spread it to other samples or to the other sensor.
    cal = load_calibration(write(tmp_path, MATRIX))
    nan = float("nan")
    accel = np.array([[2.0, 4.0, 7.0], [nan, nan, nan], [1.0, 2.0, 3.0]])
    gyro = np.array([[0.3, -0.2, 0.1], [0.1, 0.2, 0.3], [nan, nan, nan]])
    a, g = _apply(cal, accel, gyro)
    assert np.isnan(a[1]).all() and np.isnan(g[2]).all()
    np.testing.assert_allclose(a[[0, 2]], [[2.0, 5.0, 4.1], [0.0, 0.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(g[:2], gyro[:2], atol=0)


def test_apply_is_pure(tmp_path: Path) -> None:
    cal = load_calibration(write(tmp_path, MATRIX))
    accel = np.array([[2.0, 4.0, 7.0]])
    gyro = np.array([[0.3, -0.2, 0.1]])
    a, g = _apply(cal, accel, gyro)
    assert accel.tolist() == [[2.0, 4.0, 7.0]] and gyro.tolist() == [[0.3, -0.2, 0.1]]
    assert not np.shares_memory(a, accel)  # a new array: the input is untouched
    assert g is gyro  # no [gyro] table: passed through as is


def test_bias_only_and_empty_file(tmp_path: Path) -> None:
    cal = load_calibration(write(tmp_path, "[gyro]\nbias = [0.5, 0.25, -1.0]\n"))
    a, g = _apply(cal, np.array([[1.0, 2.0, 3.0]]), np.array([[1.0, 1.0, 1.0]]))
    np.testing.assert_array_equal(a, [[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(g, [[0.5, 0.75, 2.0]])
    empty = load_calibration(write(tmp_path, "", "empty.toml"))
    a, g = _apply(empty, np.array([[1.0, 2.0, 3.0]]), np.array([[4.0, 5.0, 6.0]]))
    np.testing.assert_array_equal(a, [[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(g, [[4.0, 5.0, 6.0]])


def test_path_recorded(tmp_path: Path) -> None:
    p = write(tmp_path, BIAS_SCALE)
    assert load_calibration(p).path == p


def test_scale_and_matrix_together_rejected(tmp_path: Path) -> None:
    text = "[accel]\nscale = [1.0, 1.0, 1.0]\nmatrix = [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]\n"
    p = write(tmp_path, text)
    with pytest.raises(CalibrationError) as info:
        load_calibration(p)
    msg = str(info.value)
    assert str(p) in msg
    assert "accel" in msg
    assert "scale" in msg and "matrix" in msg


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("[accel]\nbais = [0.0, 0.0, 0.0]\n", "accel.bais"),
        ("[gyro]\nbias = [0.0, 0.0, 0.0]\noffset = 1.0\n", "gyro.offset"),
        ("[mag]\nbias = [0.0, 0.0, 0.0]\nhard_iron = [0.0, 0.0, 0.0]\n", "mag.hard_iron"),
    ],
)
def test_unknown_key_named(tmp_path: Path, text: str, key: str) -> None:
    p = write(tmp_path, text)
    with pytest.raises(CalibrationError) as info:
        load_calibration(p)
    assert str(p) in str(info.value)
    assert key in str(info.value)


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("[accel]\nbias = [1.0, 2.0]\n", "accel.bias"),
        ("[accel]\nmatrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]\n", "accel.matrix"),
        ('[gyro]\nscale = [1.0, "x", 1.0]\n', "gyro.scale"),
        ("version = 3\n", "version"),
        ('format = "imu_tk"\n', "format"),
    ],
)
def test_malformed_values_named(tmp_path: Path, text: str, where: str) -> None:
    with pytest.raises(CalibrationError, match=where.replace(".", r"\.")):
        load_calibration(write(tmp_path, text))


def test_toml_syntax_error(tmp_path: Path) -> None:
    p = write(tmp_path, "version = 1\n[accel]\nbias = = [0.0, 0.0, 0.0]\n")  # line 3
    with pytest.raises(CalibrationError) as info:
        load_calibration(p)
    msg = str(info.value)
    assert str(p) in msg
    assert "TOML syntax error" in msg
    assert "line 3" in msg


def test_missing_file(tmp_path: Path) -> None:
    p = tmp_path / "nope.toml"
    with pytest.raises(CalibrationError) as info:
        load_calibration(p)
    assert str(p) in str(info.value)
    assert "does not exist" in str(info.value)


def test_calibration_error_is_value_error() -> None:
    assert issubclass(CalibrationError, ValueError)


# --- what a loaded file must not contain ---------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("[accel]\nbias = [nan, 0.0, 0.0]\n", ["accel.bias", "finite"]),
        ("[gyro]\nmatrix = [[1.0, 0, 0], [0, inf, 0], [0, 0, 1.0]]\n", ["gyro.matrix", "finite"]),
        ("[accel]\nmatrix = [[1.0, 0, 0], [0, 1.0, 0], [1.0, 1.0, 0.0]]\n", ["singular"]),
        # scale 1 on x, 1e-4 on z: condition number 1e4
        ("[accel]\nscale = [1.0, 1.0, 1e-4]\n", ["ill-conditioned", "1e+04"]),
        ("[gyro]\nscale = [1.0, -1.0, 1.0]\n", ["negative determinant"]),
        (
            "[accel]\n[accel.fit]\nnames = ['a', 'b']\nvalues = [1.0, 2.0]\n"
            "covariance = [[1.0, 0.5], [0.0, 1.0]]\n",
            ["accel.fit", "not symmetric"],
        ),
        (
            "[accel]\n[accel.fit]\nnames = ['a', 'b']\nvalues = [1.0, 2.0]\n"
            "covariance = [[1.0, 2.0], [2.0, 1.0]]\n",  # eigenvalues 3 and -1
            ["positive semi-definite"],
        ),
        (
            "[accel]\n[accel.fit]\nnames = ['a']\nvalues = [1.0, 2.0]\ncovariance = [[1.0]]\n",
            ["2 entries for 1 names"],
        ),
        (
            "[gyro.temperature]\nreference_c = 30.0\nspan_c = [50.0, 10.0]\n"
            "coefficients = [[0.0, 0.0, 0.0]]\n",
            ["span_c", "low edge"],
        ),
        (
            "[gyro.temperature]\nreference_c = 30.0\nspan_c = [10.0, 50.0]\ncoefficients = [\n"
            + "[0.0, 0.0, 0.0],\n" * 4
            + "]\n",
            ["gyro.temperature.coefficients", "at most 3"],
        ),
    ],
)
def test_bad_contents_refused_with_the_key_named(
    tmp_path: Path, text: str, words: list[str]
) -> None:
    p = write(tmp_path, text)
    with pytest.raises(CalibrationError) as info:
        load_calibration(p)
    msg = str(info.value)
    assert str(p) in msg
    for w in words:
        assert w in msg, msg


def test_wrong_chip_and_missing_sensors_refused(tmp_path: Path) -> None:
    p = write(tmp_path, 'chip = "bmi088"\n[accel]\nbias = [0.0, 0.0, 0.0]\n')
    six_axis = Channel.ACCEL | Channel.GYRO | Channel.TEMPERATURE
    with pytest.raises(CalibrationError, match="made for a bmi088, this device is a mpu6050"):
        load_calibration(p, "mpu6050", six_axis)
    assert load_calibration(p, "bmi088", six_axis).accel is not None
    mag = write(tmp_path, "[mag]\nbias = [1e-6, 0.0, 0.0]\n", "mag.toml")
    with pytest.raises(CalibrationError, match=r"\[mag\]: a mpu6050 has no mag channel"):
        load_calibration(mag, "mpu6050", six_axis)
    temp = write(
        tmp_path,
        "[gyro.temperature]\nreference_c = 30.0\nspan_c = [10.0, 50.0]\n"
        "coefficients = [[1e-4, 0.0, 0.0]]\n",
        "temp.toml",
    )
    with pytest.raises(CalibrationError, match="reports no temperature"):
        load_calibration(temp, "toy", Channel.ACCEL | Channel.GYRO)


def test_a_covariance_symmetric_but_for_rounding_is_accepted_and_written_symmetric() -> None:
    from imud.calib.file import FitTable, _fit_table

    rng = np.random.default_rng(3)
    a = rng.standard_normal((6, 6)) * np.array([1e-3, 1e-5, 1e-7, 1.0, 1e-2, 1e-9])
    c = a @ a.T
    # a cross term zero but for rounding on one side (what an element-wise relative test
    # refused), and one off by rounding: both pass
    c[5, :5] = c[:5, 5] = 0.0  # parameter 5 independent of the rest (still PSD)
    c[0, 5] = 1e-14 * math.sqrt(c[0, 0] * c[5, 5])
    c[2, 4] *= 1 + 1e-9
    names = tuple(f"p{i}" for i in range(6))
    FitTable(names=list(names), values=[0.0] * 6, covariance=c.tolist())
    written = np.array(_fit_table(names, np.zeros(6), c).covariance)
    assert np.array_equal(written, written.T)
    c[1, 3] += 1e-3 * math.sqrt(c[1, 1] * c[3, 3])  # a real asymmetry: refused
    with pytest.raises(ValidationError, match="not symmetric"):
        FitTable(names=list(names), values=[0.0] * 6, covariance=c.tolist())
