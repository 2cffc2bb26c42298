"""Gyro-bias tracking while still: learns the bias at rest, and keeps motion out of it.

Synthetic streams are made here from written physics: white noise of a stated density
(sigma = N sqrt(fs) per sample), gravity along +z rotated by the true motion, a constant bias.
The estimator is an exponential average of 1-s window means with gain k = 1 - exp(-W/tau), so at
steady state its standard deviation is sqrt(k / (2 - k)) * sigma / sqrt(m) per axis.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from rich.console import Console

from imud.calib.track import GyroBiasTracker, TrackState
from imud.channels import Channel
from imud.cli.status_view import status_view
from imud.config import parse_config
from imud.errors import ConfigError
from imud.pipeline import track
from imud.settings import GyroBiasTracking
from tests.helpers import concat, make_rig

G = 9.80665
FS = 200.0
ACCEL_ND = 400e-6 * G  # MPU6050: 400 ug/sqrt(Hz)
GYRO_ND = math.radians(0.005)  # MPU6050: 0.005 deg/s/sqrt(Hz)
SIGMA_A = ACCEL_ND * math.sqrt(FS)
SIGMA_G = GYRO_ND * math.sqrt(FS)
BIAS = np.array([0.010, -0.006, 0.003])  # rad/s, within the default 0.035 limit
SETTINGS = GyroBiasTracking(enabled=True, window_s=1.0, time_constant_s=10.0, confirm_s=10.0)


def rotation_x(angle: np.ndarray) -> np.ndarray:
    """Gravity's direction in the body frame while the body turns about x by `angle`."""
    return np.stack([np.zeros_like(angle), np.sin(angle), np.cos(angle)], axis=1)


def stream(
    seconds: float,
    seed: int,
    rate_x: float = 0.0,
    rate_z: float = 0.0,
    jitter: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """(gyro, accel) of a body turning at rate_x (a horizontal axis: gravity turns) and rate_z
    (the vertical: gravity does not), with `jitter` rad/s of white handling motion."""
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    t = np.arange(n) / FS
    gyro = BIAS + rng.normal(0.0, SIGMA_G, (n, 3))
    gyro[:, 0] += rate_x
    gyro[:, 2] += rate_z
    accel = G * rotation_x(rate_x * t) + rng.normal(0.0, SIGMA_A, (n, 3))
    if jitter:
        gyro += rng.normal(0.0, jitter, (n, 3))
        accel += rng.normal(0.0, jitter * G, (n, 3))  # the hand's tilt moves gravity too
    return gyro, accel


def feed(tr: GyroBiasTracker, gyro: np.ndarray, accel: np.ndarray, sizes: Any = None) -> None:
    i = 0
    rng = np.random.default_rng(0)
    while i < len(gyro):
        n = int(rng.integers(1, 90)) if sizes == "random" else int(FS) // 20
        tr.correct(gyro[i : i + n], accel[i : i + n], 1.0 / FS)
        i += n


def steady_sd(settings: GyroBiasTracking) -> float:
    k = 1.0 - math.exp(-settings.window_s / settings.time_constant_s)
    m = settings.window_s * FS
    return math.sqrt(k / (2.0 - k)) * SIGMA_G / math.sqrt(m)


def test_a_still_gyro_converges_to_its_bias_within_the_averages_own_noise() -> None:
    tr = GyroBiasTracker(SETTINGS)
    gyro, accel = stream(200.0, seed=1)
    feed(tr, gyro, accel)
    sd = steady_sd(SETTINGS)
    assert np.all(np.abs(tr.bias - BIAS) < 5 * sd), (tr.bias - BIAS) / sd
    assert tr.state == TrackState.STILL
    # p = 1e-4 tests: still windows are almost never refused; 10 windows learn, then 10 confirm
    assert tr.windows == 200
    assert tr.still_windows >= 0.97 * (200 - 10)
    assert tr.learned_windows == tr.still_windows - 10 or tr.learned_windows > 150


def test_the_output_is_corrected_by_the_bias_held_at_the_start_of_the_batch() -> None:
    tr = GyroBiasTracker(SETTINGS)
    gyro, accel = stream(120.0, seed=2)
    feed(tr, gyro, accel)
    held = tr.bias.copy()
    g, a = stream(1.0, seed=3)
    out = tr.correct(g, a, 1.0 / FS)
    np.testing.assert_array_equal(out, g - held)
    # and through the pipeline stage: delta angles lose bias * dt, the input is left untouched
    delta = g / FS
    chans = {Channel.GYRO: g, Channel.ACCEL: a, Channel.DELTA_ANGLE: delta}
    held = tr.bias.copy()
    out_chans = track(tr, chans, 1.0 / FS)
    np.testing.assert_allclose(out_chans[Channel.DELTA_ANGLE], delta - held / FS, atol=1e-15)
    np.testing.assert_array_equal(out_chans[Channel.GYRO], g - held)
    assert chans[Channel.GYRO] is g and chans[Channel.DELTA_ANGLE] is delta


def test_the_estimate_does_not_depend_on_how_samples_were_batched() -> None:
    gyro, accel = stream(60.0, seed=4)
    a, b = GyroBiasTracker(SETTINGS), GyroBiasTracker(SETTINGS)
    feed(a, gyro, accel)
    feed(b, gyro, accel, sizes="random")
    np.testing.assert_array_equal(a.bias, b.bias)
    assert (a.windows, a.still_windows, a.learned_windows) == (
        b.windows,
        b.still_windows,
        b.learned_windows,
    )


def test_a_bias_drifting_with_temperature_is_followed_with_the_averages_lag() -> None:
    # 0.002 deg/s per second (an MPU6050's 0.02 deg/s/degC at 0.1 degC/s): the gyro mean moves
    # between windows by far less than their noise, so every window stays still. An exponential
    # average of a ramp r lags it by r W (1 - k) / k; the learned window is `confirm` windows old
    # and its mean describes its middle: in all, r (W (1 - k) / k + confirm_s + W / 2) behind.
    r = math.radians(0.002)
    tr = GyroBiasTracker(SETTINGS)
    gyro, accel = stream(300.0, seed=12)
    gyro[:, 0] += r * np.arange(len(gyro)) / FS
    feed(tr, gyro, accel)
    k = 1.0 - math.exp(-SETTINGS.window_s / SETTINGS.time_constant_s)
    lag_s = SETTINGS.window_s * (1 - k) / k + SETTINGS.confirm_s + SETTINGS.window_s / 2
    expected = BIAS[0] + r * (300.0 - lag_s)
    assert abs(tr.bias[0] - expected) < 5 * steady_sd(SETTINGS)
    assert tr.state == TrackState.STILL


def test_a_slow_turn_about_a_horizontal_axis_is_never_learned() -> None:
    # 0.05 deg/s adds no variance a window can see, but gravity turns g * rate * t: against the
    # still run's mean the accel change passes 4.6 standard errors within ~4 s, before the 10 s
    # of confirmation a window needs
    rate = math.radians(0.05)
    tr = GyroBiasTracker(SETTINGS)
    gyro, accel = stream(200.0, seed=5, rate_x=rate)
    feed(tr, gyro, accel)
    assert tr.learned_windows == 0
    np.testing.assert_array_equal(tr.bias, 0.0)


def test_a_steady_turn_about_the_vertical_beyond_the_limit_is_refused() -> None:
    tr = GyroBiasTracker(SETTINGS)
    gyro, accel = stream(60.0, seed=6, rate_z=0.1)  # 5.7 deg/s: gravity does not move
    feed(tr, gyro, accel)
    assert tr.state == TrackState.BEYOND_LIMIT
    assert tr.learned_windows == 0
    np.testing.assert_array_equal(tr.bias, 0.0)


def test_a_steady_turn_about_the_vertical_below_the_limit_is_learned_as_bias() -> None:
    # the documented limit of any stillness detector without a magnetometer: nothing in gyro
    # variance or gravity tells a 0.5 deg/s turn about the vertical from a bias
    rate = math.radians(0.5)
    tr = GyroBiasTracker(SETTINGS)
    gyro, accel = stream(200.0, seed=7, rate_z=rate)
    feed(tr, gyro, accel)
    assert abs(tr.bias[2] - (BIAS[2] + rate)) < 5 * steady_sd(SETTINGS)


def test_handling_is_motion_and_teaches_nothing() -> None:
    tr = GyroBiasTracker(SETTINGS)
    still_g, still_a = stream(30.0, seed=8)
    feed(tr, still_g, still_a)
    learned = tr.learned_windows
    bias = tr.bias.copy()
    # a hand's jitter, 0.02 rad/s: the window variance is 0.02^2 / SIGMA_G^2 ~ 20x the floor
    g, a = stream(60.0, seed=9, jitter=0.02)
    feed(tr, g, a)
    assert tr.state == TrackState.MOVING
    assert tr.learned_windows == learned
    np.testing.assert_array_equal(tr.bias, bias)


def test_invalid_samples_end_the_run_and_are_not_averaged() -> None:
    tr = GyroBiasTracker(SETTINGS)
    g, a = stream(40.0, seed=10)
    feed(tr, g, a)
    g2, a2 = stream(1.0, seed=11)
    g2[50] = np.nan
    tr.correct(g2, a2, 1.0 / FS)
    assert tr.state == TrackState.NO_DATA
    assert np.isfinite(tr.bias).all()


def test_settings_are_validated_by_name() -> None:
    device = {"name": "a", "chip": "mpu6050", "bus": {"kind": "sim"}}
    with pytest.raises(ConfigError, match="window_s"):
        parse_config({"device": [{**device, "gyro_bias_tracking": {"window_s": 0}}]})
    with pytest.raises(ConfigError, match="enable"):
        parse_config({"device": [{**device, "gyro_bias_tracking": {"enable": True}}]})
    cfg = parse_config({"device": [device]})
    assert cfg.device[0].gyro_bias_tracking.enabled is False  # off by default


# --- in the device runner, against the simulated MPU6050 -------------------------------------
SIM_BIAS_DPS = (0.5, -0.3, 0.2)
TRACKED = {"enabled": True, "window_s": 0.5, "time_constant_s": 3.0, "confirm_s": 2.0}


def test_the_runner_tracks_a_simulated_still_mpu6050_and_reports_it() -> None:
    sim = {"seed": 4, "motion": {"kind": "still"}, "errors": {"gyro_bias_dps": list(SIM_BIAS_DPS)}}
    rig = make_rig({"odr_hz": 200, "dlpf_hz": 42, "gyro_bias_tracking": TRACKED}, sim)
    st = rig.runner.status().gyro_bias_tracking
    assert st["state"] == TrackState.LEARNING and st["windows"] == 0  # before anything ran
    rig.run(30.0)
    st = rig.runner.status().gyro_bias_tracking
    assert st["state"] == TrackState.STILL and st["learned_windows"] > 20
    want = np.radians(SIM_BIAS_DPS)
    # 0.02 deg/s: ~10x the average's noise at this DLPF, 1/10 of the smallest bias
    np.testing.assert_allclose(st["bias_rad_s"], want, atol=math.radians(0.02))
    # the published gyro of the last 5 s no longer carries the bias
    meas = concat(rig.batches())
    last = meas["gyro"][-1000:]
    assert np.all(np.abs(last.mean(axis=0)) < math.radians(0.02))
    # shown in `imud status`
    console = Console(width=200, record=True)
    st = rig.runner.status().to_json()
    for r in status_view({"devices": [st]}, "tcp/127.0.0.1:7450", console):
        console.print(r)
    text = console.export_text()
    assert "t0 gyro bias tracking: still" in text
    # a new calibration resets what was learned relative to the old one
    rig.runner.set_calibration(None, None)
    assert rig.runner.status().gyro_bias_tracking["bias_rad_s"] == [0.0, 0.0, 0.0]


def test_tracking_is_absent_from_status_when_off() -> None:
    rig = make_rig({"odr_hz": 200}, {"motion": {"kind": "still"}})
    rig.run(0.5)
    assert rig.runner.status().gyro_bias_tracking is None


def test_long_run_ratio_sees_the_filter_that_correlates_the_noise() -> None:
    """White noise: a window's mean scatters as variance / m (ratio 1). Behind an L-tap moving
    average (a chip's low-pass) the long-run variance is sigma^2 (sum h)^2 = sigma^2 while the
    sample variance is sigma^2 / L: the mean scatters L times more than variance / m predicts.
    Without this the tracker took the filtered noise of a still MPU6050 for motion."""
    from imud.calib.track import long_run_ratio

    rng = np.random.default_rng(1)
    white = rng.normal(0.0, 1.0, (400, 512, 3))
    assert np.median(long_run_ratio(white)) == pytest.approx(1.0, abs=0.1)
    taps = 6
    x = rng.normal(0.0, 1.0, (400, 512 + taps - 1, 3))
    c = np.cumsum(np.concatenate([np.zeros((400, 1, 3)), x], axis=1), axis=1)
    smoothed = (c[:, taps:] - c[:, :-taps]) / taps
    assert np.median(long_run_ratio(smoothed)) == pytest.approx(taps, rel=0.15)
