"""Temperature polynomial fit on synthetic still recordings whose physics is written here.

The device lies still in one orientation while its temperature ramps linearly from 10 to
50 degC. The gyro reads a constant (bias at 30 degC plus Earth rate) plus a known polynomial of
(T - 30), with white noise of an MPU6050-grade density, 0.005 deg/s/sqrt(Hz). The accel reads
gravity in its orientation plus a known bias drift, with 400 ug/sqrt(Hz). The temperature
sensor has its own white noise.

Cramer-Rao check. Blocks are equally spaced in temperature, so x = (T - 30)/20 is uniform on
[-1, 1]. Write the fit in Legendre polynomials, sum b_n P_n. The b_n are independent, with
var(b_n) = (2n+1) sigma_b^2 / n_blocks, where sigma_b is the noise of a block mean. For a cubic,
the power coefficients are a1 = b1 - 3/2 b3, a2 = 3/2 b2, a3 = 5/2 b3, so
var(a1) = (3 + 9/4 * 7) = 18.75, var(a2) = 9/4 * 5 = 11.25 and var(a3) = 25/4 * 7 = 43.75,
each times sigma_b^2 / n_blocks. Then c_k = a_k / 20^k.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from imud.calib.recording import Recording
from imud.calib.temp import fit_temperature, temp_correction

F64 = npt.NDArray[np.float64]

RATE = 50.0  # Hz
GYRO_DENSITY = math.radians(0.005)  # rad/s/sqrt(Hz)
ACCEL_DENSITY = 400e-6 * 9.80665  # m/s^2/sqrt(Hz)
TEMP_NOISE = 0.05  # degC per sample
CUBIC = np.array(  # rad/s per degC^k, rows k = 1, 2, 3: a clear cubic (~0.02 rad/s at the ends)
    [[1.5e-3, -8e-4, 2e-3], [1e-5, 2e-5, -1.5e-5], [2e-6, -3e-6, 1.5e-6]]
)
LINE = np.array([[4e-3, -2.5e-3, 6e-3]])  # m/s^2 per degC (~0.4-0.6 mg/degC)


def drift(coefficients: F64, t: F64) -> F64:
    """sum_k c_k (T - 30)^k, written out directly (not Horner)."""
    dt = (t - 30.0)[:, None]
    return sum(
        (coefficients[k] * dt ** (k + 1) for k in range(coefficients.shape[0])), start=0 * dt
    )


def ramp(
    seconds: float,
    t0: float,
    t1: float,
    gyro_poly: F64,
    accel_poly: F64,
    seed: int,
) -> Recording:
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE)
    temp_true = np.linspace(t0, t1, n)
    gyro = (
        np.array([0.01, -0.02, 0.005])
        + drift(gyro_poly, temp_true)
        + rng.normal(0.0, GYRO_DENSITY * math.sqrt(RATE), (n, 3))
    )
    gravity_body = 9.80665 * np.array([0.1, -0.2, 0.9747])  # a tilted pose, not a face
    accel = (
        gravity_body
        + np.array([0.2, -0.1, 0.3])
        + drift(accel_poly, temp_true)
        + rng.normal(0.0, ACCEL_DENSITY * math.sqrt(RATE), (n, 3))
    )
    temp = temp_true + rng.normal(0.0, TEMP_NOISE, n)
    t_ns = (np.arange(n) * (1e9 / RATE)).astype(np.int64)
    return Recording(t_ns, accel, gyro, temp=temp, source="ramp.csv")


def test_cubic_gyro_drift_is_recovered_at_order_3_within_its_uncertainty() -> None:
    rec = ramp(2000.0, 10.0, 50.0, CUBIC, LINE, seed=1)
    est = fit_temperature(rec, "gyro")
    assert est.verdict.accepted, est.verdict.reasons
    assert est.sensor == "gyro" and est.order == 3
    assert est.reference_c == pytest.approx(30.0, abs=0.05)  # the middle of the span
    assert est.span_c[0] == pytest.approx(10.0, abs=0.05)
    assert est.span_c[1] == pytest.approx(50.0, abs=0.05)

    # the truth is written about 30 degC; T_ref sits a few mK away, so re-expand exactly
    d = est.reference_c - 30.0
    c1, c2, c3 = CUBIC
    truth = np.array([c1 + 2 * c2 * d + 3 * c3 * d**2, c2 + 3 * c3 * d, c3])
    sigma = est.fit.sigma().reshape(3, 3)
    assert np.all(np.abs(est.coefficients - truth) < 4.0 * sigma)

    # sigma against the Cramer-Rao value of the module docstring
    n_blocks = 2000
    sigma_b = GYRO_DENSITY / math.sqrt(1.0)  # a 1 s block mean: density / sqrt(seconds)
    crb = np.array(
        [
            math.sqrt(v / n_blocks) * sigma_b / 20.0**k
            for k, v in ((1, 18.75), (2, 11.25), (3, 43.75))
        ]
    )
    ratio = sigma / crb[:, None]
    assert np.all(ratio > 1 / 1.3) and np.all(ratio < 1.3)

    res = est.fit.residuals
    assert res["p_value"] >= 0.01
    assert res["noise"] == pytest.approx(sigma_b, rel=0.1)
    assert {"rms_x", "rms_y", "rms_z", "chi2", "dof"} <= set(res)


def test_after_compensation_the_drift_is_under_5_percent_of_the_uncompensated() -> None:
    rec = ramp(2000.0, 10.0, 50.0, CUBIC, LINE, seed=2)
    est = fit_temperature(rec, "gyro")
    grid = np.linspace(10.0, 50.0, 401)
    raw = drift(CUBIC, grid)
    corr, outside = temp_correction(est.coefficients, est.reference_c, est.span_c, grid)
    assert np.count_nonzero(outside) <= 2  # only the very edges may lie past the block means
    before = np.ptp(raw, axis=0)
    after = np.ptp(raw - corr, axis=0)
    assert np.all(after < 0.05 * before)


def test_a_pure_line_is_fitted_at_order_1() -> None:
    rec = ramp(2000.0, 10.0, 50.0, CUBIC, LINE, seed=3)
    est = fit_temperature(rec, "accel")
    assert est.verdict.accepted, est.verdict.reasons
    assert est.order == 1
    sigma = est.fit.sigma().reshape(1, 3)
    assert np.all(np.abs(est.coefficients - LINE) < 4.0 * sigma)
    # order-1 Cramer-Rao: var(c1) = 3 sigma_b^2 / (n_blocks * 20^2)
    sigma_b = ACCEL_DENSITY / math.sqrt(1.0)
    crb = math.sqrt(3.0 / 2000) * sigma_b / 20.0
    assert np.all(sigma / crb > 1 / 1.3) and np.all(sigma / crb < 1.3)


def test_a_cubic_forced_to_a_line_fails_the_chi2_test() -> None:
    rec = ramp(2000.0, 10.0, 50.0, CUBIC, LINE, seed=4)
    est = fit_temperature(rec, "gyro", max_order=1)
    assert est.order == 1
    assert not est.verdict.accepted
    assert "residuals exceed the measured block noise at order 1" in est.verdict.reasons[0]
    assert "allow a higher order than 1" in est.verdict.reasons[0]


def test_a_wandering_bias_is_accepted_with_its_sigmas_inflated_and_named_as_wander() -> None:
    """MPU6050-grade bias instability (10 deg/h) as a Gauss-Markov process with a 100 s
    correlation time: a bias that moves with time, not temperature. White noise between
    blocks cannot account for it, so the chi-squared test fails; every MEMS gyro has it, and
    the polynomial is still right to within it. So the fit is accepted, the reason says the
    residuals move together, and the sigmas are inflated by the long-run factor (a lower bound:
    the slowest wander looks like temperature, so the errors may still reach a few of them)."""
    rec = ramp(2400.0, 10.0, 50.0, CUBIC, LINE, seed=9)
    rng = np.random.default_rng(10)
    sigma, tau, knots = math.radians(10.0) / 3600.0, 100.0, 2402
    phi = math.exp(-1.0 / tau)
    wander = np.empty((knots, 3))
    wander[0] = rng.normal(0.0, sigma, 3)
    for k in range(1, knots):  # one knot per second, linearly interpolated
        wander[k] = phi * wander[k - 1] + rng.normal(0.0, sigma * math.sqrt(1 - phi**2), 3)
    t = rec.t_ns / 1e9
    gm = np.stack([np.interp(t, np.arange(knots), wander[:, a]) for a in range(3)], axis=1)
    est = fit_temperature(Recording(rec.t_ns, rec.accel, rec.gyro + gm, temp=rec.temp), "gyro")
    assert est.verdict.accepted
    wander_note, one_way = est.verdict.reasons
    assert "drift together from block to block" in wander_note
    assert "bias instability" in wander_note and "inflated" in wander_note
    assert "moved one way only" in one_way  # a heating ramp: hysteresis unseen
    inflation = est.fit.details["sigma_inflation"]
    assert inflation > 2.0
    assert est.order == 3
    sd = np.sqrt(np.diag(est.fit.covariance)).reshape(3, 3)
    z = np.abs(est.coefficients - CUBIC) / sd
    assert z.max() < 6.0  # within a few of the inflated sigmas...
    assert (z * inflation).max() > 4.0  # ...where the white-noise sigmas alone would not hold


def test_a_lagging_temperature_sensor_is_named_as_a_heating_cooling_difference() -> None:
    """Heat 10 -> 50 degC in 20 min, cool back in 20 min; the die's temperature sensor lags the
    sensing element by 20 s, so it reads T - 20 s * dT/dt. With a linear drift the bias is off
    by slope * 20 s * 0.033 degC/s = +-0.67 degC * slope: one offset while heating, the opposite
    while cooling (1e-3 rad/s on x, ~10x the block noise). One polynomial cannot hold it. The
    fit says so with the difference, without refusing: over one cycle, slow bias wander can
    separate two legs as well."""
    slope = np.array([[1.5e-3, -8e-4, 2e-3]])  # rad/s per degC
    up = ramp(1200.0, 10.0, 50.0, slope, LINE, seed=21)
    down = ramp(1200.0, 50.0, 10.0, slope, LINE, seed=22)
    t_ns = np.concatenate([up.t_ns, down.t_ns + up.t_ns[-1] + up.t_ns[1]])
    rate = np.concatenate(
        [np.full(up.t_ns.size, 40.0 / 1200.0), np.full(down.t_ns.size, -40.0 / 1200.0)]
    )
    temp = np.concatenate([up.temp, down.temp]) - 20.0 * rate  # type: ignore[list-item]
    rec = Recording(
        t_ns,
        np.concatenate([up.accel, down.accel]),
        np.concatenate([up.gyro, down.gyro]),
        temp=temp,
        source="chamber.csv",
    )
    est = fit_temperature(rec, "gyro")
    (note,) = [r for r in est.verdict.reasons if "between heating and cooling" in r]
    assert "hysteresis" in note and "lagging" in note
    hyst = est.fit.details["hysteresis"]
    expected = 2 * 0.67 * slope[0]  # heating minus cooling: the sensor reads low while heating
    np.testing.assert_allclose(hyst["difference"], expected, rtol=0.1, atol=5e-5)


def test_half_a_degree_is_refused_naming_the_span_needed() -> None:
    rec = ramp(300.0, 25.0, 25.5, CUBIC, LINE, seed=5)
    with pytest.raises(ValueError, match=r"span 0\.5 degC .* at least 5 degC \(4\.5 degC more\)"):
        fit_temperature(rec, "gyro")


def test_a_short_span_limits_the_order_and_says_what_more_is_needed() -> None:
    rec = ramp(1200.0, 24.0, 36.0, CUBIC * np.array([[1.0], [1.0], [0.0]]), LINE, seed=6)
    est = fit_temperature(rec, "gyro")
    assert est.order <= 2
    assert est.fit.details["allowed_order"] == 2
    assert any("order 3 needs a span of at least 15 degC" in r for r in est.verdict.reasons)


def test_no_temperature_and_motion_are_refused() -> None:
    rec = ramp(600.0, 10.0, 30.0, CUBIC, LINE, seed=7)
    with pytest.raises(ValueError, match="no temperature"):
        fit_temperature(Recording(rec.t_ns, rec.accel, rec.gyro, source="x.csv"), "gyro")

    # picked up for five seconds at t = 300 s: turning at 1 rad/s about x, gravity swinging
    gyro, accel = rec.gyro.copy(), rec.accel.copy()
    k = slice(int(300 * RATE), int(305 * RATE))
    angle = np.linspace(0.0, 5.0, k.stop - k.start)
    gyro[k, 0] += 1.0
    accel[k, 1] = 9.80665 * np.sin(angle)
    accel[k, 2] = 9.80665 * np.cos(angle)
    moved = Recording(rec.t_ns, accel, gyro, temp=rec.temp)
    est = fit_temperature(moved, "gyro")
    assert not est.verdict.accepted
    assert est.verdict.reasons[0].startswith("motion in ")
    assert "(first at 300.0 s)" in est.verdict.reasons[0]


def test_temp_correction_clamps_flags_and_matches_the_polynomial() -> None:
    coefficients = np.array([[1.0, 2.0, -1.0], [0.1, 0.0, 0.2], [0.01, -0.02, 0.0]])
    temp = np.array([0.0, 10.0, 25.0, 40.0, 60.0, np.nan])
    corr, outside = temp_correction(coefficients, 25.0, (10.0, 40.0), temp)
    assert outside.tolist() == [True, False, False, False, True, True]
    dt = np.array([-15.0, -15.0, 0.0, 15.0, 15.0, 0.0])[:, None]  # clamped; NaN -> reference
    direct = coefficients[0] * dt + coefficients[1] * dt**2 + coefficients[2] * dt**3
    assert np.allclose(corr, direct)
    assert corr.shape == (6, 3)
