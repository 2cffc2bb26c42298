"""Orientation from gyro, accelerometer and (optionally) magnetometer: a multiplicative error-state
Kalman filter with gyro-bias states, run on NumPy batches.

State: the orientation q (unit quaternion w, x, y, z; rotates body vectors into the world frame,
ENU, z up), the gyro bias b (rad/s) and the platform's horizontal linear acceleration a (world,
m/s^2). Error state (8): a small rotation dtheta in the *world* frame (q_true = exp(dtheta) q),
db = b_true - b, and da. World-frame errors keep the heading error apart from the tilt errors:
without a magnetometer the heading is unobservable and its variance grows without bound, and in
world coordinates that growth never leaks into the tilt.

Prediction runs at the full sample rate, a batch at a time. Within a chunk each sample's
rotation since the chunk began is the running sum of the increments (one array operation for
the chunk, not a Python loop); the chunk's end, which the next chunk starts from, adds the
second-order (coning) term. The world-frame error moves only through the bias,
d(dtheta)/dt = -R db, so the covariance needs just sums of the samples' rotation matrices, kept
exactly as sums of q outer q.

Correction runs at `update_hz`: the accelerometer samples of the last two intervals are
rotated into the world frame with the orientation of their own instants and averaged under a
triangle, so a platform turning meanwhile still yields one gravity direction, a vibration
leaves little of itself whatever the batch size, and the noise of the average is the
accelerometer's low-frequency density over the interval's length (correct even behind a
low-pass filter that correlates the samples). Linear acceleration is a first-order
Gauss-Markov state whose variance follows the innovations up to a ceiling; beyond it an
innovation fails the chi-squared gate and the gyro carries the orientation. The innovations'
step-to-step scatter (vibration the means did not cancel) and |a| away from gravity add to the
measurement's noise; after `recovery_s` of rejections, or half a second of them while |a|
stays at gravity (the estimate drifted, the platform did not accelerate), the tilt is re-seeded
from the accelerometer. The magnetometer corrects heading (its horizontal direction, with the tilt's
coupling through the dip); a field whose magnitude departs from the reference is rejected.
While the device rests, a still window's mean gyro is a direct measurement of the bias
(`zero_rate`), fed from the gyro-bias tracker's stillness tests: one bias estimate, not two.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from imud.compiled import load
from imud.orient import kalman
from imud.orient.kalman import FORM_V, N_STATES, Learn
from imud.rotations import quat_exp, quat_to_matrix

F64 = npt.NDArray[np.float64]
_kernels = load("imud._kernels")  # a chunk's integration in one call, when built

CHI2_2DOF_999 = 13.816  # innovation gate: chi-squared 2 dof, upper tail 1e-3
CHI2_2DOF_95 = 5.991
CHI2_1DOF_999 = 10.828
CHI2_3DOF_999 = 16.266
# how fast the linear acceleration's variance follows the innovations (per correction): about
# twenty corrections, two seconds at the default rate
ADAPT_GAIN = 0.05
WHITE_GAIN = 0.05  # per correction: the innovations' white scatter, over about twenty
LINEAR_FLOOR = 0.001  # m/s^2: never assumed steadier than this
# m/s^2: the most linear acceleration taken as the platform's own (a state); beyond, an
# acceleration is an outlier the innovation gate rejects, so a car's 3 m/s^2 turn is ridden
# through on the gyro instead of tilting the estimate (the daemon's `linear_accel_max_m_s2`)
LINEAR_CEILING = 0.2
G0_GAIN = 0.003  # the reference |gravity| follows |a| over about thirty seconds
STEADY_AFTER = 12  # corrections (two seconds at the default rate)
LINEAR_STEADY = 0.05  # m/s^2: at most this much linear acceleration, the bias learns from gravity
# rejected intervals whose |a| shows less than this share of what a horizontal acceleration as
# large as the innovation would add, and by this many standard deviations, for this long: the
# estimate drifted (see `_accel_update`)
DRIFT_SHARE = 0.25
DRIFT_SIGMAS = 4.0
DRIFT_S = 0.5
MAG_NORM_TOLERANCE = 0.1  # a field whose magnitude departs from the reference by more: disturbed
INIT_TILT_SIGMA = math.radians(5.0)  # the first mean may hold linear acceleration: say so
INIT_HEADING_SIGMA = math.radians(15.0)  # and the tilt's error shows in the heading, 2-3x
_I3 = np.eye(3)
_COV6 = np.array([0, 1, 2, 9, 10, 18])  # xx, xy, xz, yy, yz, zz in the flattened 8 x 8
_H_BIAS = np.hstack([np.zeros((3, 3)), np.eye(3), np.zeros((3, 2))])  # a still window's mean


class OrientState(StrEnum):
    INITIALISING = "initialising"  # no accelerometer interval yet: no orientation
    RUNNING = "running"
    ACCEL_REJECTED = "accel_rejected"  # the last interval's gravity was rejected


@dataclass(frozen=True)
class NoiseModel:
    """The sensors' low-frequency (two-sided) noise densities and the bias's random walk: what
    the covariance is made of. A datasheet's one-sided density d gives d / sqrt(2)."""

    gyro: float  # rad/s/sqrt(Hz)
    accel: float  # m/s^2/sqrt(Hz)
    bias_walk: float = 2e-5  # rad/s/sqrt(s)
    mag: float | None = None  # tesla per sample (its readings are few and held)


@dataclass
class Counters:
    accel_updates: int = 0
    accel_rejected: int = 0
    mag_updates: int = 0
    mag_rejected: int = 0
    zero_rate_updates: int = 0
    recoveries: int = 0


def _quat_exp1(x: float, y: float, z: float) -> F64:
    th = math.sqrt(x * x + y * y + z * z)
    s = math.sin(0.5 * th) / th if th > 1e-12 else 0.5
    return np.array([math.cos(0.5 * th), x * s, y * s, z * s])


_RAMPS: dict[int, F64] = {}


def _ramp(m: int) -> F64:
    """0, 1, ..., m - 1 (a chunk's sample indices), made once per chunk length."""
    r = _RAMPS.get(m)
    if r is None:
        r = np.arange(m, dtype=np.float64)
        if len(_RAMPS) < 4096:
            _RAMPS[m] = r
    return r


Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


def _rotate(e: Quat, v: Vec3) -> Vec3:
    """R(e) v for a unit quaternion e, in floats."""
    w, x, y, z = e
    a, b, c = v
    return (
        (1 - 2 * (y * y + z * z)) * a + 2 * (x * y - w * z) * b + 2 * (x * z + w * y) * c,
        2 * (x * y + w * z) * a + (1 - 2 * (x * x + z * z)) * b + 2 * (y * z - w * x) * c,
        2 * (x * z - w * y) * a + 2 * (y * z + w * x) * b + (1 - 2 * (x * x + y * y)) * c,
    )


def _left(q: F64) -> F64:
    """L(q): q x p = L(q) p for quaternions as columns."""
    w, x, y, z = q.tolist()
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


def tilt_quaternion(accel: F64) -> F64:
    """The orientation with zero heading whose gravity matches a mean specific force (3,): the
    shortest rotation taking the body's measured 'up' to the world's z."""
    u = accel / np.linalg.norm(accel)
    # rotation from u (body up) to z: axis u x z, angle acos(u . z)
    w = 1.0 + u[2]
    if w < 1e-9:  # upside down: a half turn about x
        return np.array([0.0, 1.0, 0.0, 0.0])
    q = np.array([w, u[1], -u[0], 0.0])
    out: F64 = q / np.linalg.norm(q)
    return out


@dataclass
class _Interval:
    """What one correction interval has gathered so far. Rotation matrices are summed as sums of
    q outer q (`kalman.FORM` turns them into matrices at the correction), so a chunk adds two
    small products and rotates nothing. The sums are views of one buffer, zeroed in one call
    after each correction."""

    def __init__(self) -> None:
        self._buf = np.zeros(16 + 48 + 48 + 3)
        self.qq: F64 = self._buf[:16]  # sum q outer q
        self.qqa: F64 = self._buf[16:64].reshape(16, 3)  # sum (q outer q) outer a
        # the same weighted by each sample's index in the interval, and the sum of those
        # indices: the two halves of the gravity window (`_gravity_window`)
        self.kqqa: F64 = self._buf[64:112].reshape(16, 3)
        self.m_sum: F64 = self._buf[112:]
        self.reset()

    def reset(self) -> None:
        self._buf.fill(0.0)
        self.n = 0  # samples with a valid accelerometer reading
        self.steps = 0  # samples integrated
        self.t = 0.0  # seconds integrated
        self.kn = 0.0
        self.m_n = 0


class OrientationFilter:
    """One device's filter. `step` takes a batch and returns its orientation and covariance."""

    def __init__(
        self,
        noise: NoiseModel,
        update_hz: float = 10.0,
        bias_sigma: float = 0.01,
        recovery_s: float = 10.0,
        use_mag: bool = True,
        declination_rad: float = 0.0,
        linear_time_s: float = 1.0,
        init_s: float = 1.0,
        linear_max: float = LINEAR_CEILING,
    ) -> None:
        self.noise = noise
        self.update_s = 1.0 / update_hz
        self.init_s = init_s
        self.bias_sigma = bias_sigma
        self.recovery_s = recovery_s
        self.use_mag = use_mag and noise.mag is not None
        self.declination = declination_rad
        # the platform's own horizontal acceleration, a first-order Gauss-Markov process: what
        # lets slow linear acceleration be told from tilt by its time scale, not taken for it
        # assumed steady at first (the innovations show otherwise within a few corrections)
        self.linear_var = LINEAR_FLOOR**2
        self.linear_time_s = linear_time_s
        self.linear_max = linear_max
        self._q_density = np.array([noise.gyro**2] * 3 + [noise.bias_walk**2] * 3 + [0.0, 0.0])
        self.q = np.array([1.0, 0.0, 0.0, 0.0])
        self.b = np.zeros(3)
        self.a = np.zeros(2)  # world-horizontal linear acceleration, m/s^2
        self.P = np.zeros((N_STATES, N_STATES))
        self.state = OrientState.INITIALISING
        self.counters = Counters()
        self.heading_known = False  # a magnetometer has set the heading
        self._g0: float | None = None  # the reference |gravity|, m/s^2
        self._g0_n = 0  # intervals averaged into it
        self._adapt_n = 0  # corrections the linear acceleration's variance has followed
        self._mag_ref: float | None = None  # |B| at the start, T
        self._rejected_s = 0.0
        self._prev_y: tuple[float, float] | None = None  # the last gravity innovation
        self._white_var = 0.0  # its steps' variance per axis, m^2/s^4
        self._g_var = 0.0  # |a| about the reference's variance, in intervals gravity explained
        self._drifted_s = 0.0  # rejected in a row with |a| at gravity: the estimate drifted
        self._iv = _Interval()
        self._h = np.empty((2, N_STATES))  # gravity's measurement matrix, made afresh each time
        # the compiled correction's scalar state and constants (imud/_kernels.c CS_*, CP_*)
        self._st = np.zeros(19)
        self._params = np.array(
            [
                noise.accel**2, linear_time_s, linear_max**2, recovery_s, STEADY_AFTER,
                LINEAR_STEADY**2, ADAPT_GAIN, WHITE_GAIN, G0_GAIN, LINEAR_FLOOR**2, DRIFT_SHARE,
                DRIFT_SIGMAS, DRIFT_S, CHI2_2DOF_999, CHI2_2DOF_95,
            ]
        )  # fmt: skip
        # the last interval's half of the next gravity window: its world-frame specific force
        # weighted by a ramp rising to its end, the ramp's weight, its length (s)
        self._rise: tuple[Vec3, float, float] | None = None
        self._pending_zero_rate: list[tuple[F64, F64]] = []

    # --- inputs ---------------------------------------------------------------------------
    def zero_rate(self, gyro_mean: F64, variance: F64) -> None:
        """A still window's mean gyro (rad/s, the same stream `step` takes) and the variance of
        that mean per axis: applied at the next correction."""
        self._pending_zero_rate.append((np.asarray(gyro_mean, float), np.asarray(variance, float)))

    def step(
        self, gyro: F64, accel: F64 | None, dt: float, mag: F64 | None = None
    ) -> tuple[F64, F64]:
        """Integrate a batch (n, 3) sampled every `dt` seconds; returns the orientation (n, 4)
        and the world-frame orientation error covariance (n, 6: xx, xy, xz, yy, yz, zz, rad^2)
        of each sample. NaN before the filter has seen gravity."""
        n = gyro.shape[0]
        q_out = np.empty((n, 4))
        c_out = np.empty((n, 6))
        if n == 0:
            return q_out, c_out
        i = 0
        if self.state is OrientState.INITIALISING:
            i = self._initialise(gyro, accel, mag, dt, q_out, c_out)
        per = max(1, round(self.update_s / dt))
        while i < n:
            # a batch is one chunk unless it spans several correction intervals: the fixed cost
            # of a chunk (a few dozen array operations) is what bounds the cost per sample
            left = per - self._iv.steps
            j = n if n - i <= left + per else i + max(left, 1)
            if i == 0 and j == n:  # (slices are NumPy calls too)
                g, a, qo, co = gyro, accel, q_out, c_out
            else:
                g, qo, co = gyro[i:j], q_out[i:j], c_out[i:j]
                a = None if accel is None else accel[i:j]
            self._chunk(g, a, dt, qo, co)
            if mag is not None and self.use_mag:
                self._mag_chunk(mag[i:j], qo)
            if self._iv.steps >= per:
                self._correct()
                co[:] = self._cov6()
            i = j
        return q_out, c_out

    # --- prediction ------------------------------------------------------------------------
    def _initialise(
        self, gyro: F64, accel: F64 | None, mag: F64 | None, dt: float, q_out: F64, c_out: F64
    ) -> int:
        """Integrate from an arbitrary start for `init_s` (the gyro keeps track of any motion
        meanwhile), then turn the world so the interval's mean specific force is up and (with a
        magnetometer) its mean field points north. Returns the samples consumed; their
        orientation is NaN."""
        n = int(gyro.shape[0])
        target = max(1, round(self.init_s / dt))
        # at least one sample: the fitted period may have moved the target below what is in
        j = int(min(n, max(target - self._iv.steps, 1)))
        q_out[:j] = np.nan
        c_out[:j] = np.nan
        self._chunk(gyro[:j], None if accel is None else accel[:j], dt, np.empty((j, 4)))
        if mag is not None and self.use_mag:
            self._mag_chunk(mag[:j], np.broadcast_to(self.q, (j, 4)))
        iv = self._iv
        if iv.steps < target:  # j == n: the whole batch went in
            return n
        self._iv = _Interval()
        mean = FORM_V @ iv.qqa.ravel() / max(iv.n, 1)
        g = float(np.linalg.norm(mean))
        if iv.n == 0 or not g > 0.0:  # no gravity seen (no valid accelerometer): wait on
            self.q = np.array([1.0, 0.0, 0.0, 0.0])
            q_out[j:] = np.nan
            c_out[j:] = np.nan
            return n
        self.q = _left(tilt_quaternion(mean)) @ self.q
        self._g0, self._g0_n = g, 1
        span = iv.t * iv.n / iv.steps
        tilt_var = self.noise.accel**2 / span / g**2 + INIT_TILT_SIGMA**2
        self.P = np.diag(
            [tilt_var, tilt_var, 0.0] + [self.bias_sigma**2] * 3 + [self.linear_var] * 2
        )
        if iv.m_n and self.use_mag:
            m = quat_to_matrix(self.q) @ (iv.m_sum / iv.m_n)
            bh = math.hypot(float(m[0]), float(m[1]))
            if bh > 0.0:
                self._rotate_world(0.0, 0.0, self._north(m))
                self._mag_ref = float(np.linalg.norm(m))
                self.heading_known = True
                self.P[2, 2] = INIT_HEADING_SIGMA**2
        self.state = OrientState.RUNNING
        return j

    def _north(self, m: F64) -> float:
        """The heading error a world-frame field implies: its horizontal angle from north (+y,
        less the declination), wrapped."""
        north = math.atan2(float(m[0]), float(m[1])) - self.declination
        return (north + math.pi) % (2 * math.pi) - math.pi

    def _seed_tilt(self, mean: F64, span_s: float) -> None:
        """Turn the estimate so an interval's mean specific force, in the world frame as the
        estimate sees it, points up (the shortest rotation: its axis is horizontal, so the
        heading stays), and start the tilt's covariance again; the bias that drove the tilt
        away is as uncertain as at the start."""
        q = _left(tilt_quaternion(mean)) @ self.q
        self.q = q / math.sqrt(float(q @ q))
        self._rise = None  # measured in the world the estimate has left
        g = float(np.linalg.norm(mean))
        self._g0 = g if self._g0 is None else self._g0
        var = self.noise.accel**2 / max(span_s, 1e-3) / g**2 + math.radians(1.0) ** 2
        # the heading keeps what it knew (a new tilt says nothing of it: zeroed, its variance
        # made the covariance singular)
        for i in (0, 1, 3, 4, 5, 6, 7):
            self.P[i, :] = 0.0
            self.P[:, i] = 0.0
        self.P[0, 0] = self.P[1, 1] = var
        self.P[3:6, 3:6] = _I3 * self.bias_sigma**2
        self.a = np.zeros(2)
        self.P[6, 6] = self.P[7, 7] = self.linear_var

    def reset_bias(self, sigma: float) -> None:
        """Forget the bias learned (a new calibration made it relative to the old one)."""
        self.b = np.zeros(3)
        self.P[3:6, :] = 0.0
        self.P[:, 3:6] = 0.0
        self.P[3:6, 3:6] = _I3 * sigma**2

    def _chunk(
        self, gyro: F64, accel: F64 | None, dt: float, q_out: F64, c_out: F64 | None = None
    ) -> None:
        """Integrate a chunk: each sample's orientation into `q_out` and, given `c_out`, the
        covariance as it stands into each of its rows (`_cov6`)."""
        m = gyro.shape[0]
        if m == 0:
            return
        if _kernels is None:
            self._chunk_numpy(gyro, accel, dt, q_out)
            if c_out is not None:
                c_out[:] = self._cov6()
            return
        iv = self._iv
        args = [gyro, self.b, dt, self.q, accel, float(iv.steps), q_out]
        args += [iv.qq, iv.qqa, iv.kqqa, self.P, c_out]
        try:  # the kernel reads float64 rows in place, and writes the chunk's end into self.q
            kn, k = _kernels.orient_chunk(*args)
        except (TypeError, ValueError, BufferError):  # another dtype or layout: a copy
            args[0] = np.ascontiguousarray(gyro, dtype=np.float64)
            if accel is not None:
                args[4] = np.ascontiguousarray(accel, dtype=np.float64)
            kn, k = _kernels.orient_chunk(*args)
        if k:
            iv.kn += kn
            iv.n += k
        iv.steps += m
        iv.t += m * dt

    def _chunk_numpy(self, gyro: F64, accel: F64 | None, dt: float, q_out: F64) -> None:
        """`_chunk` in NumPy: the compiled kernel's twin and reference."""
        m = gyro.shape[0]
        theta = (gyro - self.b) * dt
        c = np.cumsum(theta, axis=0)
        x, y, z = c[-1].tolist()
        if not math.isfinite(x + y + z):  # an invalid gyro sample: no turn during it
            theta = np.where(np.isfinite(theta), theta, 0.0)
            c = np.cumsum(theta, axis=0)
            x, y, z = c[-1].tolist()
        th2 = np.einsum("ij,ij->i", c, c)
        e = quat_exp(c, th2)  # each sample's rotation since the chunk began (first order)
        left = _left(self.q)
        q = e @ left.T
        q_out[:] = q
        iv = self._iv
        q2 = (q[:, :, None] * q[:, None, :]).reshape(m, 16)
        iv.qq += q2.sum(axis=0)
        if accel is not None:
            idx = _ramp(m) + iv.steps  # each sample's index in the interval
            if np.isnan(accel[:, 0]).any():
                ok = ~np.isnan(accel[:, 0])
                accel, q2, idx = accel[ok], q2[ok], idx[ok]
                kn = float(idx.sum())
            else:
                kn = m * iv.steps + 0.5 * m * (m - 1)
            k = accel.shape[0]
            if k:
                both = np.empty((k, 6))  # the plain and the index-weighted sums in one product
                both[:, :3] = accel
                np.multiply(accel, idx[:, None], out=both[:, 3:])
                sums = q2.T @ both
                iv.qqa += sums[:, :3]
                iv.kqqa += sums[:, 3:]
                iv.kn += kn
                iv.n += k
        iv.steps += m
        iv.t += m * dt
        # the chunk's end: its rotation vector to second order (Bortz's coning term)
        mm = ((c - theta).T @ theta).tolist()
        x += 0.5 * (mm[1][2] - mm[2][1])
        y += 0.5 * (mm[2][0] - mm[0][2])
        z += 0.5 * (mm[0][1] - mm[1][0])
        qn = left @ _quat_exp1(x, y, z)
        self.q = qn / math.sqrt(float(qn @ qn))

    def _propagate(self, iv: _Interval) -> None:
        """The covariance over the interval: d(dtheta)/dt = -R db, white gyro noise, the bias's
        random walk; the linear acceleration decays."""
        rho = math.exp(-iv.t / self.linear_time_s)
        scale = iv.t / max(iv.steps, 1)
        kalman.propagate(self.P, iv.qq, scale, rho, self._q_density, iv.t, self.linear_var, self.a)

    def _mag_chunk(self, mag: F64, q: F64) -> None:
        ok = np.isfinite(mag).all(axis=1)
        if not ok.any():
            return
        # the magnetometer is slow and coarse: each reading rotated by its sample's orientation
        r = quat_to_matrix(q[ok][len(q[ok]) // 2])
        self._iv.m_sum += r @ mag[ok].sum(axis=0)
        self._iv.m_n += int(ok.sum())

    def _cov6(self) -> F64:
        """The rotation error's covariance: xx, xy, xz, yy, yz, zz."""
        out: F64 = self.P.take(_COV6)
        return out

    # --- correction ------------------------------------------------------------------------
    def _correct(self) -> None:
        iv = self._iv
        if _kernels is not None and iv.n and not self._pending_zero_rate:
            self._correct_compiled(iv)
            if iv.m_n and self.use_mag:
                self._mag_update(iv)
            iv.reset()
            return
        self._propagate(iv)
        for mean, var in self._pending_zero_rate:
            y = (mean - self.b).tolist()
            self._update(_H_BIAS, tuple(y), tuple(var.tolist()), 3)
            self.counters.zero_rate_updates += 1
        self._pending_zero_rate = []
        if iv.n:
            self._accel_update(iv, kalman.force_sums(iv.qqa, iv.kqqa))
        if iv.m_n and self.use_mag:
            self._mag_update(iv)
        iv.reset()

    def _correct_compiled(self, iv: _Interval) -> None:
        """`_propagate` and `_accel_update` in one kernel call (`imud._kernels.orient_correct`,
        whose twin they are): the scalar state goes in and comes out as one array."""
        assert _kernels is not None
        nan = math.nan
        g0, prev_y, rise = self._g0, self._prev_y, self._rise
        (rx, ry, rz), rw, rt = rise if rise is not None else ((0.0, 0.0, 0.0), 0.0, 0.0)
        st = self._st
        st[:] = (
            self.linear_var, nan if g0 is None else g0, self._g0_n, self._adapt_n,
            *(prev_y if prev_y is not None else (nan, nan)), self._white_var, self._g_var,
            self._drifted_s, self._rejected_s, rx, ry, rz, rw, rt, 0.0 if rise is None else 1.0,
            0.0, 0.0, 0.0,
        )  # fmt: skip
        code = _kernels.orient_correct(
            self.P, iv.qq, iv.qqa, iv.kqqa, self._h, self.q, self.b, self.a, self._q_density,
            self._params, st, float(iv.n), float(iv.steps), iv.t, iv.kn, not self.heading_known,
        )  # fmt: skip
        (lv, g0, g0_n, adapt_n, pyx, pyy, white, g_var, drifted, rejected,
         rx, ry, rz, rw, rt, has_rise, mx, my, mz) = st.tolist()  # fmt: skip
        self.linear_var, self._white_var, self._g_var = lv, white, g_var
        self._g0 = None if math.isnan(g0) else g0
        self._g0_n, self._adapt_n = int(g0_n), int(adapt_n)
        self._prev_y = None if math.isnan(pyx) else (pyx, pyy)
        self._drifted_s, self._rejected_s = drifted, rejected
        self._rise = ((rx, ry, rz), rw, rt) if has_rise else None
        if code == 0:
            self.counters.accel_updates += 1
            self.state = OrientState.RUNNING
            return
        self.counters.accel_rejected += 1
        self.state = OrientState.ACCEL_REJECTED
        if code == 2:  # never agreeing for this long: the tilt is wrong, not the accelerometer
            self._seed_tilt(np.array([mx, my, mz]), iv.t)
            self.counters.recoveries += 1

    def _gravity_window(self, iv: _Interval, sums: tuple[float, ...]) -> tuple[Vec3, float]:
        """The world-frame mean specific force under a triangle spanning the last interval and
        this one (rising through the last, falling through this), and how long before this
        interval's end the window's centre lies (s).

        A plain mean over one interval passes a vibration of 1.5 cycles an interval at 21 % of
        its amplitude (a car's 15 Hz road shake at 10 Hz corrections), and how many cycles an
        interval holds depends on the batch size; the triangle passes 4.5 % (sinc squared).
        Overlapping windows correlate successive means, by 1/4 for white noise: the
        triangle's variance, 2/3 of a plain mean's, times the 1.5 that correlation costs a
        filter averaging them, is a plain mean's, so the measurement noise stays as it was.
        The first interval after the start or a re-seed is a plain mean."""
        steps = max(iv.steps, 1)
        total = sums[:3]
        rising = (sums[3] / steps, sums[4] / steps, sums[5] / steps)
        w_rise = iv.kn / steps
        w_fall = iv.n - w_rise
        prev = self._rise
        self._rise = (rising, w_rise, iv.t)
        if prev is None or not prev[1] + w_fall > 0.0:
            n = iv.n
            return (total[0] / n, total[1] / n, total[2] / n), 0.5 * iv.t
        vec, w, t_prev = prev
        # this interval's falling half weighs a sample at x of the way through it by (1 - x),
        # (1 - x) t before its end: its centre is t / 3 before; the last one's rising half
        # weighs by x, t + (1 - x) t_prev before: its centre is t + t_prev / 3 before
        centre = (w_fall * iv.t / 3.0 + w * (iv.t + t_prev / 3.0)) / (w_fall + w)
        k = w_fall + w
        return (
            (total[0] - rising[0] + vec[0]) / k,
            (total[1] - rising[1] + vec[1]) / k,
            (total[2] - rising[2] + vec[2]) / k,
        ), centre

    def _accel_update(self, iv: _Interval, sums: tuple[float, ...]) -> None:
        """Gravity's correction from the interval's specific-force `sums` (`kalman.force_sums`).
        Its scalar steps are Python floats: as NumPy calls on 2- and 3-vectors they cost more
        than all the matrix arithmetic (paced, after a sleep)."""
        (mx, my, mz), centre = self._gravity_window(iv, sums)
        g = math.sqrt(mx * mx + my * my + mz * mz)
        g0 = self._g0 if self._g0 is not None else g
        t = iv.n * iv.t / max(iv.steps, 1)
        # the datasheet's white noise averaged over the interval, what the innovations have
        # shown beyond it lately (vibration the average did not cancel, linear acceleration),
        # and |a| away from gravity (linear acceleration of that size, now)
        var = self.noise.accel**2 / t + (g - g0) ** 2
        ax, ay = self.a.tolist()
        yx, yy = mx - ax, my - ay
        yy2 = yx * yx + yy * yy
        # what the interval means scatter by from one to the next beyond the datasheet's white
        # noise (a vibration the mean did not cancel) is white noise too: measured by the
        # innovations' steps, which a slow acceleration hardly moves, it goes into the
        # measurement's noise, and only what is left (the slow part) into the linear
        # acceleration's state
        if self._prev_y is not None:
            dx, dy = yx - self._prev_y[0], yy - self._prev_y[1]
            self._white_var += WHITE_GAIN * (0.25 * (dx * dx + dy * dy) - self._white_var)
        self._prev_y = (yx, yy)
        var = max(var, self._white_var)
        # the error at the window's centre: the end's, plus the turn the bias made since (the
        # body's rotation over the interval taken as steady)
        h = self._h
        hph = kalman.gravity_h(self.P, iv.qq, centre / max(iv.steps, 1), g, h)
        # covariance matching: the innovations' spread beyond what the filter predicts is the
        # platform's linear acceleration (or vibration the average did not cancel); its
        # variance follows, within [LINEAR_FLOOR, linear_max], rejected intervals included
        excess = 0.5 * (yy2 - hph) - var
        self._adapt_n += 1
        lv = self.linear_var + max(ADAPT_GAIN, 1.0 / self._adapt_n) * excess  # a mean at first
        self.linear_var = min(max(lv, LINEAR_FLOOR**2), self.linear_max**2)
        # what gravity may teach the bias: nothing while the linear acceleration's level is
        # still unknown (at the start a drone's holding accelerations would be learned as a
        # bias that stays wrong for tens of seconds); all of it while the platform is steady;
        # else its horizontal components alone, which show in the tilt itself: the vertical one
        # shows only through the body's changing lean, faintly, and under linear acceleration
        # the innovations are systematic for seconds: that faint coupling would integrate them
        # into a wrong bias, and the heading with it
        if self._adapt_n < STEADY_AFTER:
            learn = Learn.IF_CONSISTENT
        elif self.linear_var <= LINEAR_STEADY**2:
            learn = Learn.ALL
        else:
            learn = Learn.HORIZONTAL
        if self._update(h, (yx, yy), (var, var), 2, learn):
            # the reference follows |a| slowly, from the intervals gravity explained: a
            # horizontal acceleration only ever adds to |a|, so a car's manoeuvres would raise
            # it, and every steady interval after them would look accelerated
            self._g0_n += 1
            self._g0 = g0 + max(G0_GAIN, 1.0 / self._g0_n) * (g - g0)  # a plain mean at first
            self._g_var += WHITE_GAIN * ((g - g0) ** 2 - self._g_var)
            self.counters.accel_updates += 1
            self._rejected_s = self._drifted_s = 0.0
            self.state = OrientState.RUNNING
            return
        self.counters.accel_rejected += 1
        self.state = OrientState.ACCEL_REJECTED
        self._rejected_s += iv.t
        # a horizontal acceleration as large as the innovation would add |y|^2 / 2g to |a|; if
        # |a| stays at gravity instead, the estimate drifted (a bias learned wrong), not the
        # platform: a hovering drone is not made to wait `recovery_s` at a 10-20 deg tilt. A
        # car's turn shows its |a| (2.5 m/s^2 of it: +0.32 m/s^2); a vertical acceleration
        # that hid one would need to cancel it for the whole run.
        claimed = yy2 / (2.0 * g0)
        sd = math.sqrt(self.noise.accel**2 / t + self._g_var)
        seen = g - g0
        drifted = seen < DRIFT_SHARE * claimed and claimed - seen > DRIFT_SIGMAS * sd
        self._drifted_s = self._drifted_s + iv.t if drifted else 0.0
        if self._drifted_s >= DRIFT_S or self._rejected_s >= self.recovery_s:
            # never agreeing for this long: the tilt is wrong, not the accelerometer
            self._seed_tilt(np.array([mx, my, mz]), iv.t)
            self.counters.recoveries += 1
            self._rejected_s = self._drifted_s = 0.0

    def _mag_update(self, iv: _Interval) -> None:
        m = iv.m_sum / iv.m_n
        bh = math.hypot(float(m[0]), float(m[1]))
        norm = float(np.linalg.norm(m))
        if bh <= 0.0 or norm <= 0.0:
            return
        if not self.heading_known:  # the first field seen (it came after the start)
            self._rotate_world(0.0, 0.0, self._north(m))
            self.P[2, :] = 0.0
            self.P[:, 2] = 0.0
            self.P[2, 2] = INIT_HEADING_SIGMA**2
            self._mag_ref = norm
            self.heading_known = True
            return
        ref = self._mag_ref if self._mag_ref is not None else norm
        # a disturbed field (iron nearby, currents) changes its magnitude; its dip seen through
        # the estimated tilt would also change with the tilt's own error, so only the
        # magnitude is checked here and the innovation gate does the rest
        if abs(norm - ref) > MAG_NORM_TOLERANCE * ref:
            self.counters.mag_rejected += 1
            return
        north = self._north(m)
        assert self.noise.mag is not None
        var = self.noise.mag**2 / bh**2  # held readings: not averaged down by the repeats
        h = np.zeros((1, N_STATES))
        h[0, 1] = -float(m[2]) / bh
        h[0, 2] = 1.0
        # the heading's drift teaches the bias along the vertical; the field's tilt coupling
        # would also reach the horizontal bias, through the tilt errors gravity left (a drone's
        # holding accelerations), and made it confident and wrong: considered, not learned
        if self._update(h, (north,), (var,), 1, Learn.VERTICAL):
            self.counters.mag_updates += 1
        else:
            self.counters.mag_rejected += 1

    def _update(
        self, h: F64, y: tuple[float, ...], r: tuple[float, ...], dof: int, learn: Learn = Learn.ALL
    ) -> bool:
        """A Kalman update with the chi-squared gate (`kalman.update`: `y` the innovation, `r`
        its noise variances); False (and nothing changed) if rejected. Without a magnetometer's
        heading, an update that learns less than all leaves the heading alone too: through its
        correlation with the tilt it would follow the acceleration taken for gravity."""
        gate = CHI2_2DOF_999 if dof == 2 else CHI2_1DOF_999 if dof == 1 else CHI2_3DOF_999
        keep_heading = not self.heading_known
        e = kalman.update(
            self.P, h, y, r, gate, learn, CHI2_2DOF_95, self.q, keep_heading, self.b, self.a
        )
        if e is None:
            return False
        self._turn_rise(e)
        return True

    def _rotate_world(self, x: float, y: float, z: float) -> None:
        """Turn the estimate by the world-frame rotation vector (x, y, z). In Python floats: a
        correction's few scalar steps cost less so than as NumPy calls."""
        e = kalman.rotation_quat(x, y, z)
        self.q = np.array(kalman.turned(e, self.q.tolist()))
        self._turn_rise(e)

    def _turn_rise(self, e: Quat) -> None:
        """The next gravity window's first half turns with the world (by e)."""
        if self._rise is not None:
            vec, weight, t = self._rise
            self._rise = (_rotate(e, vec), weight, t)
