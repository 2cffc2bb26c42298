"""A calibration applied by the device runner, at virtual time: exact, and swapped without a gap.

The simulated MPU6050 has known errors, m = S (x + b); the file that undoes them is written in the
test from those numbers (corrected = S^-1 (m - S b)), so what comes out must be the truth.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pytest

from imud.calib.file import CalibrationFile, SensorTable, TempTable, load_calibration
from imud.calib.file import write_calibration as write
from imud.calib.watch import CalibrationWatcher
from imud.channels import Channel, SampleFlag
from imud.wire import FLAG_CALIBRATED, decode
from tests.helpers import concat, make_rig, match_truth

G = 9.80665
MG = 1e-3 * G
ACCEL_BIAS_MG = (40.0, -30.0, 20.0)
ACCEL_SCALE_ERR = (0.02, -0.01, 0.015)
GYRO_BIAS_DPS = (1.5, -2.0, 0.5)
SIM = {
    "seed": 3,
    "motion": {"kind": "still", "roll_deg": 30.0},
    "errors": {
        "ideal": True,
        "accel_noise_ug_rthz": 0.0,
        "gyro_noise_dps_rthz": 0.0,
        "accel_bias_mg": list(ACCEL_BIAS_MG),
        "gyro_bias_dps": list(GYRO_BIAS_DPS),
        "accel_scale_error": list(ACCEL_SCALE_ERR),
    },
}
DEVICE = {"odr_hz": 200, "dlpf_hz": 42}
SIX_AXIS = Channel.ACCEL | Channel.GYRO | Channel.TEMPERATURE


def correcting_file() -> CalibrationFile:
    s = [1 + e for e in ACCEL_SCALE_ERR]
    accel = SensorTable(
        bias=tuple(b * MG * k for b, k in zip(ACCEL_BIAS_MG, s, strict=True)),  # type: ignore[arg-type]
        scale=tuple(1 / k for k in s),  # type: ignore[arg-type]
    )
    gyro = SensorTable(bias=tuple(math.radians(v) for v in GYRO_BIAS_DPS))  # type: ignore[arg-type]
    return CalibrationFile(chip="mpu6050", accel=accel, gyro=gyro)


def test_a_new_calibration_takes_effect_at_the_next_batch_with_no_seq_gap(tmp_path: Path) -> None:
    rig = make_rig(DEVICE, SIM)
    rig.run(1.0)
    n_before = len(rig.out)
    path = tmp_path / "cal.toml"
    write(path, correcting_file())
    rig.runner.set_calibration(load_calibration(path, "mpu6050", SIX_AXIS), None)
    rig.run(1.0)
    batches = rig.batches()
    before, after = batches[:n_before], batches[n_before:]
    assert before and after
    assert not any(b.flags & FLAG_CALIBRATED for b in before)
    assert all(b.flags & FLAG_CALIBRATED for b in after)
    # one unbroken stream: every batch starts where the previous ended, none lost
    seq = np.concatenate([b.seq for b in batches])
    np.testing.assert_array_equal(seq, np.arange(seq[0], seq[0] + len(seq)))
    assert all(b.lost_before == 0 for b in batches)
    # after the swap the output is the truth (no noise; the modelled errors only)
    meas = concat(after)
    truth = concat(rig.truth_batches())
    i = match_truth(meas, truth)
    np.testing.assert_allclose(meas["accel"], truth["accel"][i], atol=0.01)  # ~1 LSB at 2 g
    np.testing.assert_allclose(meas["gyro"], truth["gyro"][i], atol=2e-3)
    # before it, the biases are still there: accel x reads 40 mg high (times its 2 % scale)
    raw = concat(before)
    j = match_truth(raw, truth)
    err_x = float(np.mean(raw["accel"][:, 0] - truth["accel"][j, 0]))
    assert abs(err_x - 40 * MG * 1.02) < 0.02


def test_raw_stream_carries_the_uncorrected_samples_only_while_wanted(tmp_path: Path) -> None:
    rig = make_rig(DEVICE, SIM)
    raw_out: list[bytes] = []
    rig.runner.publish_raw = raw_out.append
    path = tmp_path / "cal.toml"
    write(path, correcting_file())
    rig.runner.set_calibration(load_calibration(path, "mpu6050", SIX_AXIS), None)
    rig.run(0.5)
    assert raw_out == []  # nobody asked: not even computed
    rig.runner.want_raw(True)
    n0 = len(rig.out)
    rig.run(0.5)
    rig.runner.want_raw(False)
    rig.run(0.3)
    raw = [decode(b) for b in raw_out]
    corrected = rig.batches()[n0 : n0 + len(raw)]
    assert raw and len(raw) == len(corrected)
    for r, c in zip(raw, corrected, strict=True):
        assert r.first_seq == c.first_seq and r.count == c.count  # the same samples...
        np.testing.assert_array_equal(r.t_ns, c.t_ns)
        assert not r.flags & FLAG_CALIBRATED and c.flags & FLAG_CALIBRATED
    # ...before correction: raw = S (x + b), so the corrected file applied to raw gives corrected
    s = np.array([1 + e for e in ACCEL_SCALE_ERR])
    bias = np.array(ACCEL_BIAS_MG) * MG * s
    ra = np.concatenate([r.accel for r in raw]).astype(np.float64)
    ca = np.concatenate([c.accel for c in corrected]).astype(np.float64)
    np.testing.assert_allclose((ra - bias) / s, ca, atol=1e-5)  # float32 on the wire
    assert len(raw_out) == len(raw)  # nothing after want_raw(False)
    assert rig.runner.status().raw_subscribed is False


def test_temperature_outside_the_span_is_flagged_and_counted(tmp_path: Path) -> None:
    # the simulated chip sits at 25 C; a polynomial fitted on 30..50 C must clamp and flag all
    cf = correcting_file()
    assert cf.gyro is not None
    temp = TempTable(reference_c=40.0, span_c=(30.0, 50.0), coefficients=[(1e-3, 0.0, 0.0)])
    cf = cf.model_copy(update={"gyro": cf.gyro.model_copy(update={"temperature": temp})})
    path = tmp_path / "cal.toml"
    write(path, cf)
    rig = make_rig(DEVICE, SIM)
    rig.runner.set_calibration(load_calibration(path, "mpu6050", SIX_AXIS), None)
    rig.run(0.5)
    meas = concat(rig.batches())
    flag = int(SampleFlag.TEMPERATURE_OUTSIDE_CALIBRATION)
    assert ((meas["flags"] & flag) != 0).all()
    assert rig.runner.status().calibration_outside_span == len(meas["seq"])
    # clamped at 30 C: the term is 1e-3 * (30 - 40) = -0.01 rad/s, so x reads 0.01 rad/s high
    truth = concat(rig.truth_batches())
    i = match_truth(meas, truth)
    assert abs(float(np.mean(meas["gyro"][:, 0] - truth["gyro"][i, 0])) - 0.01) < 2e-3


def test_the_watcher_loads_changes_and_reports_a_bad_file(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "cal.toml"
    rig = make_rig({**DEVICE, "calibration": str(path)}, SIM)
    w = CalibrationWatcher([rig.runner])
    caplog.set_level(logging.INFO, logger="imud.calibration")
    w.check()
    st = rig.runner.status().to_json()
    assert st["calibration"] is None and "does not exist" in st["calibration_error"]
    # not written yet: where every device starts, a warning; a refused file below: an error
    assert [r.levelno for r in caplog.records] == [logging.WARNING]
    write(path, correcting_file())
    w.check()
    st = rig.runner.status().to_json()
    assert st["calibration"] == str(path) and st["calibration_error"] is None
    path.write_text("[accel]\nmatrix = [[1.0, 0, 0], [0, 1.0, 0], [1.0, 1.0, 0.0]]\n")
    w.check()
    rig.run(0.3)
    st = rig.runner.status().to_json()
    assert st["calibration"] is None and "singular" in st["calibration_error"]
    assert caplog.records[-1].levelno == logging.ERROR
    assert not any(b.flags & FLAG_CALIBRATED for b in rig.batches())  # never garbage


def test_the_device_applies_the_gyros_g_sensitivity(tmp_path: Path) -> None:
    """A file whose gyro has g-sensitivity G: the device's corrected gyro is its raw gyro less
    the bias and G times the same sample's corrected accelerometer, sample by sample (the raw
    stream carries the samples before correction)."""
    k_ga = np.array([[0.0, 2e-3, 0.0], [-1e-3, 0.0, 3e-3], [1e-3, 0.0, -2e-3]])  # rad/s per m/s^2
    cf = correcting_file()
    assert cf.gyro is not None
    rows = tuple(tuple(float(x) for x in r) for r in k_ga)
    cf = cf.model_copy(update={"gyro": cf.gyro.model_copy(update={"g_sensitivity": rows})})
    path = tmp_path / "cal.toml"
    write(path, cf)
    rig = make_rig(DEVICE, SIM)
    rig.runner.publish_raw = (raw_out := []).append
    rig.runner.set_calibration(load_calibration(path, "mpu6050", SIX_AXIS), None)
    rig.run(0.3)
    rig.runner.want_raw(True)
    n0 = len(rig.out)
    rig.run(0.5)
    rig.runner.want_raw(False)
    raw = [decode(b) for b in raw_out]
    corrected = rig.batches()[n0 : n0 + len(raw)]
    assert raw and len(raw) == len(corrected)
    rg = np.concatenate([r.gyro for r in raw]).astype(np.float64)
    ca = np.concatenate([c.accel for c in corrected]).astype(np.float64)
    cg = np.concatenate([c.gyro for c in corrected]).astype(np.float64)
    bias = np.radians(GYRO_BIAS_DPS)
    np.testing.assert_allclose(cg, rg - bias - ca @ k_ga.T, atol=2e-6)  # float32 on the wire
    assert np.abs(ca @ k_ga.T).max() > 1e-2  # the term is there to see
