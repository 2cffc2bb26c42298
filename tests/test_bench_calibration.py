"""A fast smoke run of bench/calibration_accuracy.py: its physics and its yardsticks checked on
their own, and every section run with a few trials. Nothing here depends on timing; the
figures a few trials give are too noisy to judge, so only what holds in every trial is asserted."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from imud.calib.accel import fit_accel

BENCH = Path(__file__).resolve().parent.parent / "bench" / "calibration_accuracy.py"


def _load() -> ModuleType:
    spec = importlib.util.spec_from_file_location("calibration_accuracy", BENCH)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up by name
    spec.loader.exec_module(mod)
    return mod


ca = _load()


def test_the_identifiable_truth_is_what_a_nearly_noise_free_fit_returns() -> None:
    rng = np.random.default_rng(1)
    truth = ca.AccelTruth.draw(rng)
    # the correction's upper-triangular factor: A^-1 = R U with R a rotation
    rot = np.linalg.inv(truth.a) @ np.linalg.inv(truth.u)
    assert np.allclose(rot @ rot.T, np.eye(3)) and np.linalg.det(rot) > 0
    assert np.allclose(np.tril(truth.u, -1), 0.0) and np.all(np.diag(truth.u) > 0)
    sess = ca.pose_session(
        rng,
        truth,
        ca.hand_placed(rng),
        hold_s=4.0,
        move_s=1.0,
        accel_density=ca.ACCEL_DENSITY * 1e-3,
        gyro_density=ca.GYRO_DENSITY * 1e-3,
    )
    # U (raw - b) has the norm g in every still pose, whatever the rotation R is
    clean = ca.G * sess.directions @ truth.a.T + truth.b
    np.testing.assert_allclose(np.linalg.norm((clean - truth.b) @ truth.u.T, axis=1), ca.G)
    assert [b - a for a, b in sess.holds] == [2000] * 12
    res = fit_accel(sess.rec, ca.G, "full")
    assert len(res.intervals) == 12
    np.testing.assert_allclose(res.estimate.fit.values, truth.theta, atol=2e-5)


def test_hand_placed_poses_are_a_few_degrees_off_their_nominal_directions() -> None:
    dirs = ca.hand_placed(np.random.default_rng(2))
    nominal = np.array(ca.FACE_CORNER_ORDER, dtype=float)
    nominal /= np.linalg.norm(nominal, axis=1, keepdims=True)
    off = np.degrees(np.arccos(np.clip(np.sum(dirs * nominal, axis=1), -1.0, 1.0)))
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0)
    assert np.all(off <= 5.0) and np.any(off > 0.5)
    # every move between consecutive poses is the 55 degree face-corner tilt, give or take
    moves = np.degrees(np.arccos(np.sum(nominal[1:] * nominal[:-1], axis=1)))
    assert np.allclose(moves, math.degrees(math.acos(1.0 / math.sqrt(3.0))))


def test_the_gyro_rate_integrates_to_the_turn_between_poses() -> None:
    """The body rate the session writes carries gravity from one pose to the next: integrating
    df/dt = -w x f from the first pose lands on the second."""
    rng = np.random.default_rng(3)
    truth = ca.AccelTruth.draw(rng)
    dirs = ca.hand_placed(rng)[:2]
    sess = ca.pose_session(
        rng, truth, dirs, hold_s=1.0, move_s=2.0, accel_density=0.0, gyro_density=0.0
    )
    w_raw = sess.rec.gyro
    bias = w_raw[0]
    f = ca.G * dirs[0]
    dt = 1.0 / ca.RATE_HZ
    for w in w_raw[sess.holds[0][1] : sess.holds[1][0]] - bias:  # each rate held for dt
        rate = float(np.linalg.norm(w))
        if rate > 0:
            f = ca.rotate(f, -w / rate, np.array(rate * dt))
    cos = float(f @ dirs[1]) / float(np.linalg.norm(f))
    assert math.degrees(math.acos(min(cos, 1.0))) < 0.05


def test_the_cramer_rao_bound_agrees_with_the_fits_own_covariance() -> None:
    """Written separately from the estimator's covariance (at the truth, with the noise taken
    from each pose's own samples): on one recording they agree to a few percent."""
    rng = np.random.default_rng(4)
    truth = ca.AccelTruth.draw(rng)
    sess = ca.pose_session(rng, truth, ca.hand_placed(rng))
    crb = ca.accel_crb(truth, sess)
    est = fit_accel(sess.rec, ca.G, "full").estimate
    ratio = est.fit.sigma() / np.sqrt(np.diag(crb))
    assert np.all(ratio > 0.9) and np.all(ratio < 1.15)


def test_the_seed_min_max_formula() -> None:
    """An axis-aligned ellipsoid with known centre and semi-axes: min/max gets it exactly."""
    centre = np.array([1.0, -2.0, 3.0])
    semi = np.array([2.0, 4.0, 6.0])
    pts = np.vstack([np.diag(semi), -np.diag(semi)]) + centre
    off, scale, radius = ca.seed_min_max(pts)
    np.testing.assert_allclose(off, centre)
    assert radius == pytest.approx(4.0)
    np.testing.assert_allclose(np.diag(scale), [2.0, 1.0, 4.0 / 6.0])


def test_every_section_runs_and_prints_its_table(capsys: pytest.CaptureFixture[str]) -> None:
    code = ca.main(["--trials", "3"])
    out = capsys.readouterr().out
    assert code in (0, 1)
    assert out.startswith("command: ")
    for section in ("accel", "gyro", "temp", "mag"):
        assert f"{section}: 3 trials in" in out
    assert "judged at >= 200 trials" in out  # per-parameter coverage is not judged on 3
    assert "judged figures FAIL" in out


def test_the_magnetometer_figures_hold_with_margin_in_every_trial() -> None:
    """Far below their bounds (several times), so a few trials already show it; min/max is
    percents and degrees off."""
    rows = {r.figure: r for r in ca.mag_rows(3, seed=5, evaluate=500)}
    assert rows["ellipsoid fit: field-norm error RMS"].ok
    assert rows["ellipsoid fit: direction error RMS"].ok
    assert float(rows["    seed's min/max: field-norm error RMS"].value.split()[0]) > 1.0
