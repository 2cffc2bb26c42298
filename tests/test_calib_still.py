"""Still intervals and the noise of their means, on sessions synthesised from physics here.

`session` (also used by the accel and gyro tests) turns a sensor through body-axis rotations
between still poses: orientation R(t) = R_k exp([axis angle s(t)]x) with a smooth profile s, body
rate axis * angle * s'(t) (held over each sample period, so integrating it sample by sample is
exact), accelerometer raw = A_a (R^T (0, 0, g) + b0) + noise, gyro raw = A_g w + b_g + noise,
white noise of density N (a T-second mean has sigma N / sqrt(T)).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pytest

from imud.calib.recording import Recording
from imud.calib.still import (
    CalibrationRefused,
    check_still,
    find_still,
    interval_stats,
    mean_and_cov,
)

F64 = npt.NDArray[np.float64]
G = 9.81
X, Y, Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)


def rotation(phi: F64) -> F64:
    """exp([phi]x) for rows of phi (..., 3): Rodrigues' formula."""
    phi = np.asarray(phi, dtype=np.float64)
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    k = np.zeros((*phi.shape[:-1], 3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -phi[..., 2], phi[..., 1], -phi[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    safe = np.where(th > 1e-12, th, 1.0)
    a = np.where(th > 1e-12, np.sin(safe) / safe, 1.0)
    b = np.where(th > 1e-12, (1 - np.cos(safe)) / safe**2, 0.5)
    out: F64 = np.eye(3) + a * k + b * (k @ k)
    return out


@dataclass
class Session:
    rec: Recording
    still: list[tuple[int, int]]  # true still sample spans [a, b)
    poses: list[F64]  # body-to-world rotation of each still pose


def session(
    moves: list[tuple[tuple[float, float, float], float]],
    *,
    seed: int = 0,
    fs: float = 500.0,
    still_s: float | list[float] = 5.0,
    move_s: float = 2.0,
    accel_a: F64 | None = None,
    accel_b0: F64 | None = None,
    accel_n: float = 4e-3,  # m/s^2/sqrt(Hz): MPU6050-grade, 400 ug/sqrt(Hz)
    gyro_a: F64 | None = None,
    gyro_b: F64 | None = None,
    gyro_n: float = 8.7e-5,  # rad/s/sqrt(Hz): 0.005 deg/s/sqrt(Hz)
    r0: F64 | None = None,
    temp: Callable[[F64], F64] | None = None,
) -> Session:
    rng = np.random.default_rng(seed)
    stills = still_s if isinstance(still_s, list) else [still_s] * (len(moves) + 1)
    r = np.eye(3) if r0 is None else r0
    n_move = round(move_s * fs)
    rots, rates, spans, poses = [], [], [], []
    count = 0
    for k, dur in enumerate(stills):
        n = round(dur * fs)
        rots.append(np.repeat(r[None], n, axis=0))
        rates.append(np.zeros((n, 3)))
        spans.append((count, count + n))
        poses.append(r)
        count += n
        if k == len(moves):
            break
        axis = np.asarray(moves[k][0]) / np.linalg.norm(moves[k][0])
        angle = moves[k][1]
        t = np.arange(n_move + 1) / fs
        s = (1 - np.cos(np.pi * t / move_s)) / 2
        rots.append(r[None] @ rotation(axis[None] * (angle * s[:-1])[:, None]))
        rates.append(np.diff(s)[:, None] * fs * angle * axis[None])
        r = r @ rotation(axis * angle)
        count += n_move
    rot = np.concatenate(rots)
    w = np.concatenate(rates)
    n = w.shape[0]
    f = np.einsum("nji,j->ni", rot, np.array([0.0, 0.0, G]))
    aa = np.eye(3) if accel_a is None else accel_a
    ab = np.zeros(3) if accel_b0 is None else accel_b0
    ga = np.eye(3) if gyro_a is None else gyro_a
    gb = np.zeros(3) if gyro_b is None else gyro_b
    accel = (f + ab) @ aa.T + rng.normal(0.0, accel_n * np.sqrt(fs), (n, 3))
    gyro = w @ ga.T + gb + rng.normal(0.0, gyro_n * np.sqrt(fs), (n, 3))
    t_ns = np.round(np.arange(n) * 1e9 / fs).astype(np.int64)
    tc = None if temp is None else temp(np.arange(n) / fs)
    return Session(Recording(t_ns, accel, gyro, tc, None, None, "synthetic"), spans, poses)


def still_recording(seconds: float, *, fs: float = 200.0, seed: int = 0) -> Recording:
    return session([], seed=seed, fs=fs, still_s=seconds).rec


def with_bump(rec: Recording, t0: float, t1: float) -> Recording:
    """A knock: a short wobble (accel and gyro oscillate, the pose is the same after)."""
    a, b = round(t0 * rec.rate_hz), round(t1 * rec.rate_hz)
    t = np.arange(b - a) / rec.rate_hz
    wobble = np.sin(2 * np.pi * 7.0 * t)[:, None] * np.sin(np.pi * t / (t1 - t0))[:, None]
    accel, gyro = rec.accel.copy(), rec.gyro.copy()
    accel[a:b] += 1.5 * wobble * np.array([1.0, -0.5, 0.3])
    gyro[a:b] += 0.4 * wobble * np.array([0.2, 1.0, -0.4])
    return Recording(rec.t_ns, accel, gyro, rec.temp, None, None, rec.source)


TWELVE = [  # twelve poses, no two within 20 deg of each other
    (X, np.pi / 2),
    (Z, np.pi / 3),
    (Y, np.pi / 3),
    ((1.0, 1.0, 0.0), 2.0),
    ((0.0, 1.0, 1.0), -1.5),
    ((1.0, 0.0, 1.0), 1.0),
    ((1.0, -1.0, 0.0), 2.0),
    ((1.0, 2.0, 3.0), 1.5),
    ((3.0, 1.0, -1.0), 2.2),
    (Y, -2.5),
    ((1.0, 1.0, 1.0), -2.0),
]


def test_every_pose_is_found_and_no_motion_is_included() -> None:
    s = session(TWELVE, seed=1)
    found = find_still(s.rec)
    assert len(found) == len(s.still)
    for iv, (a, b) in zip(found, s.still, strict=True):
        assert a <= iv.start < iv.end <= b  # precision: nothing of the motion
        assert iv.end - iv.start >= 0.7 * (b - a)  # recall: most of the pose
        assert iv.n == iv.end - iv.start
        assert not iv.saturated and iv.temp_c is None


def test_a_smooth_tip_under_shaking_is_cut_out_of_what_looks_still() -> None:
    """Vibration everywhere (a shaking hand, an engine) sets the noise floor: white noise 60x
    the sensor's on accel and gyro. A slow 35 deg tip (3 s, peak rate 0.3 rad/s) between two
    holds then adds less variance than three spreads of that floor, so the variance test alone
    joins both holds and the tip into one interval whose mean lies between the poses. The
    window means jump during the tip (gravity turns by 5.6 m/s^2): the run is cut there, and
    each interval lies inside one hold."""
    s = session(
        [((1.0, 0.0, 0.0), np.radians(35.0))],
        seed=3,
        fs=200.0,
        still_s=6.0,
        move_s=3.0,
        accel_n=60 * 4e-3,
        gyro_n=60 * 8.7e-5,
    )
    found = find_still(s.rec)
    assert len(found) == 2
    for iv, (a, b) in zip(found, s.still, strict=True):
        assert a <= iv.start < iv.end <= b


def test_the_means_and_their_errors_match_the_physics() -> None:
    s = session(TWELVE, seed=2, fs=400.0)
    found = find_still(s.rec)
    z = []
    for iv, pose in zip(found, s.poses, strict=True):
        truth = pose.T @ np.array([0.0, 0.0, G])
        # white noise of density N: a T-second mean has sigma N / sqrt(T)
        expect = 4e-3 / np.sqrt(iv.n / 400.0)
        assert iv.accel_se == pytest.approx(np.full(3, expect), rel=0.2)
        assert iv.gyro_se == pytest.approx(np.full(3, 8.7e-5 / np.sqrt(iv.n / 400.0)), rel=0.2)
        z.extend((iv.accel - truth) / iv.accel_se)
    assert np.max(np.abs(z)) < 4.5
    assert 0.6 < np.std(z) < 1.4


def test_block_averaging_sees_coloured_noise_that_sigma_over_sqrt_n_misses() -> None:
    # AR(1) x_t = phi x_(t-1) + e_t: the variance of a long mean is sigma_e^2 / (1 - phi)^2 / n,
    # (1 + phi) / (1 - phi) = 19 times sigma_x^2 / n for phi = 0.9
    rng = np.random.default_rng(3)
    phi, sigma_e, n = 0.9, 1.0, 200_000
    e = rng.normal(0.0, sigma_e, (n, 2))
    # the recursion as its impulse response phi^k, truncated where phi^k ~ 1e-3 (no loop over
    # samples: one shifted add per lag)
    x = np.zeros_like(e)
    for k in range(64):
        x[k:] += phi**k * e[: n - k]
    _, cov = mean_and_cov(x)
    truth = sigma_e / (1 - phi) / np.sqrt(n)
    assert np.sqrt(np.diag(cov)) == pytest.approx(np.full(2, truth), rel=0.15)
    naive = x.std(axis=0) / np.sqrt(n)
    assert np.all(naive < 0.3 * truth)


def test_white_noise_error_is_sigma_over_sqrt_n() -> None:
    x = np.random.default_rng(4).normal(0.0, 2.0, (50_000, 3))
    mean, cov = mean_and_cov(x)
    assert mean == pytest.approx(x.mean(axis=0))
    assert np.sqrt(np.diag(cov)) == pytest.approx(np.full(3, 2.0 / np.sqrt(50_000)), rel=0.08)
    assert abs(cov[0, 1]) < 0.2 * cov[0, 0]


def test_short_poses_need_min_s() -> None:
    s = session([(X, np.pi / 2), (Y, np.pi / 2)], seed=5, still_s=[2.4, 1.6, 2.4], move_s=1.0)
    assert len(find_still(s.rec)) == 0  # trimming leaves under 2 s of each
    assert len(find_still(s.rec, min_s=0.5)) == 3


def test_temperature_mean_and_change_inside_an_interval() -> None:
    s = session(TWELVE[:2], seed=6, still_s=10.0, temp=lambda t: 25.0 + 0.02 * t)
    found = find_still(s.rec)
    for iv in found:
        assert iv.temp_change_c == pytest.approx(0.02 * iv.duration_s, rel=1e-6)
        assert iv.temp_c == pytest.approx(25.0 + 0.02 * (iv.t0_s + iv.duration_s / 2), abs=1e-3)


def test_saturation_from_the_flag_and_from_clipped_values() -> None:
    s = session([(X, np.pi / 2), (X, -np.pi / 2)], seed=7, still_s=6.0)  # z, y, z up
    rec = s.rec
    a, b = s.still[1]
    flags = np.zeros(rec.n, dtype=bool)
    flags[(a + b) // 2] = True
    flagged = Recording(rec.t_ns, rec.accel, rec.gyro, None, None, flags, "x")
    assert [iv.saturated for iv in find_still(flagged)] == [False, True, False]
    # no flag from the source: y pinned at a full scale one noise sigma above g, so the y-up
    # pose sits on it for ~16 % of its samples; the others never reach it
    accel = rec.accel.copy()
    accel[:, 1] = np.minimum(accel[:, 1], G + 4e-3 * np.sqrt(500.0))
    clipped = Recording(rec.t_ns, accel, rec.gyro, None, None, None, "x")
    assert [iv.saturated for iv in find_still(clipped)] == [False, True, False]
    assert not any(iv.saturated for iv in find_still(rec))


def test_interval_stats_of_any_span() -> None:
    rec = still_recording(20.0, seed=8)
    iv = interval_stats(rec, 100, 2100)
    assert iv.n == 2000 and iv.t0_s == pytest.approx(0.5)
    assert iv.accel == pytest.approx(rec.accel[100:2100].mean(axis=0))


def test_a_still_recording_is_still() -> None:
    check = check_still(still_recording(60.0, seed=9))
    assert check.still and check.moved == () and check.reason == ""


def test_a_knock_is_reported_with_its_time() -> None:
    rec = with_bump(still_recording(60.0, seed=10), 31.0, 31.6)
    check = check_still(rec)
    assert not check.still
    ((t0, t1),) = check.moved
    assert 30.0 < t0 <= 31.1 and 31.5 <= t1 < 32.5
    assert "moved at 3" in check.reason and "record again" in check.reason


def test_a_slow_tilt_is_caught_by_the_gravity_direction() -> None:
    # 1 deg over 60 s: invisible to a variance test, but it would sit in a gyro bias
    s = session([(X, np.radians(1.0))], seed=11, fs=200.0, still_s=[0.0, 0.0], move_s=60.0)
    rec = s.rec
    assert np.max(rec.gyro[:, 0]) < 0.1  # no single sample shows the motion
    check = check_still(rec)
    assert not check.still
    assert "turned slowly by 0.9" in check.reason or "turned slowly by 1.0" in check.reason


def test_a_still_low_passed_recording_is_refused_no_more_often_than_the_significance() -> None:
    """The slow-turn test's false refusals: 3 s still captures at 500 Hz whose noise went
    through a [1, 2, 1] / 4 low-pass (lag-1 correlation 2/3, as a 98 Hz DLPF at 500 Hz gives).
    At significance 0.01, 1000 captures give ~10 refusals (P(more than 20) ~ 0.1 %); a noise
    estimate blind to the correlation refuses about three times as many."""
    rng = np.random.default_rng(21)
    fs, n, sigma = 500.0, 1500, 0.04
    t_ns = (np.arange(n) * 1e9 / fs).astype(np.int64)
    refused = 0
    for _ in range(1000):
        e = rng.normal(0.0, sigma, (n + 2, 6))
        x = (e[:-2] + 2 * e[1:-1] + e[2:]) / 4
        accel = x[:, :3] + np.array([0.0, 0.0, 9.81])
        rec = Recording(t_ns, accel, x[:, 3:] * 0.01)
        refused += not check_still(rec).still
    assert refused <= 20


def test_too_short_a_recording_is_refused() -> None:
    rec = still_recording(0.05, seed=12)
    with pytest.raises(CalibrationRefused, match="too few"):
        find_still(rec)


def test_a_gyro_capture_that_turned_slowly_is_refused_with_the_turn_named() -> None:
    """Not still and not a set of poses with turns between: the refusal says what moved (the
    still check's finding), not only that too few poses were found."""
    from imud.calib.procedure import run_gyro

    s = session([(X, np.radians(1.0))], seed=11, fs=200.0, still_s=[0.0, 0.0], move_s=60.0)
    with pytest.raises(CalibrationRefused, match=r"turned slowly by (0\.9|1\.0).*found [01]\)"):
        run_gyro(s.rec, full_turns=False)
