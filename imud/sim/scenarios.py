"""Motion scenarios with known truth for orientation filters: the orientation of every sample and
what an IMU strapped to the body would read (gyro with bias and white noise, accelerometer with
gravity, linear acceleration, vibration and white noise, optionally a magnetometer).

Frames: world ENU (z up), body FLU; quaternions w, x, y, z rotating body vectors into the world.
An accelerometer reads specific force, +g on z when level and still. The gyro reads the body rate
at the middle of each sample interval (what a rate-integrating sensor's sample stands for), so a
noise- and bias-free gyro integrated sample by sample reproduces the truth.

`reference()` is the scenario of the fusion anchors (60 s at 1 kHz, 0.5 deg/s bias per axis,
MPU6050-grade noise: 0.005 deg/s/sqrt(Hz) and 400 ug/sqrt(Hz) two-sided, per-sample sigma =
density * sqrt(rate)); `drone_hover()` and `car()` add what the reference lacks: a 100 Hz
vibration with its harmonics, and sustained linear acceleration in turns and speed changes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from imud.rotations import quat_conj, quat_exp, quat_mul, quat_rotate

F64 = npt.NDArray[np.float64]
G = 9.80665
DEG = math.pi / 180.0
MICRO_G = 1e-6 * G
# Earth's field (tesla) at 50 deg N, ENU: 18 uT north, 45 uT down
FIELD_ENU = np.array([0.0, 18e-6, -45e-6])

Euler = Callable[[F64], tuple[F64, F64, F64]]  # t (s) -> roll, pitch, yaw (rad)
Vector = Callable[[F64], F64]  # t (s) -> (n, 3)


@dataclass(frozen=True)
class Scenario:
    name: str
    rate_hz: float
    t_s: F64  # (n,)
    truth: F64  # (n, 4) body -> world at each sample instant
    gyro: F64  # (n, 3) rad/s
    accel: F64  # (n, 3) m/s^2
    mag: F64 | None  # (n, 3) T, or None
    gyro_bias: F64  # (3,) rad/s
    gyro_density: float  # two-sided white noise, rad/s/sqrt(Hz)
    accel_density: float  # m/s^2/sqrt(Hz)
    mag_sigma: float | None  # T per sample
    linear: F64  # (n, 3) world-frame linear acceleration, m/s^2 (zero in the reference)

    @property
    def dt(self) -> float:
        return 1.0 / self.rate_hz


def euler_quat(roll: F64, pitch: F64, yaw: F64) -> F64:
    """Quaternions (n, 4) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )


def body_rate(euler: Euler, t: F64, h: float = 1e-5) -> F64:
    """Body angular rate (n, 3) of a ZYX Euler trajectory (central differences of the angles)."""
    r, p, _ = euler(t)
    a, b = euler(t + h), euler(t - h)
    dr, dp, dy = ((x - y) / (2 * h) for x, y in zip(a, b, strict=True))
    return np.stack(
        [
            dr - dy * np.sin(p),
            dp * np.cos(r) + dy * np.sin(r) * np.cos(p),
            -dp * np.sin(r) + dy * np.cos(r) * np.cos(p),
        ],
        axis=-1,
    )


def to_body(q: F64, v: F64) -> F64:
    """World vectors (n, 3) in the body frame of each q (n, 4)."""
    return quat_rotate(quat_conj(q), v)


def make(
    name: str,
    euler: Euler,
    seconds: float,
    rate_hz: float,
    *,
    bias_deg_s: tuple[float, float, float],
    gyro_density: float,
    accel_density: float,
    seed: int,
    linear: Vector | None = None,
    vibration: Vector | None = None,
    angular_vibration: Vector | None = None,
    mag_sigma: float | None = None,
) -> Scenario:
    """A scenario from its attitude trajectory and the sensor's imperfections: `linear` is a
    world-frame linear acceleration, `vibration` a body-frame one (the frame shaking the
    sensor), `angular_vibration` a body-frame rate added to the trajectory's (all of t)."""
    rng = np.random.default_rng(seed)
    n = round(seconds * rate_hz)
    dt = 1.0 / rate_hz
    t: F64 = np.arange(1, n + 1, dtype=np.float64) * dt
    truth = euler_quat(*euler(t))
    half: F64 = t - dt / 2
    rate = body_rate(euler, half)
    if angular_vibration is not None:
        # a rate added in the body frame: its angle (the integral) rotates the truth too
        wobble = angular_vibration(half)
        angle: F64 = np.cumsum(wobble, axis=0) * dt
        truth = quat_mul(truth, quat_exp(angle))
        # the body rate of the rotation exp(angle) is d(angle)/dt - angle x d(angle)/dt / 2 to
        # second order (Bortz): the cross term is the coning a shake about two axes out of
        # phase makes, a steady turn the gyro measures and the truth holds
        mid = angle - 0.5 * wobble * dt
        rate = rate + wobble - 0.5 * np.cross(mid, wobble)
    bias = np.array(bias_deg_s) * DEG
    gyro = rate + bias + rng.normal(0.0, gyro_density * math.sqrt(rate_hz), (n, 3))
    lin: F64 = np.zeros((n, 3)) if linear is None else linear(t)
    up: F64 = lin + np.array([0.0, 0.0, G])
    force = to_body(truth, up)
    if vibration is not None:
        force = force + vibration(t)
    accel = force + rng.normal(0.0, accel_density * math.sqrt(rate_hz), (n, 3))
    mag = None
    if mag_sigma is not None:
        mag = to_body(truth, np.broadcast_to(FIELD_ENU, (n, 3)).copy())
        mag = mag + rng.normal(0.0, mag_sigma, (n, 3))
    return Scenario(
        name, rate_hz, t, truth, gyro, accel, mag, bias, gyro_density, accel_density,
        mag_sigma, lin,
    )  # fmt: skip


def reference(
    seed: int = 0, seconds: float = 60.0, bias_deg_s: tuple[float, float, float] | None = None
) -> Scenario:
    """The fusion anchors' scenario (docs/orientation.md: where its figures for Fusion, Madgwick
    and Mahony come from)."""

    def euler(t: F64) -> tuple[F64, F64, F64]:
        roll = 40 * DEG * np.sin(2 * np.pi * 0.11 * t) + 10 * DEG * np.sin(2 * np.pi * 0.5 * t)
        pitch = 25 * DEG * np.sin(2 * np.pi * 0.07 * t + 0.5)
        yaw = 120 * DEG * np.sin(2 * np.pi * 0.03 * t) + 5 * DEG * t
        return roll, pitch, yaw

    return make(
        "reference", euler, seconds, 1000.0, bias_deg_s=bias_deg_s or (0.5, -0.5, 0.5),
        gyro_density=0.005 * DEG, accel_density=400 * MICRO_G, seed=seed,
    )  # fmt: skip


def gauss_markov(seed: int, sigma: float, tau_s: float, seconds: float, rate_hz: float) -> Vector:
    """A horizontal linear acceleration drawn from a first-order Gauss-Markov process (standard
    deviation `sigma` per axis, time constant `tau_s`, stationary from the first sample), held
    between its samples: the orientation filter's own model of the platform's acceleration."""
    n = round(seconds * rate_hz) + 1
    rng = np.random.default_rng(seed + 2000)
    rho = math.exp(-1.0 / (rate_hz * tau_s))
    w = rng.normal(0.0, sigma * math.sqrt(1.0 - rho * rho), (n, 2))
    a = np.empty((n, 2))
    a[0] = rng.normal(0.0, sigma, 2)
    for k in range(1, n):  # a recursion: once per scenario, outside any filter's timing
        a[k] = rho * a[k - 1] + w[k]

    def linear(t: F64) -> F64:
        k = np.minimum(np.round(t * rate_hz).astype(np.int64), n - 1)
        return np.column_stack([a[k], np.zeros(len(t))])

    return linear


def drone_hover(
    seed: int = 0,
    seconds: float = 60.0,
    mag: bool = False,
    bias_deg_s: tuple[float, float, float] | None = None,
    hold_sigma: float | None = None,
) -> Scenario:
    """A multirotor holding position: a few degrees of slow attitude corrections, a slow yaw,
    and its motors' 100 Hz vibration (with the 200 Hz harmonic) shaking the sensor: 4 m/s^2 of
    linear and 20 deg/s of angular vibration, plus the small accelerations that hold it in place
    (a 0.3 m/s^2 sway; with `hold_sigma`, a Gauss-Markov process of that standard deviation and a
    1-s time constant instead: the orientation filter's own model, to check its consistency
    where the model holds)."""
    ph = np.random.default_rng(seed + 1000).uniform(0, 2 * np.pi, 8)

    def euler(t: F64) -> tuple[F64, F64, F64]:
        roll = 3 * DEG * np.sin(2 * np.pi * 0.4 * t + ph[0]) + 1.5 * DEG * np.sin(
            2 * np.pi * 1.3 * t
        )
        pitch = 3 * DEG * np.sin(2 * np.pi * 0.33 * t + ph[1]) + 1 * DEG * np.sin(
            2 * np.pi * 1.1 * t
        )
        yaw = 30 * DEG * np.sin(2 * np.pi * 0.02 * t + ph[2])
        return roll, pitch, yaw

    def shake(t: F64) -> F64:
        return np.column_stack(
            [
                3.0 * np.sin(2 * np.pi * 100 * t + ph[3]) + 1.0 * np.sin(2 * np.pi * 200 * t),
                2.5 * np.sin(2 * np.pi * 100 * t + ph[4]) + 0.8 * np.sin(2 * np.pi * 200 * t + 1),
                4.0 * np.sin(2 * np.pi * 100 * t + ph[5]) + 1.5 * np.sin(2 * np.pi * 200 * t + 2),
            ]
        )

    def wobble(t: F64) -> F64:
        return 20 * DEG * np.column_stack(
            [np.sin(2 * np.pi * 100 * t + ph[6]), np.sin(2 * np.pi * 100 * t + ph[7]),
             0.3 * np.sin(2 * np.pi * 100 * t)]
        )  # fmt: skip

    def hold(t: F64) -> F64:
        # the thrust tilt that holds position against the wind: tilt angle x g, horizontally
        return 0.3 * np.column_stack(
            [np.sin(2 * np.pi * 0.4 * t + ph[0]), np.sin(2 * np.pi * 0.33 * t + ph[1]), 0 * t]
        )  # fmt: skip

    return make(
        "drone_hover", euler, seconds, 1000.0, bias_deg_s=bias_deg_s or (0.4, -0.3, 0.5),
        gyro_density=0.005 * DEG, accel_density=400 * MICRO_G, seed=seed,
        linear=hold if hold_sigma is None else gauss_markov(seed, hold_sigma, 1.0, seconds, 1000.0),
        vibration=shake, angular_vibration=wobble, mag_sigma=0.3e-6 if mag else None,
    )  # fmt: skip


def car(
    seed: int = 0,
    seconds: float = 60.0,
    mag: bool = False,
    bias_deg_s: tuple[float, float, float] | None = None,
) -> Scenario:
    """A car driving a loop: accelerating at 3 m/s^2, cruising, turning (the centripetal
    acceleration, v x yaw rate, is sustained for seconds), braking; the body pitches and rolls
    against those accelerations and the road shakes it (15 Hz, 1 m/s^2)."""
    dt = 1e-3
    tt = np.arange(0.0, seconds + 1.0, dt)
    # longitudinal acceleration profile and yaw rate profile, smooth
    acc = (
        3.0 * _bump(tt, 2, 6)
        - 3.0 * _bump(tt, 20, 23)
        + 2.0 * _bump(tt, 30, 34)
        - 2.5 * _bump(tt, 50, 54)
    )
    yaw_rate = 12 * DEG * _bump(tt, 8, 16) - 15 * DEG * _bump(tt, 36, 44)
    speed = np.cumsum(acc) * dt
    yaw = np.cumsum(yaw_rate) * dt
    ph = np.random.default_rng(seed + 2000).uniform(0, 2 * np.pi, 3)

    def interp(x: F64, t: F64) -> F64:
        return np.interp(t, tt, x)

    def euler(t: F64) -> tuple[F64, F64, F64]:
        # the body leans against its acceleration: 0.6 deg per m/s^2
        a_lon = interp(acc, t)
        a_lat = interp(speed * yaw_rate, t)
        pitch = -0.6 * DEG * a_lon + 0.3 * DEG * np.sin(2 * np.pi * 1.7 * t + ph[0])
        roll = 0.6 * DEG * a_lat + 0.3 * DEG * np.sin(2 * np.pi * 1.3 * t + ph[1])
        return roll, pitch, interp(yaw, t)

    def linear(t: F64) -> F64:
        y = interp(yaw, t)
        a_lon, a_lat = interp(acc, t), interp(speed * yaw_rate, t)
        fwd = np.column_stack([np.cos(y), np.sin(y), 0 * t])
        left = np.column_stack([-np.sin(y), np.cos(y), 0 * t])
        out: F64 = fwd * a_lon[:, None] + left * a_lat[:, None]
        return out

    def road(t: F64) -> F64:
        return np.column_stack(
            [0.3 * np.sin(2 * np.pi * 15 * t + ph[2]), 0.3 * np.sin(2 * np.pi * 11 * t),
             1.0 * np.sin(2 * np.pi * 15 * t)]
        )  # fmt: skip

    return make(
        "car", euler, seconds, 1000.0, bias_deg_s=bias_deg_s or (-0.3, 0.4, 0.5),
        gyro_density=0.005 * DEG, accel_density=400 * MICRO_G, seed=seed,
        linear=linear, vibration=road, mag_sigma=0.3e-6 if mag else None,
    )  # fmt: skip


def _bump(t: F64, t0: float, t1: float) -> F64:
    """1 between t0 and t1 with 1-s raised-cosine edges, 0 elsewhere."""
    up = np.clip((t - t0) / 1.0, 0, 1)
    down = np.clip((t1 - t) / 1.0, 0, 1)
    out: F64 = 0.5 - 0.5 * np.cos(np.pi * np.minimum(up, down))
    return out
