"""How close imud's calibration estimators come to the truth, on recordings with known truth made
here from written physics: each figure beside the bound issue 9 holds it to, PASS or FAIL.

Every recording is synthesised in this file (nothing from the simulator package): an
MPU6050-grade sensor (accel white noise 400 ug/sqrt(Hz), gyro 0.005 deg/s/sqrt(Hz), per-sample
sigma = density * sqrt(rate)) at 500 Hz, the rate of `imu1`, the MPU6050 on the simulated
calibration bench in configs/sim.toml. The estimators run as `imud calibrate` runs them
(imud/calib/procedure.py calls the same functions with the same defaults): `fit_accel` with
the 9-parameter model, `fit_gyro_bias`, `fit_temperature` (order up to 3, chosen by the fit),
`fit_mag` (field magnitude not given).

1. Accel. Twelve poses of 30 s: the six faces and six cube corners (the simulator's choice,
   all corners but (1, -1, -1) and (-1, -1, -1)), ordered face, corner, face ... so each move
   is a 55 degree tilt, joined by 3 s minimum-jerk rotations. "Hand-placed": each pose's gravity
   direction is tilted off its nominal one by 0-5 degrees about a random axis, per trial. Sensor
   raw = A f + b + n, A = (I + E) diag(1 + s): E off-diagonal +-1 deg, s +-2 %, b +-0.3 m/s^2
   per axis, all signs random per trial.
   Which truth: a gravity-norm fit cannot see a rotation of the corrected frame, and the default
   model's C is upper-triangular, which ties that frame to the chip's axes. The true correction
   A^-1 = R U (QR, U upper-triangular with a positive diagonal, R a rotation) has U and b as
   the identifiable truth: U (raw - b) = R^T f has the norm g in every pose.
   (a) Held-out error: 20 random orientations per trial, never in the fit, their noise-free
   readings x = A f + b corrected with the fit, C^ (x - b^), against U (x - b): the error the
   calibration adds to every sample of such a pose (the samples' own noise is not part of it).
   Its bound is the Cramer-Rao bound from that recording: the Fisher information of the 12
   pose means, F = sum_i g_i g_i^T / (n_i^T S_i n_i), at the true parameters, with g_i the
   gradient of ||U (m_i - b)|| - g, n_i = U^T u_i the normal of the ellipsoid there, and S_i
   the covariance of pose i's mean measured from its 30 s of samples (sample covariance / n).
   Eliminating each pose's unknown direction (2 nuisance parameters) from the full Fisher
   information of m_i = U^-1 g u_i + b + noise leaves exactly n_i n_i^T / (n_i^T S_i n_i): the
   norm residual loses no information. Propagated to each held-out vector by the Jacobian of
   C (x - b). The figure is the RMS of |error| over trials and held-out poses against the RMS
   of the bound's sqrt(trace). (b) Coverage: how often |estimate - truth| <= the fit's own
   sigma, per parameter and pooled.
2. Gyro bias. 30 s still (the length the live `imud calibrate gyro` captures), random
   orientation, bias 0.2-1 deg/s per axis: RMS error over trials and axes against N / sqrt(T).
3. Temperature. Still in one tilted pose while the temperature ramps linearly from 10 to 50 degC
   over 2400 s (1 degC/min), read with 0.02 degC white noise. Bias drift per axis, a cubic in
   x = (T - 30) / 20 with random signs: gyro 0.2-0.6 deg/s (x), 0.05-0.2 (x^2), 0-0.1 (x^3)
   (0.01-0.03 deg/s/degC, the simulator's 0.02); accel 5-15 mg (x), 1-5 mg (x^2), 0-3 mg (x^3)
   (0.25-0.75 mg/degC; the MPU6050's zero-g drift is about 0.5 mg/degC). Recorded at 100 Hz:
   the fit works on 1 s block means, whose noise N / sqrt(1 s) does not depend on the rate.
   Figure: the peak-to-peak over 10-50 degC of the drift left after subtracting the fitted
   polynomial (with the pipeline's own `temp_correction`), against the peak-to-peak of the drift
   itself; worst axis of worst trial.
4. Magnetometer. 3000 readings at 100 Hz along one continuous spiral through all directions
   (randomly turned per trial), |B| = 50 uT, white noise 0.3 uT per axis, hard iron 10-40 uT per
   axis, soft iron diag 1 +- 0-5 % with 6 % off-diagonal coupling (random signs, not symmetric).
   Only the ellipsoid is observable: write S^-1 = U P (polar), the fit's symmetric correction
   maps a field b to (a multiple of) U^T b, the truth its direction is held to. Field-norm error:
   |corrected| against the method's own radius, over 2000 noise-free random directions;
   direction error: the angle to U^T b. The seed's min/max (offset (max + min) / 2, scale
   mean half-range / half-range, per axis) is computed here and given the rotation that suits
   it best (Kabsch), every benefit of the doubt.

    .venv/bin/python bench/calibration_accuracy.py                 # 200 trials per section
    .venv/bin/python bench/calibration_accuracy.py --quick         # 20 trials, a smoke run
    .venv/bin/python bench/calibration_accuracy.py --trials 500 --sections accel
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from imud.calib.accel import UPPER, fit_accel
from imud.calib.gyro import fit_gyro_bias
from imud.calib.mag import fit_mag
from imud.calib.recording import Recording
from imud.calib.still import check_still
from imud.calib.temp import fit_temperature, temp_correction

F64 = npt.NDArray[np.float64]

G = 9.80665  # m/s^2, used by the physics and given to the fit (local g is a separate question)
RATE_HZ = 500.0  # imu1 in configs/sim.toml
ACCEL_DENSITY = 400e-6 * G  # m/s^2/sqrt(Hz)
GYRO_DENSITY = math.radians(0.005)  # rad/s/sqrt(Hz)
BOUND_FACTOR = 1.2
COVERAGE_BAND = (0.60, 0.76)
COVERAGE_TRIALS = 200  # the trial count the coverage band is defined for
TEMP_LIMIT = 0.05
MAG_NORM_LIMIT_PCT = 0.1
MAG_DIR_LIMIT_DEG = 0.1
PARAM_NAMES = ("C_xx", "C_xy", "C_xz", "C_yy", "C_yz", "C_zz", "b_x", "b_y", "b_z")


@dataclass(frozen=True)
class Row:
    """One printed figure: value, the bound beside it, and whether it holds (None: shown for
    comparison, not judged)."""

    section: str
    figure: str
    value: str
    bound: str
    ok: bool | None

    @property
    def verdict(self) -> str:
        return "-" if self.ok is None else ("PASS" if self.ok else "FAIL")


# --- rotations and shared physics -----------------------------------------------------------


def rotate(v: F64, axis: F64, angle: F64) -> F64:
    """Rodrigues: each row of v (n, 3) (or one vector) turned by angle (n,) about a unit axis."""
    ang = np.asarray(angle, dtype=np.float64)[..., None]
    c, s = np.cos(ang), np.sin(ang)
    cross = np.cross(axis, v)
    dot = np.sum(v * axis, axis=-1, keepdims=True)
    out: F64 = v * c + cross * s + axis * dot * (1.0 - c)
    return out


def random_unit(rng: np.random.Generator, n: int) -> F64:
    v = rng.normal(size=(n, 3))
    out: F64 = v / np.linalg.norm(v, axis=1, keepdims=True)
    return out


def perpendicular_unit(rng: np.random.Generator, d: F64) -> F64:
    r = rng.normal(size=3)
    r -= (r @ d) * d
    out: F64 = r / np.linalg.norm(r)
    return out


def signs(rng: np.random.Generator, shape: int | tuple[int, ...]) -> F64:
    out: F64 = rng.choice(np.array([-1.0, 1.0]), size=shape)
    return out


def upper_triangular_factor(c: F64) -> F64:
    """U of c = R U (R a rotation, U upper-triangular with a positive diagonal)."""
    _, u = np.linalg.qr(c)
    out: F64 = np.sign(np.diag(u))[:, None] * u
    return out


def minimum_jerk(m: int) -> tuple[F64, F64]:
    """s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 and ds/dtau at the m sample instants of a move
    (tau = k / m, k = 0 .. m-1; the next pose begins at tau = 1)."""
    tau = np.arange(m) / m
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau * tau)
    ds = 30.0 * tau * tau * (1.0 - tau) ** 2
    return s, ds


# --- 1. accel -------------------------------------------------------------------------------

FACE_CORNER_ORDER = (
    (0, 0, 1), (1, 1, 1), (1, 0, 0), (1, 1, -1), (0, 0, -1), (-1, 1, -1),
    (0, 1, 0), (-1, 1, 1), (-1, 0, 0), (-1, -1, 1), (0, -1, 0), (1, -1, 1),
)  # fmt: skip


@dataclass(frozen=True)
class AccelTruth:
    a: F64  # raw = a @ f + b
    b: F64
    u: F64  # the identifiable correction (upper-triangular)

    @property
    def theta(self) -> F64:
        return np.array([*(self.u[i, j] for i, j in UPPER), *self.b])

    @classmethod
    def draw(cls, rng: np.random.Generator) -> AccelTruth:
        e = np.radians(1.0) * signs(rng, (3, 3))
        np.fill_diagonal(e, 0.0)
        a = (np.eye(3) + e) @ np.diag(1.0 + 0.02 * signs(rng, 3))
        b = 0.3 * signs(rng, 3)
        return cls(a, b, upper_triangular_factor(np.linalg.inv(a)))


@dataclass(frozen=True)
class PoseSession:
    rec: Recording
    holds: list[tuple[int, int]]  # sample spans [start, end) of the still poses
    directions: F64  # (12, 3) true gravity directions in the body, as placed


def hand_placed(rng: np.random.Generator, max_tilt_deg: float = 5.0) -> F64:
    """The twelve nominal directions, each tilted 0-max_tilt_deg about a random horizontal axis."""
    out = []
    for nominal in FACE_CORNER_ORDER:
        d = np.array(nominal, dtype=np.float64)
        d /= np.linalg.norm(d)
        axis = perpendicular_unit(rng, d)
        out.append(rotate(d, axis, np.array(math.radians(rng.uniform(0.0, max_tilt_deg)))))
    return np.array(out)


def pose_session(
    rng: np.random.Generator,
    truth: AccelTruth,
    directions: F64,
    hold_s: float = 30.0,
    move_s: float = 3.0,
    rate_hz: float = RATE_HZ,
    accel_density: float = ACCEL_DENSITY,
    gyro_density: float = GYRO_DENSITY,
) -> PoseSession:
    """Still poses joined by minimum-jerk rotations about the axis that carries one gravity
    direction into the next. Body-frame specific force f = g R(t)^T z (the sensor turns about
    its own centre: no linear acceleration), body rate w = -s'(t) theta k for a turn by theta
    about k; accel raw = A f + b + noise, gyro raw = w + bias + noise."""
    n_hold, n_move = round(hold_s * rate_hz), round(move_s * rate_hz)
    s, ds = minimum_jerk(n_move)
    forces, rates, holds = [], [], []
    count = 0
    for i, d in enumerate(directions):
        forces.append(np.repeat(G * d[None], n_hold, axis=0))
        rates.append(np.zeros((n_hold, 3)))
        holds.append((count, count + n_hold))
        count += n_hold
        if i + 1 == directions.shape[0]:
            break
        nxt = directions[i + 1]
        k = np.cross(d, nxt)
        k /= np.linalg.norm(k)
        theta = math.acos(float(np.clip(d @ nxt, -1.0, 1.0)))
        forces.append(G * rotate(d, k, theta * s))
        rates.append(-(theta * ds * rate_hz / n_move)[:, None] * k)
        count += n_move
    f = np.concatenate(forces)
    w = np.concatenate(rates)
    n = f.shape[0]
    gyro_bias = np.radians(1.0) * signs(rng, 3)
    accel = f @ truth.a.T + truth.b + rng.normal(0.0, accel_density * math.sqrt(rate_hz), (n, 3))
    gyro = w + gyro_bias + rng.normal(0.0, gyro_density * math.sqrt(rate_hz), (n, 3))
    t_ns = np.round(np.arange(n) * (1e9 / rate_hz)).astype(np.int64)
    rec = Recording(t_ns, accel, gyro, None, None, None, "bench accel session")
    return PoseSession(rec, holds, directions)


def norm_gradients(u: F64, b: F64, x: F64) -> tuple[F64, F64]:
    """Gradient (n, 9) of ||U (x - b)|| - g over (U's upper entries, b) at rows of x, and the
    ellipsoid normals U^T u (n, 3) that project a mean's noise onto the residual."""
    d = x - b
    v = d @ u.T
    unit = v / np.linalg.norm(v, axis=1, keepdims=True)
    grad = np.empty((x.shape[0], 9))
    for k, (i, j) in enumerate(UPPER):
        grad[:, k] = unit[:, i] * d[:, j]
    normal = unit @ u
    grad[:, 6:] = -normal
    return grad, normal


def accel_crb(truth: AccelTruth, sess: PoseSession) -> F64:
    """Cramer-Rao covariance (9, 9) of (U upper entries, b) from this recording: the poses'
    true readings, their means' covariance measured from the samples (see the module doc)."""
    x = G * sess.directions @ truth.a.T + truth.b
    covs = np.array(
        [np.cov(sess.rec.accel[a:b].T) / (b - a) for a, b in sess.holds], dtype=np.float64
    )
    grad, normal = norm_gradients(truth.u, truth.b, x)
    var = np.einsum("ni,nij,nj->n", normal, covs, normal)
    fisher = grad.T @ (grad / var[:, None])
    out: F64 = np.linalg.inv(fisher)
    return out


def correction_jacobian(c: F64, b: F64, x: F64) -> F64:
    """d [C (x - b)] / d (C's upper entries, b): (n, 3, 9)."""
    d = x - b
    jac = np.zeros((x.shape[0], 3, 9))
    for k, (i, j) in enumerate(UPPER):
        jac[:, i, k] = d[:, j]
    jac[:, :, 6:] = -c
    return jac


@dataclass
class AccelTrials:
    err2: list[float]  # |held-out error|^2, every held-out pose of every trial
    crb2: list[float]  # trace of the bound's covariance there
    seed_err2: list[float]  # the seed's up/down formula's held-out error^2
    inside: list[npt.NDArray[np.bool_]]  # per trial: |est - truth| <= sigma, per parameter
    z: list[F64]  # per trial: (est - truth) / CRB sigma
    sigma_ratio: list[F64]  # per trial: the fit's sigma / CRB sigma
    accepted: int = 0
    poses_found: int = 0


def accel_trial(rng: np.random.Generator, held_out: int, out: AccelTrials) -> None:
    truth = AccelTruth.draw(rng)
    sess = pose_session(rng, truth, hand_placed(rng))
    res = fit_accel(sess.rec, G, "full")
    est = res.estimate
    out.accepted += int(est.verdict.accepted)
    out.poses_found += len(res.intervals)
    crb = accel_crb(truth, sess)
    crb_sigma = np.sqrt(np.diag(crb))
    dev = est.fit.values - truth.theta
    out.inside.append(np.abs(dev) <= est.fit.sigma())
    out.z.append(dev / crb_sigma)
    out.sigma_ratio.append(est.fit.sigma() / crb_sigma)

    x = G * random_unit(rng, held_out) @ truth.a.T + truth.b  # noise-free held-out readings
    want = (x - truth.b) @ truth.u.T
    got = (x - est.bias) @ est.matrix.T
    out.err2.extend(np.sum((got - want) ** 2, axis=1).tolist())
    jac = correction_jacobian(truth.u, truth.b, x)
    out.crb2.extend(np.einsum("nik,kl,nil->n", jac, crb, jac).tolist())
    if res.seed is not None:
        seed = (x - res.seed.bias) @ res.seed.matrix.T
        out.seed_err2.extend(np.sum((seed - want) ** 2, axis=1).tolist())


def accel_rows(trials: int, seed: int, held_out: int = 20) -> list[Row]:
    rng = np.random.default_rng(seed)
    out = AccelTrials([], [], [], [], [], [])
    for _ in range(trials):
        accel_trial(rng, held_out, out)
    err = math.sqrt(float(np.mean(out.err2)))
    bound = math.sqrt(float(np.mean(out.crb2)))
    rows = [
        Row("accel", "trials accepted by the fit's own chi2 test (p >= 0.01)",
            f"{out.accepted}/{trials}", "-", None),
        Row("accel", "still poses found per trial (12 placed)",
            f"{out.poses_found / trials:.2f}", "-", None),
        Row("accel", "(a) held-out corrected error, RMS |e| (mm/s^2)", f"{1e3 * err:.3f}",
            f"<= {BOUND_FACTOR} x CRB {1e3 * bound:.3f} = {1e3 * BOUND_FACTOR * bound:.3f}",
            err <= BOUND_FACTOR * bound),
        Row("accel", "(a) ratio held-out error / CRB", f"{err / bound:.3f}",
            f"<= {BOUND_FACTOR}", err <= BOUND_FACTOR * bound),
    ]  # fmt: skip
    if out.seed_err2:
        seed_err = math.sqrt(float(np.mean(out.seed_err2)))
        rows.append(
            Row("accel", "    seed's up/down formula, same held-out poses (mm/s^2)",
                f"{1e3 * seed_err:.1f}", "-", None)
        )  # fmt: skip
    z = np.array(out.z)
    ratio = np.array(out.sigma_ratio)
    rms_z = np.sqrt(np.mean(z * z, axis=0))
    rows.append(
        Row("accel", "    MC spread / CRB per parameter (min-max of 9)",
            f"{rms_z.min():.3f}-{rms_z.max():.3f}", "-", None)
    )  # fmt: skip
    rows.append(
        Row("accel", "    fit's sigma / CRB sigma per parameter (mean, min-max of 9)",
            f"{ratio.mean():.3f} ({ratio.mean(axis=0).min():.3f}-{ratio.mean(axis=0).max():.3f})",
            "-", None)
    )  # fmt: skip
    inside = np.array(out.inside)
    judged = trials >= COVERAGE_TRIALS
    lo, hi = COVERAGE_BAND
    band = f"{100 * lo:.0f}-{100 * hi:.0f} %"
    for k, name in enumerate(PARAM_NAMES):
        frac = float(inside[:, k].mean())
        rows.append(
            Row("accel", f"(b) 68 % interval covers the truth: {name}", f"{100 * frac:.1f} %",
                band if judged else f"{band} (judged at >= {COVERAGE_TRIALS} trials)",
                (lo <= frac <= hi) if judged else None)
        )  # fmt: skip
    pooled = float(inside.mean())
    rows.append(
        Row("accel", "(b) 68 % interval covers the truth: pooled", f"{100 * pooled:.1f} %",
            band, lo <= pooled <= hi)
    )  # fmt: skip
    return rows


# --- 2. gyro bias ---------------------------------------------------------------------------


def gyro_rows(trials: int, seed: int, seconds: float = 30.0) -> list[Row]:
    """Still, in a random orientation; bias 0.2-1 deg/s per axis; white noise."""
    rng = np.random.default_rng(seed)
    n = round(seconds * RATE_HZ)
    t_ns = np.round(np.arange(n) * (1e9 / RATE_HZ)).astype(np.int64)
    err, sig, accepted, still = [], [], 0, 0
    for _ in range(trials):
        bias = np.radians(rng.uniform(0.2, 1.0, 3)) * signs(rng, 3)
        gravity = G * random_unit(rng, 1)[0]
        accel = gravity + rng.normal(0.0, ACCEL_DENSITY * math.sqrt(RATE_HZ), (n, 3))
        gyro = bias + rng.normal(0.0, GYRO_DENSITY * math.sqrt(RATE_HZ), (n, 3))
        rec = Recording(t_ns, accel, gyro, None, None, None, "bench gyro still")
        still += int(check_still(rec).still)  # what `imud calibrate gyro` checks first
        est = fit_gyro_bias(rec)
        accepted += int(est.verdict.accepted)
        err.extend((est.bias - bias).tolist())
        sig.extend(est.fit.sigma().tolist())
    t = n / RATE_HZ
    limit = GYRO_DENSITY / math.sqrt(t)
    rms = math.sqrt(float(np.mean(np.square(err))))
    dph = 3600.0 * 180.0 / math.pi
    return [
        Row("gyro", "trials still (check_still) / accepted", f"{still}/{accepted} of {trials}",
            "-", None),
        Row("gyro", f"bias error RMS over trials and axes, T = {t:g} s (deg/h)",
            f"{dph * rms:.3f}",
            f"<= {BOUND_FACTOR} N/sqrt(T) = {BOUND_FACTOR} x {dph * limit:.3f} = "
            f"{dph * BOUND_FACTOR * limit:.3f}", rms <= BOUND_FACTOR * limit),
        Row("gyro", "ratio error RMS / (N/sqrt(T))", f"{rms / limit:.3f}", f"<= {BOUND_FACTOR}",
            rms <= BOUND_FACTOR * limit),
        Row("gyro", "    fit's reported sigma / (N/sqrt(T)), mean",
            f"{float(np.mean(sig)) / limit:.3f}", "-", None),
    ]  # fmt: skip


# --- 3. temperature -------------------------------------------------------------------------

TEMP_RATE_HZ = 100.0
TEMP_SPAN = (10.0, 50.0)
TEMP_NOISE_C = 0.02
RAMP_S = 2400.0
# |coefficient| ranges of x, x^2, x^3 with x = (T - 30) / 20: gyro deg/s, accel mg
GYRO_DRIFT_DPS = ((0.2, 0.6), (0.05, 0.2), (0.0, 0.1))
ACCEL_DRIFT_MG = ((5.0, 15.0), (1.0, 5.0), (0.0, 3.0))


def drift_coefficients(rng: np.random.Generator, ranges: tuple[tuple[float, float], ...]) -> F64:
    """(3 orders, 3 axes) in units of x = (T - 30) / 20, random magnitudes and signs."""
    out: F64 = np.array([rng.uniform(lo, hi, 3) * signs(rng, 3) for lo, hi in ranges])
    return out


def drift(coef: F64, temp: F64) -> F64:
    x = ((temp - 30.0) / 20.0)[:, None]
    out: F64 = x * coef[0] + x**2 * coef[1] + x**3 * coef[2]
    return out


def temperature_rows(trials: int, seed: int) -> list[Row]:
    rng = np.random.default_rng(seed)
    n = round(RAMP_S * TEMP_RATE_HZ)
    t_ns = np.round(np.arange(n) * (1e9 / TEMP_RATE_HZ)).astype(np.int64)
    true_t = np.linspace(*TEMP_SPAN, n)
    grid = np.linspace(*TEMP_SPAN, 401)
    ratios: dict[str, list[float]] = {"gyro": [], "accel": []}
    orders: dict[str, list[int]] = {"gyro": [], "accel": []}
    accepted = 0
    for _ in range(trials):
        coef = {
            "gyro": np.radians(drift_coefficients(rng, GYRO_DRIFT_DPS)),
            "accel": 1e-3 * G * drift_coefficients(rng, ACCEL_DRIFT_MG),
        }
        pose = G * random_unit(rng, 1)[0]
        accel = (
            pose
            + 0.3 * signs(rng, 3)
            + drift(coef["accel"], true_t)
            + rng.normal(0.0, ACCEL_DENSITY * math.sqrt(TEMP_RATE_HZ), (n, 3))
        )
        gyro = (
            np.radians(1.0) * signs(rng, 3)
            + drift(coef["gyro"], true_t)
            + rng.normal(0.0, GYRO_DENSITY * math.sqrt(TEMP_RATE_HZ), (n, 3))
        )
        temp = true_t + rng.normal(0.0, TEMP_NOISE_C, n)
        rec = Recording(t_ns, accel, gyro, temp, None, None, "bench temperature ramp")
        ok = True
        for sensor in ("gyro", "accel"):
            est = fit_temperature(rec, sensor, 3)
            ok &= est.verdict.accepted
            orders[sensor].append(est.order)
            truth = drift(coef[sensor], grid)
            corr, _ = temp_correction(est.coefficients, est.reference_c, est.span_c, grid)
            before = np.ptp(truth, axis=0)
            after = np.ptp(truth - corr, axis=0)
            ratios[sensor].append(float(np.max(after / before)))
        accepted += int(ok)
    rows = [
        Row("temp", "trials accepted (both sensors)", f"{accepted}/{trials}", "-", None),
    ]
    for sensor in ("gyro", "accel"):
        r = np.array(ratios[sensor])
        counts = np.bincount(orders[sensor], minlength=4)[1:]
        rows.append(
            Row("temp", f"{sensor}: drift left / drift, worst axis of worst trial",
                f"{100 * r.max():.3f} %", f"< {100 * TEMP_LIMIT:.0f} %", r.max() < TEMP_LIMIT)
        )  # fmt: skip
        rows.append(
            Row("temp", f"    {sensor}: same, median trial", f"{100 * float(np.median(r)):.3f} %",
                "-", None)
        )  # fmt: skip
        rows.append(
            Row("temp", f"    {sensor}: order chosen 1/2/3",
                "/".join(str(int(c)) for c in counts), "-", None)
        )  # fmt: skip
    return rows


# --- 4. magnetometer ------------------------------------------------------------------------

FIELD_T = 50e-6
MAG_NOISE_T = 0.3e-6
MAG_SAMPLES = 3000
MAG_RATE_HZ = 100.0


def spiral(n: int) -> F64:
    """Unit vectors along one continuous spiral from +z to -z, consecutive points a constant
    3.6 / sqrt(n) rad apart: directions uniform in area, along a path a hand could follow."""
    z = 1.0 - 2.0 * np.arange(n) / (n - 1)
    theta = np.arccos(z)
    dphi = np.zeros(n)
    dphi[1:-1] = 3.6 / math.sqrt(n) / np.sqrt(1.0 - z[1:-1] ** 2)
    phi = np.cumsum(dphi)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), z], axis=1)


def random_rotation(rng: np.random.Generator) -> F64:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    out: F64 = q if np.linalg.det(q) > 0 else -q
    return out


def kabsch(a: F64, b: F64) -> F64:
    """The rotation R minimising sum |R a_i - b_i|^2."""
    u, _, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    out: F64 = u @ np.diag([1.0, 1.0, d]) @ vt
    return out


def seed_min_max(m: F64) -> tuple[F64, F64, float]:
    """The seed's method: per-axis offset (max + min) / 2, scale avg_radius / radius_axis."""
    lo, hi = m.min(axis=0), m.max(axis=0)
    radius = (hi - lo) / 2.0
    avg = float(radius.mean())
    return (hi + lo) / 2.0, np.diag(avg / radius), avg


def angles_deg(a: F64, b: F64) -> F64:
    cos = np.sum(a * b, axis=1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    out: F64 = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return out


def mag_rows(trials: int, seed: int, evaluate: int = 2000) -> list[Row]:
    rng = np.random.default_rng(seed)
    t_ns = np.round(np.arange(MAG_SAMPLES) * (1e9 / MAG_RATE_HZ)).astype(np.int64)
    zeros = np.zeros((MAG_SAMPLES, 3))  # fit_mag reads only the magnetometer and the stamps
    path = spiral(MAG_SAMPLES)
    norm_e: dict[str, list[F64]] = {"fit": [], "minmax": []}
    dir_e: dict[str, list[F64]] = {"fit": [], "minmax": []}
    accepted = 0
    for _ in range(trials):
        soft = 0.06 * signs(rng, (3, 3))
        np.fill_diagonal(soft, 1.0 + rng.uniform(-0.05, 0.05, 3))
        hard = rng.uniform(10e-6, 40e-6, 3) * signs(rng, 3)
        body = FIELD_T * path @ random_rotation(rng).T
        clean = body @ soft.T + hard
        noisy = clean + rng.normal(0.0, MAG_NOISE_T, clean.shape)
        rec = Recording(t_ns, zeros, zeros, mag=noisy, source="bench magnetometer spiral")
        res = fit_mag(rec)
        est = res.estimate
        accepted += int(est.verdict.accepted)
        assert est.field_t is not None

        w, _, vt = np.linalg.svd(np.linalg.inv(soft))  # S^-1 = U P
        rot = w @ vt
        b_eval = FIELD_T * random_unit(rng, evaluate)
        truth_dir = b_eval @ rot  # rows: U^T b
        m_eval = b_eval @ soft.T + hard
        got = (m_eval - est.bias) @ est.matrix.T
        norm_e["fit"].append(np.linalg.norm(got, axis=1) / est.field_t - 1.0)
        dir_e["fit"].append(angles_deg(got, truth_dir))

        off, scale, radius = seed_min_max(noisy)
        mm = (m_eval - off) @ scale.T
        mm_rot = mm @ kabsch(mm, truth_dir).T
        norm_e["minmax"].append(np.linalg.norm(mm, axis=1) / radius - 1.0)
        dir_e["minmax"].append(angles_deg(mm_rot, truth_dir))

    def rms(x: list[F64]) -> float:
        return math.sqrt(float(np.mean(np.square(np.concatenate(x)))))

    fn, fd = 100.0 * rms(norm_e["fit"]), rms(dir_e["fit"])
    mn, md = 100.0 * rms(norm_e["minmax"]), rms(dir_e["minmax"])
    return [
        Row("mag", "trials accepted by the fit's verdict", f"{accepted}/{trials}", "-", None),
        Row("mag", "ellipsoid fit: field-norm error RMS", f"{fn:.4f} %",
            f"<= {MAG_NORM_LIMIT_PCT} %", fn <= MAG_NORM_LIMIT_PCT),
        Row("mag", "ellipsoid fit: direction error RMS", f"{fd:.4f} deg",
            f"<= {MAG_DIR_LIMIT_DEG} deg", fd <= MAG_DIR_LIMIT_DEG),
        Row("mag", "    seed's min/max: field-norm error RMS", f"{mn:.2f} %", "-", None),
        Row("mag", "    seed's min/max (best rotation): direction error RMS", f"{md:.2f} deg",
            "-", None),
    ]  # fmt: skip


# --- the run --------------------------------------------------------------------------------

SECTIONS: dict[str, Callable[[int, int], list[Row]]] = {
    "accel": accel_rows,
    "gyro": gyro_rows,
    "temp": temperature_rows,
    "mag": mag_rows,
}


def print_table(rows: list[Row]) -> None:
    w_fig = max(len(r.figure) for r in rows)
    w_val = max(len(r.value) for r in rows)
    w_bnd = max(len(r.bound) for r in rows)
    print(
        f"{'section':<7} | {'figure':<{w_fig}} | {'value':>{w_val}} | {'bound':<{w_bnd}} | result"
    )
    for r in rows:
        print(
            f"{r.section:<7} | {r.figure:<{w_fig}} | {r.value:>{w_val}} | {r.bound:<{w_bnd}} | "
            f"{r.verdict}"
        )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    p.add_argument(
        "--trials", type=int, default=COVERAGE_TRIALS, help="Monte-Carlo trials per section"
    )
    p.add_argument("--quick", action="store_true", help="20 trials per section: a smoke run")
    p.add_argument("--seed", type=int, default=9, help="base seed (each section adds its own)")
    p.add_argument("--sections", default=",".join(SECTIONS), help="comma-separated subset")
    argv = sys.argv[1:] if argv is None else argv
    args = p.parse_args(argv)
    trials = 20 if args.quick else args.trials
    if trials < 1:
        p.error("--trials must be at least 1")
    print("command:", shlex.join([sys.executable, "bench/calibration_accuracy.py", *argv]))
    rows: list[Row] = []
    for k, name in enumerate(SECTIONS):
        if name not in args.sections.split(","):
            continue
        t0 = time.perf_counter()
        rows.extend(SECTIONS[name](trials, args.seed * 100 + k))
        print(f"{name}: {trials} trials in {time.perf_counter() - t0:.1f} s", flush=True)
    print()
    print_table(rows)
    failed = [r for r in rows if r.ok is False]
    print()
    print(f"{len(failed)} of {sum(r.ok is not None for r in rows)} judged figures FAIL")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
