"""Physics shared by the chip simulators: motion, temperature and the IMU error model.

Measurement model (per sensor): m = M @ S @ (x + b0 + k_T (T - 25 C) + b_gm(t)) + n, with M a
misalignment matrix, S diagonal scale, b0 a turn-on bias, k_T a linear temperature drift, b_gm a
Gauss-Markov bias (bias instability), and n the noise of the datasheet density.

The noise convention: a datasheet's noise density is one-sided (the MPU6050's 0.005 deg/s/rtHz
and its 0.05 deg/s RMS at the 100 Hz DLPF: 0.005 * sqrt(100) = 0.05). A chip simulator built on
`imud.sim.filters.FilteredChip` draws it that way: white noise of per-sample sigma
density * sqrt(f / 2) on the chip's internal grid, through the chip's configured low-pass filter,
so the output has RMS density * sqrt(noise bandwidth) and Allan N = density / sqrt(2) (the
Allan deviation at 1 s). A simulator not yet built on it keeps `SensorErrors.apply`: unfiltered
white noise of per-sample sigma density * sqrt(rate), sqrt(2) above that convention (Allan
deviation at 1 s = density), with no group delay.

For chips that estimate orientation or sense the magnetic field: the motion's true orientation as
a quaternion (body -> world, ENU), and the Earth's field with a board's hard and soft iron. The
motion itself (and the quaternion helpers, imported here for the chip simulators) is in
`imud.sim.motion`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from imud.rotations import quat_conj, quat_rotate
from imud.sim.motion import MotionModel as MotionModel
from imud.sim.settings import ErrorSettings, MagneticSettings, SimSettings
from imud.units import STANDARD_GRAVITY as G

F64 = npt.NDArray[np.float64]


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
    """The die temperature: a linear ramp clipped to the limits (the default; a constant without
    a ramp), or with `temperature_cycle_min` a sine between the limits, starting at
    `temperature_c` on its way up. A thermal chamber's slow cycle: a temperature calibration
    sees the whole span, both ways, and a smooth path keeps the die close to the chamber (a fast
    step would leave the die and the sensor's true temperature apart, which no fit models)."""

    def __init__(self, s: SimSettings) -> None:
        self.t0 = s.temperature_c
        self.ramp = s.temperature_ramp_c_per_min / 60.0
        self.lo, self.hi = s.temperature_limits_c
        self.cycle_s = s.temperature_cycle_min * 60.0
        self.mid, self.amp = 0.5 * (self.lo + self.hi), 0.5 * (self.hi - self.lo)
        if self.cycle_s > 0:  # T(t) = mid - amp cos(2 pi t / cycle + phase): T(0) = t0, rising
            self.phase = math.acos(min(1.0, max(-1.0, (self.mid - self.t0) / self.amp)))

    def at(self, t_s: F64) -> F64:
        if self.cycle_s > 0:
            out: F64 = self.mid - self.amp * np.cos(2 * math.pi * t_s / self.cycle_s + self.phase)
            return out
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

    def deterministic(self, t_s: F64, x: F64, temp_c: F64) -> F64:
        """Every error but the white noise: M S (x + b0 + k_T (T - 25 C) + b_gm(t))."""
        b = self.bias + np.outer(temp_c - 25.0, self.drift) + self.gm.at(t_s)
        y: F64 = (x + b) @ self.matrix.T
        return y

    def apply(
        self, t_s: F64, x: F64, temp_c: F64, rate_hz: float, noise_rng: np.random.Generator
    ) -> F64:
        """The unfiltered model (a chip simulator without `imud.sim.filters`): white noise of
        per-sample sigma density * sqrt(rate)."""
        y = self.deterministic(t_s, x, temp_c)
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
