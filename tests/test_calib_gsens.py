"""The gyro's g-sensitivity (imud/calib/gsens.py, imud/calib/model.py): found when the still
poses ask for it and only then, recovered within its uncertainty, refused in a table that is not
the gyro's, and applied by the pipeline's own function as corrected = C (raw - b - G a)."""

from __future__ import annotations

import numpy as np
import pytest

from imud.calib.file import CalibrationError, parse_calibration
from imud.calib.gsens import fit_g_sensitivity
from imud.calib.model import CalibrationModel, SensorModel, apply
from imud.channels import Channel

G = 9.81
NOISE = 2e-5  # rad/s, the standard error of a still pose's gyro mean
BIAS = np.array([0.01, -0.02, 0.005])
# a MEMS part's linear acceleration effect: up to 0.1 deg/s per g, not symmetric
K_GA = np.radians(np.array([[0.05, 0.08, -0.02], [-0.1, 0.03, 0.06], [0.04, -0.07, 0.02]])) / G


def poses(k_ga: np.ndarray, seed: int, n: int = 14) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    up = rng.standard_normal((n, 3))
    force = up / np.linalg.norm(up, axis=1, keepdims=True) * G
    means = BIAS + force @ k_ga.T + rng.standard_normal((n, 3)) * NOISE
    covs = np.tile(np.eye(3) * NOISE**2, (n, 1, 1))
    return means, covs, force


def test_a_known_g_sensitivity_is_found_and_recovered() -> None:
    gs = fit_g_sensitivity(*poses(K_GA, 1))
    assert gs is not None and gs.included and gs.p_value < 1e-12
    # 42 equations for 12 parameters: each G entry to ~NOISE / (G sqrt(n / 3)), well below 5 %
    np.testing.assert_allclose(gs.matrix, K_GA, atol=4 * NOISE / G)
    np.testing.assert_allclose(gs.bias, BIAS, atol=4 * NOISE)


def test_none_is_left_out_so_the_bias_keeps_its_precision() -> None:
    found = [fit_g_sensitivity(*poses(np.zeros((3, 3)), seed)) for seed in range(40)]
    assert all(gs is not None for gs in found)
    included = sum(gs.included for gs in found if gs is not None)
    assert included <= 3  # the test's own 1 % false-alarm rate, with room
    for gs in found:
        assert gs is not None
        if not gs.included:
            assert not gs.matrix.any()


def test_too_few_poses_or_one_direction_say_nothing() -> None:
    means, covs, force = poses(K_GA, 2, n=5)
    assert fit_g_sensitivity(means, covs, force) is None
    means, covs, _ = poses(K_GA, 3)
    flat = np.tile([0.0, 0.0, G], (means.shape[0], 1))  # every pose the same way up
    assert fit_g_sensitivity(means, covs, flat) is None


def test_the_pipeline_takes_g_a_out_of_the_gyro() -> None:
    c = np.array([[1.01, 0.002, 0.0], [0.0, 0.99, -0.003], [0.001, 0.0, 1.0]])
    model = CalibrationModel(
        path=None,  # type: ignore[arg-type]
        accel=SensorModel(np.array([0.1, 0.0, -0.2]), np.eye(3) * 1.02),
        gyro=SensorModel(BIAS, c, g_sensitivity=K_GA),
    )
    rng = np.random.default_rng(4)
    accel_raw = rng.standard_normal((5, 3)) * 5
    gyro_raw = rng.standard_normal((5, 3))
    out, _ = apply(model, {Channel.ACCEL: accel_raw, Channel.GYRO: gyro_raw}, None, 0.01)
    accel = (accel_raw - [0.1, 0.0, -0.2]) * 1.02
    want = np.array([c @ (w - BIAS - K_GA @ a) for w, a in zip(gyro_raw, accel, strict=True)])
    np.testing.assert_allclose(out[Channel.GYRO], want, rtol=1e-12)
    # a delta angle over dt takes the delta velocity over dt as its specific force
    dt = 0.004
    delta, _ = apply(
        model,
        {Channel.DELTA_VELOCITY: accel_raw * dt, Channel.DELTA_ANGLE: gyro_raw * dt},
        None,
        dt,
    )
    np.testing.assert_allclose(delta[Channel.DELTA_ANGLE], want * dt, rtol=1e-9, atol=1e-15)


def test_only_the_gyros_table_may_hold_it() -> None:
    row = [1e-4, 0.0, 0.0]
    ok = {"gyro": {"bias": [0.0] * 3, "g_sensitivity": [row, row, row]}}
    assert parse_calibration(ok).gyro is not None
    with pytest.raises(CalibrationError, match=r"\[accel\] g_sensitivity: only the gyro's"):
        parse_calibration({"accel": {"bias": [0.0] * 3, "g_sensitivity": [row, row, row]}})


def test_the_bias_carries_gs_uncertainty() -> None:
    """Poses all within 60 deg of up: the intercept is an extrapolation to zero specific force,
    far less certain than the poses' pooled mean; its covariance must say so (it is what the
    file writes as the bias's uncertainty)."""
    rng = np.random.default_rng(7)
    n = 14
    tilt = np.radians(rng.uniform(0, 60, n))
    az = rng.uniform(0, 2 * np.pi, n)
    up = np.column_stack([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
    force = up * G
    means = BIAS + force @ K_GA.T + rng.standard_normal((n, 3)) * NOISE
    covs = np.tile(np.eye(3) * NOISE**2, (n, 1, 1))
    gs = fit_g_sensitivity(means, covs, force)
    assert gs is not None and gs.included
    pooled = NOISE / np.sqrt(n)
    # the intercept's sigma from the design alone: at least twice the pooled mean's here
    assert np.all(np.sqrt(np.diag(gs.bias_cov)) > 2 * pooled)
    assert np.all(np.abs(gs.bias - BIAS) < 4 * np.sqrt(np.diag(gs.bias_cov)))
