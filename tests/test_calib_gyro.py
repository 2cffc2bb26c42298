"""Gyro calibration against sessions synthesised here (tests/test_calib_still.py `session`):
raw gyro = A_g w + b_g + white noise of density N, so the calibration is C = A_g^-1, b = b_g;
the accelerometer gives gravity's direction in each still pose. `earth_session` puts the same
motions on the turning Earth: raw gyro = A_g (w + R^T e) + b_g + noise, e Earth's rotation in a
level world frame (z up) whose north is at a chosen azimuth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pytest

from imud.calib.accel import fit_accel
from imud.calib.acceptance import DPH, Acceptance, Grade
from imud.calib.estimate import AffineEstimate
from imud.calib.gyro import EARTH_RATE_RAD_S, fit_gyro_bias, fit_gyro_full
from imud.calib.recording import Recording
from imud.calib.still import CalibrationRefused, find_still
from imud.rotations import cumulative_product
from tests.test_calib_still import (
    TWELVE,
    G,
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


def test_a_still_gyro_alone_gives_its_bias() -> None:
    """A recording of the gyro only (no accelerometer columns) still gives the bias."""
    from imud.calib.procedure import run_gyro

    rec = session([], seed=6, fs=200.0, still_s=60.0, gyro_b=B_G, gyro_n=N).rec
    alone = Recording(rec.t_ns, np.full_like(rec.accel, np.nan), rec.gyro, source="gyro only")
    out = run_gyro(alone, False, None)
    assert out.accepted, out.reasons
    sigma = np.sqrt(np.diag(np.array(out.report["covariance"])))[:3]
    assert np.all(np.abs(np.array(out.report["bias"]) - B_G) < 4 * sigma)
    moved = with_bump(alone, 20.0, 20.5)
    with pytest.raises(CalibrationRefused, match="no accelerometer columns"):
        run_gyro(moved, False, None)


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


# --- Earth's rotation -----------------------------------------------------------------------------

OMEGA = 7.292115e-5  # rad/s, Earth's rotation (WGS84)
LAT = 49.6  # degrees north
R0 = rotation(np.array([0.35, -0.25, 0.1]))  # a first pose that is not axis-aligned


@dataclass
class EarthSession:
    rec: Recording
    poses: list[F64]  # body-to-world rotation of each still pose
    earth: F64  # Earth's rotation in the world frame (rad/s)
    north: F64  # unit north in the world frame


def earth_session(
    seed: int,
    moves: list[tuple[tuple[float, float, float], float]],
    north_deg: float,
    *,
    fs: float = 200.0,
    still_s: float = 5.0,
    move_s: float = 2.0,
    g_sensitivity: F64 | None = None,
) -> EarthSession:
    """`session`'s motions (smooth body-axis turns between still poses, starting in R0) on a
    level table at latitude LAT whose north is north_deg from world +y towards +x (east). The
    gyro measures rotation against the stars: w + R^T e, e = Omega (cos(lat) north +
    sin(lat) up). g_sensitivity (rad/s per m/s^2) adds a bias proportional to the specific
    force, as MEMS gyros have."""
    rng = np.random.default_rng(seed)
    r = R0
    n_move, n_still = round(move_s * fs), round(still_s * fs)
    rots, rates, poses = [], [], []
    for k in range(len(moves) + 1):
        rots.append(np.repeat(r[None], n_still, axis=0))
        rates.append(np.zeros((n_still, 3)))
        poses.append(r)
        if k == len(moves):
            break
        axis = np.asarray(moves[k][0]) / np.linalg.norm(moves[k][0])
        angle = moves[k][1]
        s = (1 - np.cos(np.pi * np.arange(n_move + 1) / n_move)) / 2
        rots.append(r[None] @ rotation(axis[None] * (angle * s[:-1])[:, None]))
        rates.append(np.diff(s)[:, None] * fs * angle * axis[None])
        r = r @ rotation(axis * angle)
    rot, w = np.concatenate(rots), np.concatenate(rates)
    n = w.shape[0]
    lat, az = np.radians(LAT), np.radians(north_deg)
    north = np.array([np.sin(az), np.cos(az), 0.0])
    earth = OMEGA * (np.cos(lat) * north + np.sin(lat) * np.array([0.0, 0.0, 1.0]))
    f = np.einsum("nji,j->ni", rot, np.array([0.0, 0.0, G]))  # R^T (g up)
    inertial = w + np.einsum("nji,j->ni", rot, earth)
    gyro = inertial @ A_G.T + B_G + rng.normal(0.0, N * np.sqrt(fs), (n, 3))
    if g_sensitivity is not None:
        gyro += f @ g_sensitivity.T
    accel = f + rng.normal(0.0, 4e-3 * np.sqrt(fs), (n, 3))
    t_ns = np.round(np.arange(n) * 1e9 / fs).astype(np.int64)
    rec = Recording(t_ns, accel, gyro, None, None, None, "synthetic, on the turning Earth")
    return EarthSession(rec, poses, earth, north)


def heading_of(axis: str, first_pose: F64, north: F64) -> float:
    """Compass heading (degrees east of north) of a body axis in the first pose."""
    a = first_pose[:, "xyz".index(axis)]
    east = np.cross(north, [0.0, 0.0, 1.0])
    return float(np.degrees(np.arctan2(a @ east, a @ north)) % 360.0)


def pose_heading_bound(s: EarthSession, found_s: list[float]) -> float:
    """The heading's Cramer-Rao sigma (degrees) from the still poses' gyro means alone (C known,
    b free): mean_k = b + A_g R_k^T e(psi), each of noise N^2 / T_k per axis. The fit also has
    the motions, so its sigma is at most this."""
    lat = np.radians(LAT)
    d_earth = OMEGA * np.cos(lat) * np.cross([0.0, 0.0, 1.0], s.north)  # de/dpsi: towards west
    info = np.zeros((4, 4))
    for pose, seconds in zip(s.poses, found_s, strict=True):
        jac = np.column_stack([np.eye(3), A_G @ pose.T @ d_earth])
        info += jac.T @ jac * seconds / N**2
    return float(np.degrees(np.sqrt(np.linalg.inv(info)[3, 3])))


def test_earth_rotation_fitted_with_the_latitude() -> None:
    """Five headings: C and b within their sigma, the bias the sensor's own (the poses' means
    differ by Earth's rotation seen from each pose), the heading found."""
    rng = np.random.default_rng(60)
    z: list[float] = []
    for trial in range(5):
        north = float(rng.uniform(0.0, 360.0))
        s = earth_session(60 + trial, MOVES, north)
        found = find_still(s.rec)
        assert len(found) == len(s.poses)
        est = fit_gyro_full(s.rec, found, None, latitude_deg=LAT)
        assert est.verdict.accepted, est.verdict.reasons
        assert est.fit.names == (*[f"C_{a}{b}" for a in "xyz" for b in "xyz"], "b_x", "b_y", "b_z")
        zs = (est.fit.values - np.append(C_TRUE.ravel(), B_G)) / est.fit.sigma()
        assert np.all(np.abs(zs) < 4), zs
        z.extend(zs)
        earth = est.fit.details["earth"]
        assert earth["heading_of"].startswith("body x axis")  # x lies near level in R0
        truth = heading_of("x", R0, s.north)
        off = (earth["heading_deg"] - truth + 180.0) % 360.0 - 180.0
        assert abs(off) < 4 * earth["heading_sigma_deg"], (off, earth)
        bound = pose_heading_bound(s, [iv.duration_s for iv in found])
        assert 0.7 * bound < earth["heading_sigma_deg"] <= 1.05 * bound, (bound, earth)
        # the same data without the latitude: the bias holds the poses' mean Earth rate
        flat = fit_gyro_full(s.rec, found, None)
        inside = np.mean([A_G @ p.T @ s.earth for p in s.poses], axis=0)
        assert np.all(np.abs(flat.bias - B_G - inside) < 4 * flat.fit.sigma()[9:])
    assert 0.65 < np.std(z) < 1.4


def test_with_the_latitude_a_given_bias_is_held() -> None:
    s = earth_session(70, MOVES, 120.0)
    est = fit_gyro_full(s.rec, None, B_G, latitude_deg=LAT)
    assert est.verdict.accepted, est.verdict.reasons
    assert np.array_equal(est.bias, B_G) and np.all(est.fit.sigma()[9:] == 0)
    zs = (est.matrix - C_TRUE).ravel() / est.fit.sigma()[:9]
    assert np.all(np.abs(zs) < 4), zs
    assert est.fit.details["earth"]["bias_from"] == "given, held fixed"


def test_with_the_latitude_poses_that_disagree_are_refused_by_name() -> None:
    """A gyro whose bias moves with gravity (0.01 deg/s/g: a tenth of an MPU6050's): its still
    poses' means differ by more than Earth's rotation explains. The pure test refuses it; the
    model-error floor measures it in deg/h, within a consumer part's default tolerance and
    beyond a tactical part's."""
    g_sens = np.radians(0.01) / G * np.array([[0.5, -0.3, 0.2], [0.1, 0.8, -0.4], [0.2, 0.3, 0.6]])
    s = earth_session(71, MOVES, 40.0, g_sensitivity=g_sens)
    strict = fit_gyro_full(s.rec, None, None, latitude_deg=LAT, acceptance=Acceptance(strict=True))
    assert not strict.verdict.accepted
    assert "still poses' gyro means differ" in strict.verdict.reasons[0]
    assert "g-sensitivity" in strict.verdict.reasons[0]
    est = fit_gyro_full(s.rec, None, None, latitude_deg=LAT)
    floor = est.fit.residuals["model_error_means"]
    # the means move by up to |G g| = 0.01 deg/s = 36 deg/h between poses: a floor of that order
    assert 3 * DPH < floor < 36 * DPH, floor / DPH
    assert est.verdict.accepted, est.verdict.reasons
    assert any("deg/h beyond their noise" in r for r in est.verdict.reasons)
    tight = fit_gyro_full(
        s.rec, None, None, latitude_deg=LAT, acceptance=Acceptance(grade=Grade.TACTICAL)
    )
    if floor > 10 * DPH:  # the tactical default
        assert not tight.verdict.accepted
        assert "tactical-grade default; --tolerance-dph" in tight.verdict.reasons[0]


def test_bias_with_the_latitude_removes_the_vertical_part_only() -> None:
    """A still minute in the tilted first pose: the vertical part of Earth's rotation along the
    measured up is subtracted, the horizontal part (its direction needs the heading) stays."""
    s = earth_session(72, [], 75.0, still_s=120.0)
    up = R0.T @ np.array([0.0, 0.0, 1.0])
    vertical = OMEGA * np.sin(np.radians(LAT)) * up
    plain = fit_gyro_bias(s.rec)
    est = fit_gyro_bias(s.rec, latitude_deg=LAT)
    assert plain.verdict.accepted and est.verdict.accepted, est.verdict.reasons
    sigma = est.fit.sigma()
    assert sigma == pytest.approx(np.full(3, N / np.sqrt(120.0)), rel=0.2)
    inside = A_G @ R0.T @ s.earth  # what a still gyro reads of Earth's rotation
    assert np.all(np.abs(plain.bias - B_G - inside) < 4 * sigma)
    assert np.all(np.abs(est.bias - B_G - (inside - vertical)) < 4 * sigma)
    assert np.max(np.abs(est.bias - plain.bias) / sigma) > 4  # the part removed is real
    details = est.fit.details
    assert details["earth_removed_rad_s"] == pytest.approx(vertical, abs=1e-8)
    assert details["earth_remaining_rad_s"] == pytest.approx(OMEGA * np.cos(np.radians(LAT)))
    assert "horizontal part" in details["earth_rate_note"]


@pytest.mark.parametrize("latitude", [91.0, -90.5, float("nan")])
def test_a_latitude_must_be_one(latitude: float) -> None:
    rec = still_recording(2.0, seed=73)
    with pytest.raises(ValueError, match="between -90 and 90"):
        fit_gyro_bias(rec, latitude_deg=latitude)


def test_earth_rotation_is_not_taken_for_g_sensitivity() -> None:
    """A gyro without g-sensitivity on the turning Earth: the still poses' means differ by Earth's
    rate seen from each pose (its vertical part along the measured up, exactly what a diagonal G
    would give). Without the latitude G is kept only beyond Earth's own size; with it, Earth's
    vertical rate is taken out first: either way none is written, and the calibration is
    accepted."""
    from imud.calib.procedure import run_gyro

    kept = 0
    for seed in range(80, 86):
        s = earth_session(seed, MOVES, 30.0 * (seed - 80))
        for latitude in (None, LAT):
            out = run_gyro(s.rec, False, latitude_deg=latitude)
            assert out.accepted, (seed, latitude, out.reasons)
            kept += bool(out.report.get("g_sensitivity", {}).get("included"))
    assert kept == 0


def test_a_real_g_sensitivity_is_kept_with_the_latitude_too() -> None:
    from imud.calib.procedure import run_gyro

    g_sens = np.radians(np.array([[0.0, 0.05, 0.0], [-0.06, 0.0, 0.02], [0.0, 0.04, 0.03]])) / G
    s = earth_session(90, MOVES, 10.0, g_sensitivity=g_sens)
    for latitude in (None, LAT):
        gs = run_gyro(s.rec, False, latitude_deg=latitude).report["g_sensitivity"]
        assert gs["included"], (latitude, gs)
        np.testing.assert_allclose(
            np.array(gs["matrix_rad_s_per_m_s2"]) @ np.linalg.inv(A_G), g_sens, atol=2e-5
        )


def test_a_holdout_that_cannot_be_made_is_said_and_the_fit_stands() -> None:
    from imud.calib.procedure import run_gyro

    rec = gyro_session(42, MOVES[:8], fs=200.0).rec  # nine poses: enough to fit, not to halve
    assert len(find_still(rec)) == 9
    out = run_gyro(rec, False, holdout=True)
    assert out.accepted, out.reasons
    assert "needs at least 12" in out.report["holdout"]["unavailable"]
