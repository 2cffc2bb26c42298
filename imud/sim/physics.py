"""Physics shared by the chip simulators: motion, temperature and the IMU error model.

Measurement model (per sensor): m = M @ S @ (x + b0 + k_T (T - 25 C) + b_gm(t)) + n, with M a
misalignment matrix, S diagonal scale, b0 a turn-on bias, k_T a linear temperature drift, b_gm a
Gauss-Markov bias (bias instability), and n white noise of the datasheet density: per-sample sigma
= density * sqrt(rate), the discrete equivalent Allan deviation sees. The chip's low-pass filter
colouring of that noise and its group delay are not modelled.

For chips that estimate orientation or sense the magnetic field: the motion's true orientation as
a quaternion (body -> world, ENU), and the Earth's field with a board's hard and soft iron.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from imud.sim.settings import (
    ErrorSettings,
    MagneticSettings,
    SimSettings,
    StillMotion,
    TumbleMotion,
)

G = 9.80665
F64 = npt.NDArray[np.float64]


def rotation_zyx(roll_deg: float, pitch_deg: float, yaw_deg: float) -> F64:
    """Body-to-world rotation R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = (math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg))
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


class MotionModel:
    """True specific force (m/s^2) and angular rate (rad/s) in the body frame at times t (s).

    World frame ENU: a body at rest feels +g along world up.
    """

    def __init__(self, motion: StillMotion | TumbleMotion) -> None:
        r0 = rotation_zyx(motion.roll_deg, motion.pitch_deg, motion.yaw_deg)
        self._f0 = r0.T @ np.array([0.0, 0.0, G])
        rate = np.radians(motion.rate_dps) if isinstance(motion, TumbleMotion) else np.zeros(3)
        self._w = np.asarray(rate, dtype=np.float64)
        speed = float(np.linalg.norm(self._w))
        u = self._w / speed if speed else self._w
        self._uxv = np.cross(u, self._f0)  # Rodrigues terms, constant for a constant rate
        self._uuv = u * float(u @ self._f0)
        # the true orientation (body -> world), for chips that estimate it: R(t) = R0 exp(t [w]x)
        self._q0 = quat_from_euler_zyx(motion.roll_deg, motion.pitch_deg, motion.yaw_deg)
        self._u = u
        self._speed = speed

    def sample(self, t_s: F64) -> tuple[F64, F64]:
        n = t_s.shape[0]
        w = np.broadcast_to(self._w, (n, 3)).copy()
        speed = float(np.linalg.norm(self._w))
        if speed == 0.0:
            return np.broadcast_to(self._f0, (n, 3)).copy(), w
        # A world-fixed vector seen from a body turning at w rotates by -|w| t about w (Rodrigues)
        a = -speed * t_s[:, None]
        return self._f0 * np.cos(a) + self._uxv * np.sin(a) + self._uuv * (1 - np.cos(a)), w

    def orientation(self, t_s: F64) -> F64:
        """True orientation at times t: unit quaternions (w, x, y, z), body -> world (ENU),
        shape (N, 4); the same rotation `sample` applies to gravity."""
        n = t_s.shape[0]
        if self._speed == 0.0:
            return np.broadcast_to(self._q0, (n, 4)).copy()
        half = 0.5 * self._speed * t_s
        turn = np.empty((n, 4))
        turn[:, 0] = np.cos(half)
        turn[:, 1:] = self._u * np.sin(half)[:, None]
        return quat_mul(self._q0, turn)


# --- quaternions: (w, x, y, z), Hamilton product, q rotates body vectors into the world ---------
def quat_mul(a: F64, b: F64) -> F64:
    """Hamilton product a b, for (4,) or (N, 4) arrays (broadcast)."""
    aw, ax, ay, az = (a[..., i] for i in range(4))
    bw, bx, by, bz = (b[..., i] for i in range(4))
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conj(q: F64) -> F64:
    """The inverse rotation of a unit quaternion."""
    out: F64 = q * np.array([1.0, -1.0, -1.0, -1.0])
    return out


def _cross(a: F64, b: F64) -> F64:
    """np.cross for (..., 3) arrays, without its axis handling (a hot path of the simulators)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def quat_rotate(q: F64, v: F64) -> F64:
    """v rotated by q (q v q*), for (4,)/(N, 4) quaternions and (3,)/(N, 3) vectors."""
    w = q[..., :1]
    r = q[..., 1:]
    t = 2.0 * _cross(r, v)
    out: F64 = v + w * t + _cross(r, t)
    return out


def quat_from_axis_angle(axis: F64, angle_rad: float) -> F64:
    """The rotation by `angle_rad` about the unit vector `axis`."""
    half = 0.5 * angle_rad
    return np.concatenate([[math.cos(half)], np.asarray(axis, dtype=np.float64) * math.sin(half)])


def quat_from_euler_zyx(roll_deg: float, pitch_deg: float, yaw_deg: float) -> F64:
    """The quaternion of `rotation_zyx`: Rz(yaw) Ry(pitch) Rx(roll)."""
    z = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), math.radians(yaw_deg))
    y = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), math.radians(pitch_deg))
    x = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(roll_deg))
    return quat_mul(quat_mul(z, y), x)


def quat_from_matrix(m: F64) -> F64:
    """The unit quaternion of a proper rotation matrix (Shepperd's method: stable for every
    rotation, including half turns)."""
    tr = float(np.trace(m))
    cands = [tr, m[0, 0], m[1, 1], m[2, 2]]
    i = int(np.argmax(cands))
    if i == 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif i == 1:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif i == 2:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    out = np.array(q)
    result: F64 = out if out[0] >= 0 else -out
    return result


class MagneticField:
    """The Earth's field in the world frame (ENU) and what a magnetometer on the board reads:
    m = A b_body + h + n (soft iron A, hard iron h, white noise n), in tesla."""

    def __init__(self, s: MagneticSettings, rng: np.random.Generator) -> None:
        b = s.field_ut * 1e-6
        inc, dec = math.radians(s.inclination_deg), math.radians(s.declination_deg)
        horizontal = b * math.cos(inc)  # toward magnetic north, `dec` east of true north
        self.world = np.array([horizontal * math.sin(dec), horizontal * math.cos(dec),
                               -b * math.sin(inc)])  # fmt: skip
        self.soft_iron = np.asarray(s.soft_iron, dtype=np.float64)
        self.hard_iron = np.asarray(s.hard_iron_ut, dtype=np.float64) * 1e-6
        self.noise = s.noise_ut * 1e-6
        self.declination_rad = dec
        self.rng = rng

    def in_body(self, q: F64) -> F64:
        """The true field in the body frame of orientations q (N, 4): (N, 3) tesla."""
        return quat_rotate(quat_conj(q), self.world)

    def measure(self, b_body: F64) -> F64:
        """What the magnetometer reads of the true body-frame field."""
        m: F64 = b_body @ self.soft_iron.T + self.hard_iron
        if self.noise > 0:
            m = m + self.rng.normal(0.0, self.noise, m.shape)
        return m


class TemperatureModel:
    def __init__(self, s: SimSettings) -> None:
        self.t0 = s.temperature_c
        self.ramp = s.temperature_ramp_c_per_min / 60.0
        self.lo, self.hi = s.temperature_limits_c

    def at(self, t_s: F64) -> F64:
        return np.clip(self.t0 + self.ramp * t_s, self.lo, self.hi)


@dataclass(frozen=True)
class ChipFigures:
    """A chip's datasheet error figures: the simulator's defaults."""

    accel_noise_ug_rthz: float
    gyro_noise_dps_rthz: float
    accel_bias_mg: float  # 1-sigma turn-on bias
    gyro_bias_dps: float
    accel_bias_instability_ug: float
    gyro_bias_instability_dph: float
    scale_error: float  # 1-sigma fraction
    misalignment_deg: float  # 1-sigma cross-axis angle
    accel_temp_drift_mg_per_c: float
    gyro_temp_drift_dps_per_c: float


class GaussMarkovBias:
    """Three-axis first-order Gauss-Markov bias on a fixed knot grid, linearly interpolated, so the
    sequence depends only on the seed, not on how the reader chunks time."""

    def __init__(self, sigma: float, rng: np.random.Generator, tau_s: float = 100.0) -> None:
        self.sigma = sigma
        self.rng = rng
        self.dt = 0.1
        self.phi = math.exp(-self.dt / tau_s)
        self.q = sigma * math.sqrt(1 - self.phi**2)
        self.first = 0  # knot index of knots[0]
        self.knots: list[F64] = [rng.normal(0.0, sigma, 3) if sigma > 0 else np.zeros(3)]

    def at(self, t_s: F64) -> F64:
        if self.sigma == 0.0 or t_s.size == 0:
            return np.zeros((t_s.shape[0], 3))
        need = math.floor(float(t_s[-1]) / self.dt) + 2
        while self.first + len(self.knots) < need:
            self.knots.append(self.phi * self.knots[-1] + self.rng.normal(0.0, self.q, 3))
        lo = max(math.floor(float(t_s[0]) / self.dt), self.first)
        if lo > self.first:  # readers only move forward: forget what is behind them
            del self.knots[: lo - self.first]
            self.first = lo
        k = np.asarray(self.knots)
        grid = (self.first + np.arange(len(k))) * self.dt
        return np.stack([np.interp(t_s, grid, k[:, i]) for i in range(3)], axis=1)


def _vec(v: tuple[float, float, float] | None, draw: F64, scale: float) -> F64:
    return np.asarray(v, dtype=np.float64) * scale if v is not None else draw


class SensorErrors:
    """Deterministic errors of one 3-axis sensor, drawn once from the seed."""

    def __init__(
        self,
        rng: np.random.Generator,
        noise: float,
        bias: F64,
        instability: float,
        scale_err: F64,
        misalign_rad: float,
        drift: F64,
        gm_rng: np.random.Generator,
    ) -> None:
        self.noise = noise  # density, SI/sqrt(Hz)
        self.bias = bias
        self.drift = drift
        skew = rng.normal(0.0, misalign_rad, (3, 3)) if misalign_rad > 0 else np.zeros((3, 3))
        np.fill_diagonal(skew, 0.0)
        self.matrix = (np.eye(3) + skew) @ np.diag(1.0 + scale_err)
        self.gm = GaussMarkovBias(instability, gm_rng)

    def apply(
        self, t_s: F64, x: F64, temp_c: F64, rate_hz: float, noise_rng: np.random.Generator
    ) -> F64:
        b = self.bias + np.outer(temp_c - 25.0, self.drift) + self.gm.at(t_s)
        y = (x + b) @ self.matrix.T
        if self.noise > 0:
            y += noise_rng.normal(0.0, self.noise * math.sqrt(rate_hz), y.shape)
        return y


class ErrorModel:
    """Accel and gyro errors of one simulated chip, from its figures, overrides and seed."""

    def __init__(self, figures: ChipFigures, s: SimSettings, stream: int = 0) -> None:
        e: ErrorSettings = s.errors
        seeds = np.random.SeedSequence([s.seed, stream]).spawn(5)
        draw = np.random.default_rng(seeds[0])
        self.noise_rng = np.random.default_rng(seeds[1])
        on = 0.0 if e.ideal else 1.0
        f = figures
        mg = 1e-3 * G
        a_noise = (
            e.accel_noise_ug_rthz if e.accel_noise_ug_rthz is not None else f.accel_noise_ug_rthz
        )
        g_noise = (
            e.gyro_noise_dps_rthz if e.gyro_noise_dps_rthz is not None else f.gyro_noise_dps_rthz
        )
        a_inst = (
            e.accel_bias_instability_ug
            if e.accel_bias_instability_ug is not None
            else (f.accel_bias_instability_ug * on)
        )
        g_inst = (
            e.gyro_bias_instability_dph
            if e.gyro_bias_instability_dph is not None
            else (f.gyro_bias_instability_dph * on)
        )
        mis = e.misalignment_deg if e.misalignment_deg is not None else f.misalignment_deg * on
        self.accel = SensorErrors(
            draw,
            a_noise * 1e-6 * G,
            _vec(e.accel_bias_mg, draw.normal(0, f.accel_bias_mg * on, 3) * mg, mg),
            a_inst * 1e-6 * G,
            _vec(e.accel_scale_error, draw.normal(0, f.scale_error * on, 3), 1.0),
            math.radians(mis),
            _vec(
                e.accel_temp_drift_mg_per_c,
                draw.normal(0, f.accel_temp_drift_mg_per_c * on, 3) * mg,
                mg,
            ),
            np.random.default_rng(seeds[2]),
        )
        d2r = math.pi / 180
        self.gyro = SensorErrors(
            draw,
            g_noise * d2r,
            _vec(e.gyro_bias_dps, draw.normal(0, f.gyro_bias_dps * on, 3) * d2r, d2r),
            g_inst * d2r / 3600.0,
            _vec(e.gyro_scale_error, draw.normal(0, f.scale_error * on, 3), 1.0),
            math.radians(mis),
            _vec(
                e.gyro_temp_drift_dps_per_c,
                draw.normal(0, f.gyro_temp_drift_dps_per_c * on, 3) * d2r,
                d2r,
            ),
            np.random.default_rng(seeds[3]),
        )
        if s.clock_error is not None:
            self.clock_error = s.clock_error
        else:
            self.clock_error = float(draw.uniform(-0.015, 0.015)) * on

    def apply(self, t_s: F64, f: F64, w: F64, temp_c: F64, rate_hz: float) -> tuple[F64, F64]:
        return (
            self.accel.apply(t_s, f, temp_c, rate_hz, self.noise_rng),
            self.gyro.apply(t_s, w, temp_c, rate_hz, self.noise_rng),
        )


def quantise(x: F64, lsb: float, bits: int = 16, symmetric: bool = False) -> npt.NDArray[np.int32]:
    """Round to the range's LSB and saturate at full scale, as the ADC does. `symmetric`: the
    most negative code is reserved (a chip's invalid marker), so saturation stops one above."""
    hi = 2 ** (bits - 1) - 1
    return np.clip(np.rint(x / lsb), -hi if symmetric else -hi - 1, hi).astype(np.int32)
