"""Magnetometer ellipsoid fit on synthetic recordings whose physics is written here.

Readings: m = S b_body + h + n. b_body is the local field (|b| = 50 uT) seen in the body as the
device turns along a smooth spiral through all directions. S is soft iron with 6 % off-diagonal
coupling, h is hard iron of tens of uT, and n is white noise of 0.3 uT per axis.

Which correction is "the truth": every Q S^-1 with Q orthogonal maps the ellipsoid back onto a
sphere, and the fit must return the symmetric one. Write S^-1 = U P (polar decomposition:
U orthogonal, P symmetric positive definite). The only symmetric positive-definite choice is
M = alpha P. Q U P is symmetric positive definite only for Q U = I, by uniqueness of the
polar decomposition. Then M (m - h) = alpha P S b = alpha U^T S^-1 S b = alpha U^T b. So the
truth direction of each corrected sample is U^T b, not b. Here alpha = 1 when the field is
known (|corrected| = |b|), and alpha = det(P)^(-1/3) in the det(matrix) = 1 gauge.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from imud.calib.acceptance import Acceptance
from imud.calib.mag import difference_noise, fit_mag
from imud.calib.recording import Recording

F64 = npt.NDArray[np.float64]

FIELD = 50e-6  # tesla
NOISE = 0.3e-6  # tesla per axis, per sample
HARD = np.array([25e-6, -18e-6, 40e-6])
SOFT = np.array(  # diagonal scale errors plus ~6 % cross-coupling, deliberately not symmetric
    [[1.10, 0.06, -0.04], [0.05, 0.93, 0.06], [-0.06, 0.03, 1.02]]
)
SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def spiral(n: int) -> F64:
    """Unit vectors along one continuous spiral from +z to -z, consecutive points a constant
    3.6/sqrt(n) rad apart: directions uniform in area, and a path a hand could follow."""
    z = 1.0 - 2.0 * np.arange(n) / (n - 1)
    theta = np.arccos(z)
    dphi = np.zeros(n)
    dphi[1:-1] = 3.6 / math.sqrt(n) / np.sqrt(1.0 - z[1:-1] ** 2)
    phi = np.cumsum(dphi)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), z], axis=1)


def polar(s: F64) -> tuple[F64, F64]:
    """S^-1 = U P: U orthogonal, P symmetric positive definite (from the SVD)."""
    w, sv, vt = np.linalg.svd(np.linalg.inv(s))
    return w @ vt, vt.T @ np.diag(sv) @ vt


def recording(body: F64, seed: int, rate_hz: float = 100.0) -> tuple[Recording, F64]:
    n = body.shape[0]
    clean = body @ SOFT.T + HARD
    noisy = clean + np.random.default_rng(seed).normal(0.0, NOISE, (n, 3))
    t = (np.arange(n) * (1e9 / rate_hz)).astype(np.int64)
    zeros = np.zeros((n, 3))
    return Recording(t, zeros, zeros, mag=noisy, source="synthetic"), clean


def angle_rms_deg(a: F64, b: F64) -> float:
    cos = np.sum(a * b, axis=1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    return math.degrees(math.sqrt(float(np.mean(np.arccos(np.clip(cos, -1.0, 1.0)) ** 2))))


def best_rotation(a: F64, b: F64) -> F64:
    """Kabsch: the rotation R minimising sum |R a_i - b_i|^2 (gives min/max every benefit)."""
    u, _, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    out: F64 = u @ np.diag([1.0, 1.0, d]) @ vt
    return out


def test_the_polar_relation_the_tests_rely_on() -> None:
    u, p = polar(SOFT)
    assert np.allclose(u @ p, np.linalg.inv(SOFT))
    assert np.allclose(u @ u.T, np.eye(3)) and np.allclose(p, p.T)
    assert np.all(np.linalg.eigvalsh(p) > 0)
    body = FIELD * spiral(50)
    assert np.allclose((body @ SOFT.T) @ p.T, body @ u)  # P S b = U^T b (rows: b @ U)
    # the rotation is not negligible: comparing against b itself would be wrong
    assert math.degrees(math.acos((np.trace(u) - 1.0) / 2.0)) > 1.0


@pytest.mark.parametrize("known_field", [False, True])
def test_ellipsoid_fit_reaches_a_tenth_of_a_percent_and_degree(known_field: bool) -> None:
    body = FIELD * spiral(1000)
    rec, clean = recording(body, seed=7)
    result = fit_mag(rec, FIELD if known_field else None)
    est = result.estimate
    assert est.sensor == "mag" and est.procedure == "mag-ellipsoid"
    assert est.verdict.accepted, est.verdict.reasons
    assert result.coverage.fraction == 1.0 and result.coverage.missing == ()
    assert np.allclose(est.matrix, est.matrix.T)

    u, p = polar(SOFT)
    alpha = 1.0 if known_field else float(np.linalg.det(p)) ** (-1.0 / 3.0)
    assert est.field_t is not None
    assert est.field_t == pytest.approx(alpha * FIELD, rel=1e-3)

    # accuracy on the noise-free truth
    corrected = (clean - est.bias) @ est.matrix.T
    norm_error = np.linalg.norm(corrected, axis=1) / (alpha * FIELD) - 1.0
    norm_rms_pct = 100.0 * math.sqrt(float(np.mean(norm_error**2)))
    direction_rms = angle_rms_deg(corrected, body @ u)
    assert norm_rms_pct <= 0.1
    assert direction_rms <= 0.1

    # every parameter within 4 sigma of the truth, by the fit's own covariance
    truth_m = alpha * p
    truth = np.concatenate([HARD, [truth_m[i, j] for i, j in SYM], [alpha * FIELD]])
    sigma = est.fit.sigma()
    free = sigma > 0
    assert np.all(np.abs(est.fit.values - truth)[free] < 4.0 * sigma[free])
    assert free[9] == (not known_field)  # the field carries no variance when it is given
    # hard-iron sigma against the sphere-fit Cramer-Rao bound sigma * sqrt(3 / N): the
    # readings' directions are uniform, so sum(u u^T) = N/3 I, and the soft-iron terms
    # decouple (odd moments vanish). S is within ~10 % of the identity, hence the factor.
    crb = NOISE * math.sqrt(3.0 / 1000)
    assert np.all(sigma[:3] > crb / 1.3) and np.all(sigma[:3] < crb * 1.3)

    # the residual statistics report the measured noise, not a threshold
    res = est.fit.residuals
    assert res["noise"] == pytest.approx(NOISE * alpha * FIELD / FIELD, rel=0.15)
    assert res["rms"] == pytest.approx(res["noise"], rel=0.1)
    assert res["norm_error_rms_pct"] == pytest.approx(100 * res["rms"] / est.field_t)
    assert res["p_value"] >= 0.01


def test_min_max_leaves_percents_and_degrees_where_the_fit_leaves_hundredths() -> None:
    body = FIELD * spiral(1000)
    rec, clean = recording(body, seed=7)
    result = fit_mag(rec)
    u, _ = polar(SOFT)

    fit_corr = (clean - result.estimate.bias) @ result.estimate.matrix.T
    assert result.estimate.field_t is not None
    fit_norm = float(np.std(np.linalg.norm(fit_corr, axis=1) / result.estimate.field_t))
    fit_dir = angle_rms_deg(fit_corr, body @ u)

    mm = result.minmax
    assert mm.procedure == "mag-minmax" and not mm.verdict.accepted
    assert np.allclose(mm.matrix, np.diag(np.diag(mm.matrix)))
    mm_corr = (clean - mm.bias) @ mm.matrix.T
    assert mm.field_t is not None
    mm_norm = float(np.std(np.linalg.norm(mm_corr, axis=1) / mm.field_t))
    rot = best_rotation(mm_corr / np.linalg.norm(mm_corr, axis=1)[:, None], body / FIELD)
    mm_dir = angle_rms_deg(mm_corr @ rot.T, body)  # after its own best rotation

    assert 100 * mm_norm > 2.0 and mm_dir > 2.0  # several percent and degrees
    assert mm_norm > 20 * fit_norm and mm_dir > 20 * fit_dir
    assert (
        mm.fit.residuals["norm_error_rms_pct"]
        > 5 * result.estimate.fit.residuals["norm_error_rms_pct"]
    )


def test_upper_hemisphere_only_is_refused_naming_minus_z() -> None:
    body = spiral(2000)
    body = FIELD * body[body[:, 2] > 0.0]
    rec, _ = recording(body, seed=3)
    result = fit_mag(rec)
    assert not result.coverage.ok
    assert result.coverage.fraction < 0.75
    assert not result.estimate.verdict.accepted
    (reason,) = result.estimate.verdict.reasons
    assert "below the 75% needed" in reason
    assert "-z (bottom face pointing along the field)" in reason
    assert "+z" not in reason


def test_turning_in_one_plane_only_is_refused_naming_both_z_directions() -> None:
    """Turned about z only (a compass on a table): the readings are a circle, not an
    ellipsoid, and no plausible soft iron explains them."""
    turn = np.linspace(0.0, 6.0 * math.pi, 1500)
    incl = math.radians(60.0)
    body = FIELD * np.stack(
        [math.cos(incl) * np.cos(turn), math.cos(incl) * np.sin(turn), -math.sin(incl) + 0 * turn],
        axis=1,
    )
    rec, _ = recording(body, seed=1)
    with pytest.raises(ValueError, match="no plausible ellipsoid") as refused:
        fit_mag(rec)
    assert "-z (bottom face" in str(refused.value) and "+z (top face" in str(refused.value)
    assert "+x" not in str(refused.value)


def test_reported_sigmas_match_the_scatter_over_repeated_recordings() -> None:
    """40 noise draws on the same path: each parameter's error divided by its reported sigma
    must scatter with a standard deviation near 1 (an overconfident or timid covariance
    would not)."""
    body = FIELD * spiral(1000)
    _, p = polar(SOFT)
    alpha = float(np.linalg.det(p)) ** (-1.0 / 3.0)
    truth = np.concatenate([HARD, [alpha * p[i, j] for i, j in SYM], [alpha * FIELD]])
    z = []
    for seed in range(40):
        rec, _ = recording(body, seed=100 + seed)
        fit = fit_mag(rec).estimate.fit
        z.append((fit.values - truth) / fit.sigma())
    spread = np.std(np.asarray(z), axis=0)
    assert np.all(spread > 0.65) and np.all(spread < 1.4), spread


def test_too_few_samples_and_no_magnetometer_are_refused() -> None:
    rec, _ = recording(FIELD * spiral(150), seed=1)
    with pytest.raises(ValueError, match=r"150 distinct .* at least 200 \(50 more\)"):
        fit_mag(rec)
    no_mag = Recording(rec.t_ns, rec.accel, rec.gyro, source="x.csv")
    with pytest.raises(ValueError, match=r"x\.csv has no magnetometer columns"):
        fit_mag(no_mag)


def test_held_readings_of_a_slower_magnetometer_do_not_fake_zero_noise() -> None:
    """A 100 Hz magnetometer in a 1 kHz recording repeats each reading ten times; the
    repeats are dropped, so the noise and the verdict are those of the 1000 real readings."""
    body = FIELD * spiral(1000)
    rec, _ = recording(body, seed=11)
    assert rec.mag is not None
    held = np.repeat(rec.mag, 10, axis=0)
    n = held.shape[0]
    t = (np.arange(n) * 1_000_000).astype(np.int64)
    big = Recording(t, np.zeros((n, 3)), np.zeros((n, 3)), mag=held)
    result = fit_mag(big)
    assert result.estimate.verdict.accepted, result.estimate.verdict.reasons
    assert result.estimate.fit.details["n_held_repeats_dropped"] == n - 1000
    noise = np.asarray(result.estimate.fit.details["noise_per_axis_t"])
    assert np.all(np.abs(noise / NOISE - 1.0) < 0.15)


def test_a_hard_iron_that_moves_mid_recording_fails_the_chi2_test() -> None:
    """A motor switched on halfway adds 1.5 uT of hard iron (5 sigma): no single ellipsoid
    explains both halves, and the residuals exceed the noise measured sample to sample."""
    body = FIELD * spiral(2000)
    rec, _ = recording(body, seed=5)
    assert rec.mag is not None
    mag = rec.mag.copy()
    mag[1000:] += np.array([1.5e-6, 0.0, 0.0])
    moved = Recording(rec.t_ns, rec.accel, rec.gyro, mag=mag)
    est = fit_mag(moved, acceptance=Acceptance(strict=True, significance=0.01)).estimate
    assert not est.verdict.accepted
    assert any("residuals exceed the measured noise" in r for r in est.verdict.reasons)
    assert est.fit.residuals["p_value"] < 0.01
    # by default the jump is a model error: about half the step's size in the norm residuals,
    # reported, and refused once beyond the tolerance asked for
    loose = fit_mag(moved).estimate
    floor = loose.fit.residuals["model_error"]
    assert 0.2e-6 < floor < 1.5e-6
    tight = fit_mag(moved, acceptance=Acceptance(tolerance=floor / 2)).estimate
    assert not tight.verdict.accepted
    assert any("(--tolerance-ut)" in r for r in tight.verdict.reasons)


def test_difference_noise_ignores_steady_rotation() -> None:
    """Third differences of a field turning at 1 rad/s sampled at 100 Hz see only the noise."""
    t = np.arange(5000) / 100.0
    path = np.stack([np.cos(t) * np.cos(0.3 * t), np.sin(t), np.cos(t) * np.sin(0.3 * t)], 1)
    x = FIELD * path + np.random.default_rng(2).normal(0.0, NOISE, (5000, 3))
    sigma, dof = difference_noise(x)
    assert np.all(np.abs(sigma / NOISE - 1.0) < 0.05)
    assert dof == pytest.approx(5000 / 2.31, rel=0.05)
