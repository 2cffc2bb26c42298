"""The simulator's `poses` motion, the one a calibration runs against without a human, checked
against physics written here: the gyro integrates to the orientation change, the specific force
is gravity rotated into the body, still spans are exactly still, values do not depend on how
time is chunked, the default poses condition a 9-parameter accel fit, the sweep shows the
magnetometer every direction, and the temperature cycle; plus the settings' refusals."""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError

from imud.config import parse_config
from imud.errors import ConfigError
from imud.sim.physics import MagneticField, MotionModel, TemperatureModel
from imud.sim.settings import MagneticSettings, PosesMotion, SimSettings
from tests.helpers import concat, make_rig

G = 9.80665
# a short cycle with a whole extra turn in every move: 12 x (0.5 s hold + 1 s move) + 9 s sweep
FAST = PosesMotion(hold_s=0.5, move_s=1.0, sweep_s=9.0, turns_between=1)


# --- physics written here, independent of imud's quaternion code --------------------------------
def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) arrays (w, x, y, z)."""
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of unit quaternions (N, 4), body -> world."""
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )


def up_in_body(roll_deg: float, pitch_deg: float) -> np.ndarray:
    """World up seen in the body after Rz(yaw) Ry(pitch) Rx(roll): the last row of R."""
    r, p = math.radians(roll_deg), math.radians(pitch_deg)
    return np.array([-math.sin(p), math.cos(p) * math.sin(r), math.cos(p) * math.cos(r)])


def angle_between(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Rotation angle (rad) between orientations, whatever the quaternions' signs."""
    d = qmul(q1 * np.array([1.0, -1.0, -1.0, -1.0]), q2)
    out: np.ndarray = 2 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))
    return out


def cycle(model: MotionModel) -> float:
    """The model's period: a repeating poses profile has one."""
    assert model.period_s is not None
    return model.period_s


def moving_spans(model: MotionModel, period: float) -> list[tuple[float, float]]:
    """The gaps between still spans within one cycle."""
    spans = model.still_spans(period)
    gaps = [(a.end_s, b.start_s) for a, b in itertools.pairwise(spans)]
    return [*gaps, (spans[-1].end_s, period)]


def rk4(model: MotionModel, starts: np.ndarray, duration: float, dt: float) -> np.ndarray:
    """Integrate dq/dt = q (0, w)/2 with the model's gyro from its orientation at each start,
    RK4 at step dt, all spans of one duration at once: the orientations at their ends."""
    steps = round(duration / dt)
    half = starts[:, None] + np.arange(2 * steps + 1)[None, :] * (duration / steps / 2)
    _, w = model.sample(half.ravel())
    w = np.concatenate([np.zeros((w.shape[0], 1)), w], axis=1).reshape(*half.shape, 4)
    q = model.orientation(starts)
    h = duration / steps
    for k in range(steps):
        w0, wm, w1 = w[:, 2 * k], w[:, 2 * k + 1], w[:, 2 * k + 2]
        k1 = 0.5 * qmul(q, w0)
        k2 = 0.5 * qmul(q + 0.5 * h * k1, wm)
        k3 = 0.5 * qmul(q + 0.5 * h * k2, wm)
        k4 = 0.5 * qmul(q + h * k3, w1)
        q = q + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    out: np.ndarray = q / np.linalg.norm(q, axis=1, keepdims=True)
    return out


# --- consistency ----------------------------------------------------------------------------------
def test_the_gyro_integrates_to_the_orientation_change_across_every_move_and_the_sweep() -> None:
    model = MotionModel(FAST)
    period = cycle(model)
    assert period == pytest.approx(12 * 1.5 + 9.0)
    gaps = moving_spans(model, period)
    assert len(gaps) == 12  # eleven moves, then the sweep and the move back in one gap
    moves = np.array([a for a, b in gaps if b - a == pytest.approx(1.0)])
    assert moves.size == 11
    worst = angle_between(rk4(model, moves, 1.0, 1e-3), model.orientation(moves + 1.0)).max()
    assert worst < 1e-6
    # the sweep: three parts of 3 s (each ends where it starts), then the 1 s move back to pose 0
    sweep_start = gaps[-1][0]
    parts = sweep_start + np.array([0.0, 3.0, 6.0])
    end = rk4(model, parts, 3.0, 5e-4)
    assert angle_between(end, model.orientation(parts + 3.0)).max() < 1e-6
    back = np.array([sweep_start + 9.0])
    assert angle_between(rk4(model, back, 1.0, 1e-3), model.orientation(back + 1.0))[0] < 1e-6


def test_a_move_turns_the_whole_extra_turns_it_is_asked_for() -> None:
    """turns_between = 1 ends in the same pose but the gyro sees 360 degrees more."""
    with_turn, plain = MotionModel(FAST), MotionModel(FAST.model_copy(update={"turns_between": 0}))
    t = 0.5 + np.arange(0, 1.0, 1e-4)  # the first move
    turned = [np.linalg.norm(m.sample(t)[1], axis=1).sum() * 1e-4 for m in (with_turn, plain)]
    assert turned[0] - turned[1] == pytest.approx(2 * math.pi, abs=1e-3)
    assert angle_between(with_turn.orientation(t[-1:]), plain.orientation(t[-1:]))[0] < 1e-3


def test_the_force_is_gravity_rotated_into_the_body() -> None:
    """The sensor sits at the centre of rotation: f = R^T (0, 0, g), no centripetal term."""
    model = MotionModel(FAST)
    t = np.linspace(0.0, 2 * cycle(model), 4001)
    f, _ = model.sample(t)
    want = np.einsum("nji,j->ni", matrix(model.orientation(t)), [0.0, 0.0, G])
    np.testing.assert_allclose(f, want, atol=1e-12)


def test_still_spans_have_zero_rate_and_the_poses_gravity() -> None:
    motion = PosesMotion(hold_s=1.0, move_s=1.0, sweep_s=6.0)
    model = MotionModel(motion)
    spans = model.still_spans(cycle(model))
    assert [s.pose for s in spans] == list(range(12))
    assert all(s.end_s - s.start_s == pytest.approx(1.0) for s in spans)
    for s in spans:
        t = np.linspace(s.start_s, s.end_s, 50)
        f, w = model.sample(t)
        assert not w.any()
        assert np.ptp(f, axis=0).max() == 0.0
        roll, pitch, _ = motion.poses[s.pose]
        np.testing.assert_allclose(f[0], G * up_in_body(roll, pitch), atol=1e-12)
    # in between, it moves
    for a, b in moving_spans(model, cycle(model)):
        _, w = model.sample(np.linspace(a, b, 9)[1:-1])
        assert (np.linalg.norm(w, axis=1) > 0.01).all()


def test_spans_repeat_and_a_single_cycle_ends_in_the_first_pose() -> None:
    model = MotionModel(FAST)
    p = cycle(model)
    assert model.still_spans(2.5 * p)[12].start_s == pytest.approx(p)
    assert len(model.still_spans(2.5 * p)) == 12 * 2 + 9  # the 10th hold starts at 2.5 p
    once = MotionModel(FAST.model_copy(update={"repeat": False}))
    assert once.period_s is None
    tail = once.still_spans(10 * p)[-1]
    assert tail.start_s == pytest.approx(p) and (tail.end_s, tail.pose) == (10 * p, 0)
    f, w = once.sample(np.array([p + 1.0, 7 * p]))
    assert not w.any()
    np.testing.assert_array_equal(f, np.tile(once.sample(np.array([0.0]))[0], (2, 1)))


def test_values_do_not_depend_on_how_time_is_chunked() -> None:
    model = MotionModel(FAST)
    t = np.arange(0.0, 1.6 * cycle(model), 1 / 250)
    f, w = model.sample(t)
    q = model.orientation(t)
    cuts = np.sort(np.random.default_rng(3).choice(t.size, 40, replace=False))
    parts = [model.sample(c) for c in np.split(t, cuts)]
    np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), f)
    np.testing.assert_array_equal(np.concatenate([p[1] for p in parts]), w)
    np.testing.assert_array_equal(
        np.concatenate([model.orientation(c) for c in np.split(t, cuts)]), q
    )
    one = [model.sample(t[i : i + 1]) for i in range(0, t.size, 97)]
    np.testing.assert_array_equal(np.concatenate([p[0] for p in one]), f[::97])


def test_the_rate_is_smooth_and_within_the_stated_peak() -> None:
    motion = PosesMotion()
    model = MotionModel(motion)
    t = np.arange(0.0, cycle(model), 1e-3)
    _, w = model.sample(t)
    peak = math.degrees(np.linalg.norm(w, axis=1).max())
    assert peak < 110.0  # the docstring's 102 deg/s, for a 250 deg/s gyro
    assert np.abs(np.diff(w, axis=0)).max() < 1e-3 * 5.0  # < 5 rad/s^2: no step in rate


# --- what a calibration needs from it ------------------------------------------------------------
def test_default_poses_give_nine_distinct_gravity_directions_and_the_six_faces() -> None:
    ups = np.array([up_in_body(r, p) for r, p, _ in PosesMotion().poses])
    distinct: list[np.ndarray] = []
    for u in ups:
        if all(math.degrees(math.acos(min(1.0, float(u @ d)))) > 10.0 for d in distinct):
            distinct.append(u)
    assert len(distinct) >= 9
    for face in np.vstack([np.eye(3), -np.eye(3)]):
        assert (ups @ face > math.cos(math.radians(1.0))).any(), face
    # the 9-parameter fit |C (a - b)| = g, C upper triangular: its Jacobian at C = I, b = 0
    i, j = np.triu_indices(3)
    jac = np.hstack([ups[:, i] * ups[:, j], -ups])
    sv = np.linalg.svd(jac, compute_uv=False)
    assert sv[-1] > 0 and sv[0] / sv[-1] < 5.0


@pytest.mark.parametrize(
    ("inclination", "declination"), [(60.0, 0.0), (-70.0, 15.0), (0.0, 90.0), (89.0, -30.0)]
)
def test_one_cycle_shows_the_magnetometer_every_direction(
    inclination: float, declination: float
) -> None:
    """The body-frame field's direction over one cycle, on a 60-cell equal-area grid (6 bands
    equal in z, 10 in longitude)."""
    model = MotionModel(PosesMotion())
    field = MagneticField(
        MagneticSettings(inclination_deg=inclination, declination_deg=declination),
        np.random.default_rng(0),
    )
    b = field.in_body(model.orientation(np.arange(0.0, cycle(model), 0.05)))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    band = np.minimum(((b[:, 2] + 1) * 3).astype(int), 5)
    lon = ((np.arctan2(b[:, 1], b[:, 0]) + math.pi) / (2 * math.pi) * 10).astype(int) % 10
    assert len(set(zip(band.tolist(), lon.tolist(), strict=True))) / 60 >= 0.9


def test_a_simulated_chip_runs_the_profile_and_its_truth_follows_it() -> None:
    rig = make_rig(
        {"odr_hz": 100},
        {"motion": {"kind": "poses", "hold_s": 0.5, "move_s": 0.5, "sweep_s": 0.0}},
    )
    rig.run(4.0)
    truth = concat(rig.truth_batches())
    t = (truth["t_ns"] - rig.sim.t_origin_ns) / 1e9
    f, w = rig.sim.motion.sample(t)
    np.testing.assert_allclose(truth["accel"], f, atol=1e-5)  # float32 on the wire
    np.testing.assert_allclose(truth["gyro"], w, atol=1e-6)
    assert (np.abs(w).max(axis=1) > 0).any() and (w == 0).all(axis=1).any()


# --- temperature ---------------------------------------------------------------------------------
def test_the_temperature_cycle_swings_between_the_limits_from_the_start_upward() -> None:
    s = SimSettings(temperature_c=25.0, temperature_limits_c=(10.0, 50.0), temperature_cycle_min=20)
    model = TemperatureModel(s)
    t = np.arange(0.0, 2400.0, 0.5)
    temp = model.at(t)
    assert temp[0] == pytest.approx(25.0) and temp[1] > temp[0]
    assert temp.min() == pytest.approx(10.0, abs=1e-3) and temp.max() == pytest.approx(
        50.0, abs=1e-3
    )
    np.testing.assert_allclose(model.at(t + 1200.0), temp, atol=1e-9)  # the period: 20 min
    slope = np.abs(np.diff(temp)).max() / 0.5
    assert slope == pytest.approx(20.0 * 2 * math.pi / 1200.0, rel=1e-3)  # a sine, no steps
    # a start outside the limits begins at the nearer one
    cold = TemperatureModel(s.model_copy(update={"temperature_c": -5.0}))
    assert cold.at(np.array([0.0]))[0] == pytest.approx(10.0)


def test_the_default_temperature_is_still_the_clipped_ramp() -> None:
    s = SimSettings(
        temperature_c=20.0, temperature_ramp_c_per_min=2.0, temperature_limits_c=(0, 30)
    )
    t = np.array([0.0, 60.0, 240.0, 600.0])
    np.testing.assert_array_equal(TemperatureModel(s).at(t), [20.0, 22.0, 28.0, 30.0])
    assert (TemperatureModel(SimSettings()).at(t) == 25.0).all()


# --- settings -------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("motion", "says"),
    [
        ({"poses": []}, "no poses: list at least one [roll, pitch, yaw]"),
        ({"poses": [[0, 0, float("nan")]]}, "pose 0 is [0.0, 0.0, nan]: angles must be finite"),
        ({"hold_s": -1.0}, "greater than 0"),
        ({"move_s": 0.0}, "greater than 0"),
        ({"sweep_s": -5.0}, "greater than or equal to 0"),
        ({"turns_between": -1}, "greater than or equal to 0"),
        ({"speed": 2.0}, "Extra inputs are not permitted"),
    ],
)
def test_bad_poses_settings_are_refused(motion: dict[str, Any], says: str) -> None:
    with pytest.raises(ValidationError, match=r".*") as e:
        SimSettings.model_validate({"motion": {"kind": "poses", **motion}})
    assert says in str(e.value)


@pytest.mark.parametrize(
    ("sim", "says"),
    [
        (
            {"temperature_cycle_min": 10, "temperature_limits_c": [40, 10]},
            "temperature_cycle_min needs temperature_limits_c = [low, high] with high > low",
        ),
        (
            {"temperature_cycle_min": 10, "temperature_ramp_c_per_min": 1.0},
            "temperature_cycle_min and temperature_ramp_c_per_min both set",
        ),
        ({"temperature_cycle_min": -1}, "greater than or equal to 0"),
    ],
)
def test_bad_temperature_settings_are_refused(sim: dict[str, Any], says: str) -> None:
    with pytest.raises(ValidationError) as e:
        SimSettings.model_validate(sim)
    assert says in str(e.value)


def test_a_config_names_the_device_and_field_of_a_bad_pose_setting() -> None:
    device = {"name": "cal0", "chip": "mpu6050", "bus": {"kind": "sim"}}
    ok = parse_config({"device": [{**device, "sim": {"motion": {"kind": "poses"}}}]})
    sim = ok.device[0].sim
    assert sim is not None and isinstance(sim.motion, PosesMotion)
    bad = {**device, "sim": {"motion": {"kind": "poses", "hold_s": -2.0}}}
    with pytest.raises(ConfigError) as e:
        parse_config({"device": [bad]})
    assert "device[0] 'cal0' (mpu6050): sim.motion.hold_s = -2.0: Input should be greater" in str(
        e.value
    )
