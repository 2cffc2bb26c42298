"""Gyro calibration against sessions synthesised here (tests/test_calib_still.py `session`):
raw gyro = A_g w + b_g + white noise of density N, so the calibration is C = A_g^-1, b = b_g;
the accelerometer gives gravity's direction in each still pose."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from imud.calib.accel import fit_accel
from imud.calib.estimate import AffineEstimate
from imud.calib.gyro import (
    EARTH_RATE_RAD_S,
    cumulative_product,
    fit_gyro_bias,
    fit_gyro_full,
)
from imud.calib.recording import Recording
from imud.calib.still import CalibrationRefused, find_still
from tests.test_calib_still import (
    TWELVE,
    Session,
    X,
    Y,
    Z,
    rotation,
    session,
    still_recording,
    with_bump,
)

F64 = npt.NDArray[np.float64]
N = 8.7e-5  # rad/s/sqrt(Hz): 0.005 deg/s/sqrt(Hz), MPU6050-grade
A_G = (np.eye(3) + np.array([[0, 0.010, -0.005], [0.008, 0, 0.012], [-0.006, 0.004, 0]])) @ np.diag(
    [1.01, 0.99, 1.015]
)
B_G = np.array([0.010, -0.020, 0.005])  # rad/s
C_TRUE = np.linalg.inv(A_G)
PI = np.pi
MOVES = [*TWELVE, (Z, -2.0), ((1.0, -2.0, 1.0), 1.3), (X, 1.2)]  # 14 rotations


def test_bias_error_is_n_over_sqrt_t() -> None:
    seconds = 120.0
    rec = session([], seed=1, fs=200.0, still_s=seconds, gyro_b=B_G, gyro_n=N).rec
    est = fit_gyro_bias(rec)
    assert est.procedure == "gyro-bias" and est.sensor == "gyro"
    assert np.array_equal(est.matrix, np.eye(3))
    assert est.verdict.accepted, est.verdict.reasons
    sigma = est.fit.sigma()
    assert sigma == pytest.approx(np.full(3, N / np.sqrt(seconds)), rel=0.2)
    assert np.all(np.abs(est.bias - B_G) < 4 * sigma)
    assert est.fit.details["noise_density"] == pytest.approx([N] * 3, rel=0.2)
    assert est.fit.residuals["noise"] == pytest.approx(N, rel=0.2)
    assert est.fit.details["earth_rate_rad_s"] == EARTH_RATE_RAD_S
    assert "Earth" in est.fit.details["earth_rate_note"]


def test_bias_from_a_recording_that_moved_is_rejected_with_the_time() -> None:
    rec = with_bump(still_recording(60.0, seed=2), 20.0, 20.5)
    est = fit_gyro_bias(rec)
    assert not est.verdict.accepted
    assert "moved at" in est.verdict.reasons[0]
    ((t0, t1),) = est.fit.details["moved_s"]
    assert t0 <= 20.1 and t1 >= 20.4


def test_bias_needs_a_second_and_a_steady_temperature() -> None:
    with pytest.raises(CalibrationRefused, match="at least 1 s"):
        fit_gyro_bias(still_recording(0.5, seed=3))
    warming = session([], seed=4, fs=200.0, still_s=30.0, temp=lambda t: 30.0 + 0.02 * t).rec
    est = fit_gyro_bias(warming)
    assert not est.verdict.accepted
    assert "temperature changed by +0.60 degC" in " ".join(est.verdict.reasons)


def test_cumulative_product_is_the_running_product() -> None:
    rng = np.random.default_rng(5)
    e = rotation(rng.normal(0.0, 0.3, (3001, 3)))
    expect = np.empty_like(e)
    expect[0] = e[0]
    for i in range(1, e.shape[0]):  # the slow reference, on a short array
        expect[i] = expect[i - 1] @ e[i]
    assert np.max(np.abs(cumulative_product(e) - expect)) < 1e-12


def gyro_session(
    seed: int,
    moves: list[tuple[tuple[float, float, float], float]],
    fs: float,
    still_s: float = 5.0,
    move_s: float = 2.0,
    accel_a: F64 | None = None,
) -> Session:
    return session(
        moves,
        seed=seed,
        fs=fs,
        still_s=still_s,
        move_s=move_s,
        accel_a=accel_a,
        gyro_a=A_G,
        gyro_b=B_G,
        gyro_n=N,
    )


def full_fit(
    rec: Recording, full_turns: bool = False, accel: AffineEstimate | None = None
) -> AffineEstimate:
    found = find_still(rec)
    bias = fit_gyro_bias(rec.slice(found[0].start, found[0].end))
    return fit_gyro_full(rec, found, bias, full_turns=full_turns, accel=accel)


def test_full_matrix_recovered_within_its_sigma() -> None:
    z: list[float] = []
    for trial in range(5):
        est = full_fit(gyro_session(10 + trial, MOVES, fs=200.0).rec)
        assert est.procedure == "gyro-full" and est.verdict.accepted, est.verdict.reasons
        zs = (est.matrix - C_TRUE).ravel() / est.fit.sigma()[:9]
        assert np.all(np.abs(zs) < 4), zs
        z.extend(zs)
        assert est.bias == pytest.approx(B_G, abs=4 * float(est.fit.sigma()[9:].max()))
    # the sigmas are honest: the errors' spread in units of sigma is about one
    assert 0.65 < np.std(z) < 1.4
    assert est.fit.residuals["dof"] == 2 * len(MOVES) - 9
    assert len(est.fit.details["motions"]) == len(MOVES)


def test_with_an_accel_calibration_the_gyro_lands_in_its_frame() -> None:
    e = np.array([[0.0, 0.017, -0.010], [0.012, 0.0, 0.015], [-0.008, 0.020, 0.0]])
    a_a = (np.eye(3) + e) @ np.diag([1.02, 0.98, 1.01])
    rec = gyro_session(20, MOVES, fs=200.0, still_s=8.0, accel_a=a_a).rec
    accel = fit_accel(rec, 9.81).estimate
    # the accel calibration's frame: its true C_a = R (A_a^-1 = Q R) makes C_a A_a = Q^T, a
    # rotation of the body frame; the accel fit's own error is carried in the gyro's sigma
    _, r = np.linalg.qr(np.linalg.inv(a_a))
    q_t = (np.sign(np.diag(r))[:, None] * r) @ a_a
    est = full_fit(rec, accel=accel)
    assert est.verdict.accepted, est.verdict.reasons
    z = (est.matrix - q_t @ C_TRUE).ravel() / est.fit.sigma()[:9]
    assert np.all(np.abs(z) < 4), z
    # without it, the accelerometer's 1-degree misalignment lands in the gyro matrix
    raw = full_fit(rec)
    assert not raw.verdict.accepted or np.any(
        np.abs((raw.matrix - C_TRUE).ravel() / raw.fit.sigma()[:9]) > 4
    )


VERTICAL = [  # z turns only while z is vertical; x and y tilts never turn about z
    (Z, PI / 2),
    (Z, -3 * PI / 4),
    (Z, 2 * PI),
    (X, PI / 2),
    (Y, PI / 2),
    (Y, -PI / 2),
    (X, -PI / 2),
    (Z, -2 * PI),
    (X, PI),
    (Z, 2 * PI),
    (Y, PI / 2),
    (X, PI / 3),
    (X, -PI / 3),
    (Y, -PI / 2),
    (Z, 4 * PI),
    (X, 2 * PI / 3),
    (Y, -PI / 4),
]


def test_turns_about_the_vertical_leave_that_scale_unknown_until_full_turns() -> None:
    rec = gyro_session(30, VERTICAL, fs=250.0, move_s=3.0).rec
    est = full_fit(rec)
    assert not est.verdict.accepted
    reason = est.verdict.reasons[0]
    assert "scale about its z axis" in reason and "--full-turns" in reason
    turns = full_fit(rec, full_turns=True)
    assert turns.verdict.accepted, turns.verdict.reasons
    z = (turns.matrix - C_TRUE).ravel() / turns.fit.sigma()[:9]
    assert np.all(np.abs(z) < 4), z
    assert turns.fit.sigma()[8] < 0.01 * est.fit.sigma()[8]
    counted = [m["turns"] for m in turns.fit.details["motions"]]
    assert [t for t in counted if t is not None] == [1, 1, 1, 2]
    assert turns.fit.details["partial_turns_about_vertical"] == 6


def test_too_few_rotations_says_how_many_more() -> None:
    rec = gyro_session(40, [(X, PI / 2), (Y, PI / 2), (Z, PI / 3)], fs=100.0).rec
    with pytest.raises(CalibrationRefused, match=r"found 3 rotations .* add 2 more"):
        full_fit(rec)


def test_full_turns_needs_a_turn_back_to_the_same_pose() -> None:
    rec = gyro_session(41, TWELVE, fs=100.0).rec
    with pytest.raises(CalibrationRefused, match="no rotation brought the sensor back"):
        full_fit(rec, full_turns=True)


def test_bias_as_a_vector_or_from_the_poses() -> None:
    rec = gyro_session(42, MOVES, fs=200.0).rec
    found = find_still(rec)
    for bias in (B_G, None):
        est = fit_gyro_full(rec, found, bias)
        assert est.verdict.accepted, est.verdict.reasons
        assert np.all(np.abs((est.matrix - C_TRUE).ravel() / est.fit.sigma()[:9]) < 4)
