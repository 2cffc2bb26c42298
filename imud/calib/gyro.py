"""Gyroscope calibration: bias from still data, and the full matrix from rotations between still
poses (corrected = C (raw - b)).

Bias. The mean of a still recording, with its standard error from the data's own noise (block
averaging, imud/calib/still.py), so coloured noise and slow drift widen the error bar instead of
hiding in it. Earth's rotation (7.292115e-5 rad/s, 15 deg/h) is inside any still mean: a gyro at
rest measures its projection on the sensor axes, which depends on latitude and heading. Without
the latitude nothing is subtracted; `details["earth_rate_rad_s"]` reports its size beside the
bias's standard error so a person can see whether it matters at their noise level. With the
latitude, its vertical part, Omega sin(latitude) along the measured "up" (the accelerometer reads
+g upward at rest; Earth's rotation points north and up in the northern hemisphere), is known and
subtracted; its horizontal part, Omega cos(latitude) towards north, cannot be told from the bias
in one pose (the heading is unknown) and stays in it: details say what was removed and what is
left. Only a session with several poses separates it (below).

Scale and misalignment (imu_tk's method, with uncertainty). Between two still poses the sensor is
turned by hand or by a table; the accelerometer gives gravity's direction in the body frame
before (u_k) and after (u_k+1). Integrating C (w - b) over the motion gives a rotation R, and a
right C makes R^T u_k = u_k+1. Each motion gives two equations (a direction has two degrees of
freedom); C has nine entries, so at least five motions are needed. Integration composes the exact
per-sample rotations exp(C (w_i - b) dt_i) (a rate held over each sample period), all motion
samples at once: the cumulative product is a blocked scan (sqrt(N) batched 3x3 products, not a
loop over samples), and the Jacobian is analytic: a change dC moves the end rotation by
dtheta = sum_i X_i^T J_r(phi_i) dC (w_i - b) dt_i, X_i the rotation from sample i to the end and
J_r the right Jacobian of the rotation exponential. Residuals are weighted by their full noise
covariance: the noise of both accelerometer means (shared by consecutive motions), the gyro's
white noise integrated over the motion (angle random walk N^2 T), and the bias's own uncertainty
(common to all motions); the fit is generalised least squares (Gauss-Newton, Levenberg-Marquardt
damping) and its covariance is (J^T V^-1 J)^-1, not rescaled; chi-squared tests the noise model.

The blind spot. A turn about the vertical leaves gravity where it was, so a rotation's scale
about an axis that was vertical whenever the sensor turned about it is invisible: the Fisher
information has a (near) null direction, dC = v v^T for that axis v. It is detected from the
covariance and named; with full_turns=True the caller says every motion that returned to its
starting pose was a whole number of turns (a turntable, a Ferraris session), which adds the
residual log(R) = 0 (the integrated angle is 2 pi k, k the nearest whole number) for those
motions and fixes that scale.

Earth's rotation in the full fit (latitude_deg given). The gyro measures rotation against the
stars: b + C^-1 (w + R(t)^T e), w the rate against the table, e Earth's rotation in a frame
fixed to the first still pose, R(t) the body's orientation in that frame. Two places feel it.
A motion of T seconds integrates to the rotation against the stars, Q; against the table it is
exp(-[R_k^T e] T) Q, R_k the pose it started from (exactly: the table turned by e T under it
meanwhile), which at MEMS grade is several times a turn's noise (7e-5 rad/s over a 6 s whole
turn: 4e-4 rad). And each still pose's gyro mean is b + C^-1 R_k^T e, a different vector in
each pose. With the latitude, e = Omega sin(lat) up + Omega cos(lat) north: up is the first
pose's gravity direction, north is unknown by one angle (the heading), which becomes one more
parameter. The fit is then joint over C, b and the heading: the motions' rows as above, plus
the still poses' gyro means as rows of their own (weighted by their block-averaged covariance),
so the bias is the sensor's own, not bias plus Earth rate; R_k are chained from the integrated
motions (their noise moves R_k^T e by ~1e-7 rad/s, nothing). The heading is started from a
grid after a fit without Earth (the cost on the heading circle can have two minima) and is
reported (degrees east of north of a body axis lying level in the first pose) with its sigma;
the parameters written (C, b) keep their names and their covariance is the joint one with the
heading marginalised out. Without the latitude, Earth's rotation is left out, as imu_tk and
imucal do: estimating its full vector (three more parameters) from MEMS-grade still poses of a
few seconds gives each component to about a third of its size, so it would cost more variance
in b and C than the bias it removes; its size against the noise is reported, and a refusal
names it when it is the likely cause.

Uncorrected effects, worth knowing: g-sensitivity of the gyro (a bias that depends on the
gravity direction; with the latitude the still poses' means are tested against each other, so
a strong one is refused, named), and a bias drifting between poses.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from imud import rotations as so3
from imud.calib.acceptance import DPH, Acceptance, Tolerance, model_error_floor
from imud.calib.estimate import AffineEstimate, Fit, Verdict
from imud.calib.recording import Recording
from imud.calib.stats import chi2_sf, f_sf
from imud.calib.still import (
    CalibrationRefused,
    StillInterval,
    check_still,
    find_still,
    interval_stats,
)

F64 = npt.NDArray[np.float64]

EARTH_RATE_RAD_S = 7.292115e-5  # WGS84 (NIMA TR8350.2 Table 3.1)
MIN_BIAS_S = 1.0
TEMP_LIMIT_C = 0.2
SAME_POSE_DEG = 10.0
WHOLE_TURN_RAD = math.pi / 4  # a motion that brings gravity back within this returned to its pose
OBSERVABLE_SIGMA = 0.01  # a direction of C known worse than 1 % is not determined by the data
AXES = "xyz"
BIAS_NAMES = ("b_x", "b_y", "b_z")
C_NAMES = tuple(f"C_{AXES[i]}{AXES[j]}" for i in range(3) for j in range(3))


def _latitude_rad(latitude_deg: float) -> float:
    if not math.isfinite(latitude_deg) or abs(latitude_deg) > 90.0:
        raise ValueError(f"latitude {latitude_deg} deg is not between -90 and 90")
    return math.radians(latitude_deg)


def fit_gyro_bias(
    rec: Recording,
    latitude_deg: float | None = None,
    significance: float = 0.01,
    acceptance: Acceptance | None = None,
) -> AffineEstimate:
    """The gyro bias (procedure "gyro-bias", matrix identity) from a still recording.

    Its covariance is that of the mean from the data's own noise (block averaging). Residuals:
    rms of the samples about the bias (rad/s), chi2 of ~1 s segment means against the scatter
    that covariance predicts (drift or a step shows up there), and the noise density
    N = se * sqrt(T) (rad/s/sqrt(Hz), Allan N convention: a T-second mean has sigma N / sqrt(T)).
    Rejected when the recording is not still (and when it moved), when the temperature changed
    by more than 0.2 degC, or when a sample hit full scale. Earth's rotation is inside the bias;
    with latitude_deg its vertical part (Omega sin(latitude) along the measured up) is removed,
    its horizontal part stays (details "earth_removed_rad_s", "earth_remaining_rad_s"; see the
    module docstring). The bias's covariance comes from block averaging, so a bias that wanders
    (flicker, warm-up) widens it rather than failing the segment test, which catches what that
    misses (a wobble within the segments' span). A recording without the accelerometer gives the
    bias as well; Earth's vertical part then cannot be placed."""
    if acceptance is not None:
        significance = acceptance.significance
    if rec.n < 2:
        raise CalibrationRefused(f"{rec.source or 'the recording'} has no samples")
    if latitude_deg is not None and np.isnan(rec.accel).all():
        raise CalibrationRefused(
            f"{rec.source or 'the recording'} has no accelerometer columns: --latitude places "
            "Earth's rotation along gravity's direction, which only they give; record the "
            "accelerometer too, or leave --latitude out"
        )
    duration = float(rec.t_ns[-1] - rec.t_ns[0]) * 1e-9
    if duration < MIN_BIAS_S:
        raise CalibrationRefused(
            f"{rec.source or 'the recording'} lasts {duration:.2f} s; a gyro bias needs at least "
            f"{MIN_BIAS_S:g} s of still data (its error falls as 1/sqrt(T): a minute or more is "
            "better)"
        )
    whole = interval_stats(rec, 0, rec.n)
    bias, cov = whole.gyro, whole.gyro_cov
    se = np.sqrt(np.diag(cov))
    density = se * math.sqrt(duration)
    dev = rec.gyro - bias
    sample_sd = np.sqrt(np.mean(dev * dev, axis=0))
    white = sample_sd / math.sqrt(rec.rate_hz)
    segments = int(min(20, max(2, duration // 1.0)))
    length = rec.n // segments
    seg = rec.gyro[: segments * length].reshape(segments, length, 3).mean(axis=1)
    predicted = np.diag(cov) * rec.n / length
    chi2 = float(np.sum((seg - bias) ** 2 / predicted))
    dof = 3 * (segments - 1)
    p_value = chi2_sf(chi2, dof)

    reasons: list[str] = []
    ok = True
    check = check_still(rec, significance)
    if not check.still:
        ok = False
        reasons.append(check.reason)
    elif p_value < significance:
        ok = False
        reasons.append(
            f"the gyro's mean wandered during the recording: its {segments} segment means "
            f"scatter {math.sqrt(chi2 / dof):.1f} times their predicted noise (chi2 {chi2:.1f}, "
            f"dof {dof}, p {p_value:.2g}); a temperature change or a bump: let the sensor warm "
            "up and record again"
        )
    if whole.temp_change_c is not None and abs(whole.temp_change_c) > TEMP_LIMIT_C:
        ok = False
        reasons.append(
            f"the temperature changed by {whole.temp_change_c:+.2f} degC during the recording "
            f"(more than {TEMP_LIMIT_C} degC), which moves the bias: let the sensor warm up and "
            "record again, or calibrate temperature first"
        )
    if whole.saturated:
        ok = False
        reasons.append("samples hit full scale: this is not a still recording; record again")
    earth_vs_se = EARTH_RATE_RAD_S / float(np.max(se))
    earth: dict[str, Any] = {
        "earth_rate_rad_s": EARTH_RATE_RAD_S,
        "earth_rate_over_sigma": earth_vs_se,
        "earth_rate_note": (
            f"Earth's rotation ({EARTH_RATE_RAD_S:.3e} rad/s) is inside this bias, up to "
            f"{earth_vs_se:.1f} times its standard error, depending on latitude and heading"
        ),
    }
    if latitude_deg is not None:
        # the vertical part along the measured up (the raw accelerometer's: its misalignment of
        # a degree or two moves this vector by ~1e-6 rad/s, far below the bias's error)
        lat = _latitude_rad(latitude_deg)
        up = whole.accel / float(np.linalg.norm(whole.accel))
        removed = EARTH_RATE_RAD_S * math.sin(lat) * up
        bias = bias - removed
        left = EARTH_RATE_RAD_S * abs(math.cos(lat))
        earth.update(
            {
                "latitude_deg": latitude_deg,
                "earth_removed_rad_s": removed.tolist(),
                "earth_remaining_rad_s": left,
                "earth_remaining_over_sigma": left / float(np.max(se)),
                "earth_rate_note": (
                    f"Earth's rotation: its vertical part at latitude {latitude_deg:g} deg "
                    f"({EARTH_RATE_RAD_S * math.sin(lat):.3e} rad/s along the measured up) is "
                    f"removed; its horizontal part ({left:.3e} rad/s, up to "
                    f"{left / float(np.max(se)):.1f} times the bias's standard error, towards "
                    "north, a direction this still recording cannot tell) stays in this bias: "
                    "a gyro-full session with the latitude separates it"
                ),
            }
        )
    details: dict[str, Any] = {
        "duration_s": duration,
        "noise_density": density.tolist(),
        "white_noise_density": white.tolist(),
        "segments": segments,
        **earth,
        "moved_s": [list(s) for s in check.moved],
        "temp_change_c": whole.temp_change_c,
    }
    fit = Fit(
        BIAS_NAMES,
        bias.copy(),
        cov,
        {
            "rms": float(np.sqrt(np.mean(sample_sd**2))),
            "chi2": chi2,
            "dof": float(dof),
            "p_value": p_value,
            "noise": float(np.sqrt(np.mean(density**2))),
        },
        details,
    )
    return AffineEstimate(
        sensor="gyro",
        procedure="gyro-bias",
        bias=bias.copy(),
        matrix=np.eye(3),
        fit=fit,
        verdict=Verdict(ok, tuple(reasons)),
        temperature_c=whole.temp_c,
    )


# ---- the full fit -------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Motion:
    before: int  # interval index
    after: int
    lo: int  # sample range [lo, hi) whose held rates carry the pose before to the pose after
    hi: int
    returns: bool  # gravity came back to (near) where it was (with full_turns: a whole turn)


@dataclass(frozen=True)
class _Integrated:
    rot: F64  # (S, 3, 3) rotation over each motion
    g: F64  # (S, 3, 9): d(end rotation vector) / d vec(C)
    h: F64  # (S, 3, 3): sum of X_i^T J_r dt, for the bias
    angle: F64  # (S,) unwrapped |sum phi| (for counting turns)


def _integrate(c: F64, w: F64, dt: F64, starts: F64) -> _Integrated:
    """All motions at once: w (M, 3) bias-free raw rates, dt (M,), motion s = samples
    starts[s]..starts[s+1]-1 of the concatenation."""
    phi = (w @ c.T) * dt[:, None]
    e, jr = so3.exp_and_jr(phi)
    pre = so3.cumulative_product(e)
    idx = np.asarray(starts[:-1], dtype=np.intp)
    ends = np.asarray(starts[1:], dtype=np.intp) - 1
    # P_i running product over all motions; within motion s (first sample f) the product from
    # its start to i is B_s^T P_i, B_s = P_(f-1); the rotation over the motion R_s = B_s^T P_end
    # and X_i^T = R_s^T B_s^T P_i, so K_i = X_i^T J_r(phi_i) = M_s (P_i J_r(phi_i)) with
    # M_s = R_s^T B_s^T constant over the motion: one batched product, then per-motion sums
    base_t = np.swapaxes(
        np.where(idx[:, None, None] > 0, pre[np.maximum(idx - 1, 0)], np.eye(3)), 1, 2
    )
    rot = base_t @ pre[ends]
    m = np.swapaxes(rot, 1, 2) @ base_t
    lj = pre @ jr
    wdt = w * dt[:, None]
    # G[x, a, b] = sum_i K_i[x, a] (w_i dt_i)[b] = M_s sum_i (P J)_i[:, a] (w dt)_i[b]
    sums = np.array(
        [
            (lj[a:z].reshape(-1, 9).T @ wdt[a:z]).reshape(3, 9)
            for a, z in zip(idx, ends + 1, strict=True)
        ]
    )
    g = m @ sums
    h = m @ np.add.reduceat(lj * dt[:, None, None], idx, axis=0)
    angle = np.linalg.norm(np.add.reduceat(phi, idx, axis=0), axis=1)
    return _Integrated(rot, g, h, angle)


def _basis(u: F64) -> F64:
    """Two orthonormal rows perpendicular to unit u."""
    a = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return np.array([e1, np.cross(u, e1)])


def _directions(means: F64, c: F64, b: F64) -> F64:
    v = (means - b) @ c.T
    out: F64 = v / np.linalg.norm(v, axis=1, keepdims=True)
    return out


def _gravity_directions(
    intervals: list[StillInterval], accel: AffineEstimate | None
) -> tuple[F64, F64]:
    """Unit gravity directions per pose and the covariance (3P, 3P) of all of them together:
    each pose's own noise, plus the accelerometer calibration's uncertainty, which moves every
    direction at once (carried through by central differences over its parameters)."""
    c = np.eye(3) if accel is None else accel.matrix
    b = np.zeros(3) if accel is None else accel.bias
    means = np.array([iv.accel for iv in intervals])
    u = _directions(means, c, b)
    cov = np.zeros((3 * len(intervals), 3 * len(intervals)))
    for k, iv in enumerate(intervals):
        nv = float(np.linalg.norm(c @ (iv.accel - b)))
        p = (np.eye(3) - np.outer(u[k], u[k])) / nv
        cov[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = p @ c @ iv.accel_cov @ c.T @ p.T
    if accel is not None:
        where = _affine_positions(accel.fit.names)
        jac = np.zeros((3 * len(intervals), len(where)))
        for col, (kind, i, j) in enumerate(where):
            step = 1e-6 * (1.0 if kind == "C" else max(1.0, float(np.abs(b).max())))
            moved = []
            for sign in (1.0, -1.0):
                c2, b2 = c.copy(), b.copy()
                if kind == "C":
                    c2[i, j] += sign * step
                else:
                    b2[i] += sign * step
                moved.append(_directions(means, c2, b2).ravel())
            jac[:, col] = (moved[0] - moved[1]) / (2 * step)
        idx = [accel.fit.names.index(n) for n in _names_of(where)]
        cov += jac @ accel.fit.covariance[np.ix_(idx, idx)] @ jac.T
    return u, cov


def _affine_positions(names: tuple[str, ...]) -> list[tuple[str, int, int]]:
    """("C", row, col) or ("b", axis, 0) for each parameter named C_ab or b_a."""
    out = []
    for name in names:
        kind, _, axes = name.partition("_")
        if kind == "C" and len(axes) == 2 and set(axes) <= set(AXES):
            out.append(("C", AXES.index(axes[0]), AXES.index(axes[1])))
        elif kind == "b" and len(axes) == 1 and axes in AXES:
            out.append(("b", AXES.index(axes), 0))
    return out


def _names_of(where: list[tuple[str, int, int]]) -> list[str]:
    return [f"C_{AXES[i]}{AXES[j]}" if k == "C" else f"b_{AXES[i]}" for k, i, j in where]


def _bias_of(bias: AffineEstimate | F64 | None, intervals: list[StillInterval]) -> tuple[F64, F64]:
    if isinstance(bias, AffineEstimate):
        names = bias.fit.names
        if names[:3] == BIAS_NAMES:
            return bias.bias.copy(), bias.fit.covariance[:3, :3].copy()
        pos = [names.index(n) for n in BIAS_NAMES] if set(BIAS_NAMES) <= set(names) else []
        cov = bias.fit.covariance[np.ix_(pos, pos)] if pos else np.zeros((3, 3))
        return bias.bias.copy(), cov
    if bias is not None:
        return np.asarray(bias, dtype=np.float64).copy(), np.zeros((3, 3))
    # combine the still poses' gyro means (inverse-covariance weighted)
    for k, iv in enumerate(intervals):
        if np.linalg.matrix_rank(iv.gyro_cov) < 3:
            raise CalibrationRefused(
                f"still pose {k} ({iv.t0_s:.1f}-{iv.t0_s + iv.duration_s:.1f} s): the gyro's "
                "noise there cannot be measured (an axis reads the same value throughout: a "
                "dead axis, or a gyro quantised coarser than its noise); check the recording"
            )
    info = sum(np.linalg.inv(iv.gyro_cov) for iv in intervals)
    rhs = sum(np.linalg.inv(iv.gyro_cov) @ iv.gyro for iv in intervals)
    cov = np.linalg.inv(np.asarray(info))
    return cov @ np.asarray(rhs), cov


@dataclass(frozen=True)
class _Earth:
    """Earth's rotation in the frame of the first still pose: e(psi) = vertical up +
    horizontal (cos psi n1 + sin psi n2), psi the angle of north from n1 about up."""

    up: F64
    n1: F64
    n2: F64
    vertical: float  # Omega sin(latitude)
    horizontal: float  # Omega cos(latitude)

    @classmethod
    def at_latitude(cls, up: F64, latitude_deg: float) -> _Earth:
        lat = _latitude_rad(latitude_deg)
        n1, n2 = _basis(up)
        return cls(up, n1, n2, EARTH_RATE_RAD_S * math.sin(lat), EARTH_RATE_RAD_S * math.cos(lat))

    def vector(self, psi: float) -> tuple[F64, F64, F64]:
        """e, de/dpsi and d2e/dpsi2 (minus the horizontal part)."""
        c, s = math.cos(psi), math.sin(psi)
        horizontal = self.horizontal * (c * self.n1 + s * self.n2)
        e = self.vertical * self.up + horizontal
        return e, self.horizontal * (c * self.n2 - s * self.n1), -horizontal

    def north(self, psi: float) -> F64:
        out: F64 = math.cos(psi) * self.n1 + math.sin(psi) * self.n2
        return out

    def heading(self, psi: float) -> tuple[str, float]:
        """The compass heading (degrees east of north) of the first body axis (x, y, z in turn)
        that lies within 45 deg of level in the first pose: what psi means to a person."""
        k = next((i for i in range(3) if abs(float(self.up[i])) < math.sqrt(0.5)), 0)
        axis = np.eye(3)[k] - float(self.up[k]) * self.up
        north = self.north(psi)
        east = np.cross(north, self.up)
        deg = math.degrees(math.atan2(float(axis @ east), float(axis @ north))) % 360.0
        return AXES[k], deg


@dataclass(frozen=True)
class _Problem:
    """What the fit holds fixed: the motion samples, gravity directions and still poses."""

    raw: F64  # (M, 3) raw gyro of the motion samples
    dt: F64  # (M,)
    starts: F64  # motion s = samples starts[s] .. starts[s+1]-1
    u: F64  # (P, 3) gravity directions of the poses
    motions: list[_Motion]
    durations: F64  # (S,) seconds each motion integrates over
    full_turns: bool
    means: F64 | None  # (P, 3) the poses' gyro means, as rows of their own (with the latitude)
    earth: _Earth | None  # None: Earth's rotation left out


@dataclass(frozen=True)
class _Linearised:
    r: F64  # residuals
    jac: F64  # d r / d (vec C, b, heading), (R, 13)
    d2_psi: F64  # d2 r / d heading2, (R,)
    d_u: F64  # d r / d (pose gravity directions), (R, 3 * poses)
    d_theta: F64  # d r / d (each motion's integrated rotation error), (R, 3 * motions)
    d_m: F64  # d r / d (the poses' gyro means), (R, 3 * poses)
    it: _Integrated
    poses: F64  # (P, 3, 3) each pose's orientation in the first pose's frame


C_COLS = list(range(9))
B_COLS = [9, 10, 11]
PSI = 12


def _linearise(prob: _Problem, x: F64, it: _Integrated | None = None) -> _Linearised:
    """Residuals and their derivatives at x = (vec C, b, heading). Gravity rows:
    B (R^T u_before - u_after), B two axes perpendicular to u_after, R the rotation against the
    table: R = exp(-[R_k^T e] T) Q, Q the integrated one (against the stars); a change dtheta of
    Q (on the right) moves R^T u by [p]x dtheta. Turn rows (full_turns, motions back to their
    pose): log(R), moved by J_r^-1 dtheta. A heading change turns exp(-[phi]) on the right by
    -J_r(-phi) dphi, i.e. Q by dtheta = -Q^T J_r(-phi) dphi. Pose rows (with the means): the
    gyro mean minus b + C^-1 R_k^T e. R_k's own dependence on C and the heading is dropped from
    the Jacobian (Earth's rate times an angle error: ~1e-7 rad/s)."""
    c = x[:9].reshape(3, 3)
    b = x[9:12]
    if it is None:
        it = _integrate(c, prob.raw - b, prob.dt, prob.starts)
    u, motions = prob.u, prob.motions
    n_poses = u.shape[0]
    if prob.earth is None:
        e, de, de2 = np.zeros(3), np.zeros(3), np.zeros(3)
    else:
        e, de, de2 = prob.earth.vector(float(x[PSI]))
    des = np.column_stack([de, de2])  # the residuals are linear in e to first order
    # the poses' orientations, chained through the motions (each joins pose k to k + 1)
    poses = np.broadcast_to(np.eye(3), (n_poses, 3, 3)).copy()
    rel = it.rot.copy()
    d_psi = np.zeros((len(motions), 3, 2))
    by_before = {m.before: s for s, m in enumerate(motions)}
    for k in range(n_poses - 1):
        s = by_before.get(k)
        if s is None:
            poses[k + 1] = poses[k]
            continue
        if prob.earth is not None:
            t = float(prob.durations[s])
            ex, jr = so3.exp_and_jr(-(poses[k].T @ e)[None] * t)
            rel[s] = ex[0] @ it.rot[s]
            d_psi[s] = -it.rot[s].T @ jr[0] @ (t * (poses[k].T @ des))
        poses[k + 1] = poses[k] @ rel[s]
    n_turn = sum(3 for m in motions if prob.full_turns and m.returns)
    n_mean = 0 if prob.means is None else 3 * n_poses
    n_rows = 2 * len(motions) + n_turn + n_mean
    r = np.zeros(n_rows)
    jac = np.zeros((n_rows, 13))
    d2_psi = np.zeros(n_rows)
    d_u = np.zeros((n_rows, 3 * n_poses))
    d_theta = np.zeros((n_rows, 3 * len(motions)))
    d_m = np.zeros((n_rows, 3 * n_poses))
    row = 0
    for s, m in enumerate(motions):
        rot, g, hc = rel[s], it.g[s], -it.h[s] @ c
        p = rot.T @ u[m.before]
        basis = _basis(u[m.after])
        bp = basis @ so3.skew(p)
        rows = slice(row, row + 2)
        r[rows] = basis @ (p - u[m.after])
        jac[rows, :9] = bp @ g
        jac[rows, 9:12] = bp @ hc
        jac[rows, PSI], d2_psi[rows] = (bp @ d_psi[s]).T
        d_u[rows, 3 * m.before : 3 * m.before + 3] += basis @ rot.T
        d_u[rows, 3 * m.after : 3 * m.after + 3] -= basis
        d_theta[rows, 3 * s : 3 * s + 3] = bp
        row += 2
        if prob.full_turns and m.returns:
            rho = so3.log(rot)
            jinv = so3.jr_inv(rho)
            rows = slice(row, row + 3)
            r[rows] = rho
            jac[rows, :9] = jinv @ g
            jac[rows, 9:12] = jinv @ hc
            jac[rows, PSI], d2_psi[rows] = (jinv @ d_psi[s]).T
            d_theta[rows, 3 * s : 3 * s + 3] = jinv
            row += 3
    if prob.means is not None:
        c_inv = np.linalg.inv(c)
        for k in range(n_poses):
            y = c_inv @ (poses[k].T @ e)
            rows = slice(row, row + 3)
            r[rows] = prob.means[k] - b - y
            jac[rows, :9] = np.kron(c_inv, y[None, :])  # d(-C^-1 z) = C^-1 dC C^-1 z
            jac[rows, 9:12] = -np.eye(3)
            jac[rows, PSI], d2_psi[rows] = (-c_inv @ (poses[k].T @ des)).T
            d_m[rows, 3 * k : 3 * k + 3] = np.eye(3)
            row += 3
    return _Linearised(r, jac, d2_psi, d_u, d_theta, d_m, it, poses)


def _block_diag(blocks: F64) -> F64:
    k = blocks.shape[0]
    out = np.zeros((3 * k, 3 * k))
    for i in range(k):
        out[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = blocks[i]
    return out


def _percent(sigma: float) -> str:
    """A relative sigma as a percentage; beyond 1000 % the data do not bound it at all."""
    return f"{100 * sigma:.0f} %" if sigma <= 10.0 else "unbounded"


def _unobservable(cov_c: F64) -> str | None:
    """The worst-determined direction of C, named, when the data cannot fix it to 1 %."""
    vals, vecs = np.linalg.eigh(cov_c)
    sigma = math.sqrt(max(float(vals[-1]), 0.0))
    if sigma <= OBSERVABLE_SIGMA:
        return None
    m = vecs[:, -1].reshape(3, 3)
    sym_vals, sym_vecs = np.linalg.eigh(0.5 * (m + m.T))
    k = int(np.argmax(np.abs(sym_vals)))
    axis = sym_vecs[:, k]
    axis = axis if axis[int(np.argmax(np.abs(axis)))] > 0 else -axis
    share = abs(float(axis @ m @ axis)) / float(np.linalg.norm(m))
    name = AXES[int(np.argmax(np.abs(axis)))]
    where = "(" + ", ".join(f"{a:.2f}" for a in axis) + ")"
    if share > 0.9:
        return (
            f"the gyro's scale about its {name} axis {where} is not determined (sigma "
            f"{_percent(sigma)}): it only turned about that axis while the axis was vertical, "
            "which leaves gravity unchanged; turn it about that axis while it lies horizontal, or "
            "make whole turns (a turntable) and pass --full-turns"
        )
    return (
        f"a combination of the gyro matrix is not determined (sigma {_percent(sigma)}, mostly "
        f"the {name} axis {where}): add rotations about all three axes between still poses"
    )


@dataclass(frozen=True)
class _Solved:
    x: F64
    lin: _Linearised
    iterations: int


def _solve(
    lin_at: Callable[[F64], _Linearised],
    weights: Callable[[_Linearised], F64],
    x0: F64,
    cols: list[int],
) -> _Solved:
    """Levenberg-Marquardt on the parameters `cols` of x (generalised least squares, weights
    from the noise covariance at the current point). The heading gets Newton's full curvature:
    it is an angle on a circle, weakly determined, and the residuals' own curvature along it
    (Gauss-Newton leaves it out) is a good fraction of the information, which would make the
    iteration converge only linearly."""
    x = x0.copy()
    lin = lin_at(x)
    lam = 1e-3
    iterations = 0
    n = len(cols)
    for iterations in range(1, 51):  # noqa: B007 (reported below)
        vinv = weights(lin)
        jac = lin.jac[:, cols]
        cost = float(lin.r @ vinv @ lin.r)
        info = jac.T @ vinv @ jac
        grad = jac.T @ vinv @ lin.r
        hess = info.copy()
        if PSI in cols:
            k = cols.index(PSI)
            hess[k, k] += max(float(lin.d2_psi @ vinv @ lin.r), -0.5 * float(info[k, k]))
        ridge = 1e-12 * float(np.trace(info)) * np.eye(n)
        step = np.linalg.solve(hess + lam * np.diag(np.diag(hess)) + ridge, -grad)
        x_trial = x.copy()
        x_trial[cols] += step
        trial = lin_at(x_trial)
        cost2 = float(trial.r @ vinv @ trial.r)
        if cost2 <= cost:
            x, lin = x_trial, trial
            lam = max(lam / 10.0, 1e-12)
            # converged: the step is tiny against the parameters' uncertainty (its length in
            # the information metric), whatever it does along an undetermined direction
            if float(step @ info @ step) < 1e-6 or cost - cost2 < 1e-9 * (1.0 + cost):
                break
        else:
            lam *= 10.0
            # no step lowers the cost: at the minimum to numerical precision (a rejected step
            # already negligible against the uncertainty, or damping that left none)
            if float(step @ info @ step) < 1e-6 or lam > 1e8:
                break
    return _Solved(x, lin, iterations)


# the model error accepted by default on each component of a rotation's gravity-direction
# residual: 1 deg (a direction error up to 1.4 deg), what a pose placed by hand and a turn of a
# few seconds at 100 Hz leave (a scale error of 0.5 % over a quarter turn is 0.45 deg)


def _means_floor(v: F64, r: F64, n_mean: int, n_par: int, significance: float) -> float:
    """The still poses' model-error floor, rad/s (with the latitude: their gyro means are rows
    of the fit): added to each mean's variance, it makes their chi-squared its degrees of
    freedom (less the `n_par` the means determine, the bias and heading). A bias that drifts
    through the session (warm-up, temperature) scatters them beyond their noise."""
    if n_mean == 0:
        return 0.0
    v_m, r_m = v[-n_mean:, -n_mean:], r[-n_mean:]

    def chi2_at(s2: float) -> float:
        return float(r_m @ np.linalg.solve(v_m + s2 * np.eye(n_mean), r_m))

    rms = float(np.sqrt(np.mean(r_m**2)))
    return model_error_floor(chi2_at, n_mean - n_par, rms, significance)


def _rotation_floor(
    noise: Callable[[_Linearised], F64],
    lin: _Linearised,
    n_mean: int,
    n_par: int,
    significance: float,
    mean_par: int = 0,
) -> float:
    """The rotations' model-error floor, rad: added to each rotation row's variance, it makes
    the rotation rows' chi-squared their degrees of freedom. Only those rows: the still poses'
    means (with the latitude) have their own test, and a rotation's error cannot explain them.
    `mean_par`: the parameters the means alone determine (bias and heading)."""
    v = noise(lin)
    n_rot = v.shape[0] - n_mean
    v_rot = v[:n_rot, :n_rot]
    r_rot = lin.r[:n_rot]
    dof = n_rot - (n_par - mean_par)

    def chi2_at(s2: float) -> float:
        return float(r_rot @ np.linalg.solve(v_rot + s2 * np.eye(n_rot), r_rot))

    rms = float(np.sqrt(np.mean(r_rot**2))) if n_rot else 0.0
    return model_error_floor(chi2_at, dof, rms, significance)


UNIT_FACTOR = 180.0 / math.pi  # deg/s read as rad/s turns 57 times too far


def _check_turn_units(w: F64, dt: F64, starts: F64, u: F64, motions: list[_Motion]) -> None:
    """Refuse a gyro in the wrong unit before fitting it: over the motions that tip gravity by
    30 deg or more, the raw gyro's angle is at least gravity's (a turn about the vertical adds
    angle gravity does not see) and at most a few times it; deg/s read as rad/s turns 57 times
    too far, rad/s read as deg/s 57 times too short."""
    angles = _integrate(np.eye(3), w, dt, starts).angle  # unwrapped: many turns stay many
    tipped = [
        (float(angles[s]), math.acos(float(np.clip(u[m.before] @ u[m.after], -1.0, 1.0))))
        for s, m in enumerate(motions)
    ]
    ratios = [a / g for a, g in tipped if g >= math.radians(30.0)]
    if len(ratios) < 3:
        return
    ratio = float(np.median(ratios))
    if ratio > 20.0:
        raise CalibrationRefused(
            f"the gyro turned {ratio:.0f} times as far as gravity did over the recording's "
            f"rotations (median of {len(ratios)}): a gyro in deg/s read as rad/s (--gyro-units "
            f"dps), or counts per deg/s given as per rad/s (--gyro-counts); {UNIT_FACTOR:.1f} "
            "is the factor between them"
        )
    if ratio < 1.0 / 8.0:
        raise CalibrationRefused(
            f"the gyro turned {1 / ratio:.0f} times less than gravity did over the recording's "
            f"rotations (median of {len(ratios)}): a gyro in rad/s read as deg/s (--gyro-units "
            f"rad/s), or counts per rad/s given as per deg/s (--gyro-counts); {UNIT_FACTOR:.1f} "
            "is the factor between them"
        )


def _worst_rotation(
    lin: _Linearised,
    v: F64,
    motions: list[_Motion],
    full_turns: bool,
    n_par: int,
    significance: float,
) -> tuple[int, float, float] | None:
    """The rotation whose residual stands out from the others' (the one sample gap, bump or
    slipped pose that a model-error floor fitted to all of them would absorb): each rotation's
    chi-squared against the fitted noise and floor, per row, over the others' per row is
    Fisher's F; tested over all rotations (Bonferroni). (index, ratio, p) of a refused one."""
    z2, dims, row = [], [], 0
    for m in motions:
        d = 5 if full_turns and m.returns else 2
        rows = slice(row, row + d)
        z2.append(float(lin.r[rows] @ np.linalg.solve(v[rows, rows], lin.r[rows])))
        dims.append(d)
        row += d
    if len(motions) < 4:
        return None
    w = int(np.argmax(np.array(z2) / np.array(dims)))
    others = sum(z2) - z2[w]
    nu = sum(dims) - dims[w] - n_par
    if nu <= 0 or others <= 0:
        return None
    ratio = (z2[w] / dims[w]) / (others / nu)
    p = min(1.0, f_sf(ratio, dims[w], nu) * len(motions))
    return (w, ratio, p) if p < significance else None


def fit_gyro_full(
    rec: Recording,
    intervals: list[StillInterval] | None = None,
    bias: AffineEstimate | F64 | None = None,
    full_turns: bool = False,
    accel: AffineEstimate | None = None,
    latitude_deg: float | None = None,
    significance: float = 0.01,
    acceptance: Acceptance | None = None,
) -> AffineEstimate:
    """Gyro scale and misalignment (a general 3x3 C, procedure "gyro-full") from the rotations
    between consecutive still poses (see the module docstring).

    intervals: the still poses (None: found in rec). bias: a gyro-bias estimate (its covariance
    is carried into C's), a (3,) vector (taken as exact), or None (from the still poses' gyro
    means: their combined mean, or with latitude_deg fitted jointly with Earth's rotation). A
    given bias is held fixed; it must be the sensor's own, without Earth's rotation in it, for a
    fit with latitude_deg (a still capture's mean holds the horizontal part: leave bias None).
    accel: an accelerometer calibration to correct the gravity directions with (without one,
    the raw accelerometer's misalignment leaks into C; with one, C maps the gyro into the
    calibrated accelerometer's frame). full_turns: every motion that returned to its starting
    pose was a whole number of turns. latitude_deg: model Earth's rotation (one more parameter,
    the heading, reported in details["earth"]); None leaves it out. Raises CalibrationRefused
    when too few rotations were found; otherwise the verdict says whether C may be used (named
    undetermined axes, chi2; refused below p = `significance`)."""
    acceptance = acceptance or Acceptance(significance=significance)
    significance = acceptance.significance
    if intervals is None:
        intervals = find_still(rec)
    intervals = sorted(intervals, key=lambda iv: iv.start)
    if len(intervals) < 2:
        raise CalibrationRefused(
            f"found {len(intervals)} still poses; the gyro matrix needs rotations between still "
            "poses: turn the sensor between poses held still for a few seconds"
        )
    b, bias_cov = _bias_of(bias, intervals)
    u, cov_u = _gravity_directions(intervals, accel)
    earth = None if latitude_deg is None else _Earth.at_latitude(u[0], latitude_deg)
    free_bias = earth is not None and bias is None
    cos_same = math.cos(math.radians(SAME_POSE_DEG))
    motions = [
        _Motion(k, k + 1, a.end - 1, nxt.start, float(u[k] @ u[k + 1]) > cos_same)
        for k, (a, nxt) in enumerate(itertools.pairwise(intervals))
        if nxt.start > a.end - 1
    ]
    if not motions:
        raise CalibrationRefused("the still poses follow each other with no rotation between")
    lo = np.array([m.lo for m in motions])
    hi = np.array([m.hi for m in motions])
    sel = np.concatenate([np.arange(a, z) for a, z in zip(lo, hi, strict=True)])
    raw = rec.gyro[sel]
    dt = (rec.t_ns[sel + 1] - rec.t_ns[sel]).astype(np.float64) * 1e-9
    starts = np.concatenate([[0], np.cumsum(hi - lo)]).astype(np.float64)
    first = starts[:-1].astype(np.intp)
    durations = np.add.reduceat(dt, first)
    period = float(np.median(dt))
    gaps = [k for k, longest in enumerate(np.maximum.reduceat(dt, first)) if longest > 1.5 * period]
    partial = 0
    if full_turns:
        # a motion back to its pose is a whole turn when the raw gyro's net rotation is within
        # 45 deg of none: no plausible scale error turns a quarter turn about the vertical
        # into a whole one, so such motions stay ordinary (gravity-only) ones
        rot0 = _integrate(np.eye(3), raw - b, dt, starts).rot
        whole = [
            m.returns and float(np.linalg.norm(so3.log(r))) < WHOLE_TURN_RAD
            for m, r in zip(motions, rot0, strict=True)
        ]
        partial = sum(m.returns for m in motions) - sum(whole)
        motions = [replace(m, returns=bool(t)) for m, t in zip(motions, whole, strict=True)]
    _check_turn_units(raw - b, dt, starts, u, motions)
    n_turn = 3 * sum(m.returns for m in motions) if full_turns else 0
    if full_turns and n_turn == 0:
        raise CalibrationRefused(
            "full_turns was given but no rotation brought the sensor back to the pose it started "
            "from after a whole number of turns: drop --full-turns, or turn whole turns"
        )
    if 2 * len(motions) + n_turn < len(C_NAMES) + 1:
        need = math.ceil((len(C_NAMES) + 1 - n_turn) / 2) - len(motions)
        raise CalibrationRefused(
            f"found {len(motions)} rotations between still poses; the nine matrix entries need "
            f"at least {len(motions) + need}: add {need} more turns to new poses, about "
            "different axes, each followed by a few seconds still"
        )
    density = np.median([iv.gyro_se * math.sqrt(max(iv.duration_s, 1e-9)) for iv in intervals], 0)
    n2 = float(np.mean(density**2))  # angle random walk, isotropic, rad^2/s
    cov_theta = _block_diag(np.array([n2 * d * np.eye(3) for d in durations]))
    means = None if earth is None else np.array([iv.gyro for iv in intervals])
    cov_m = _block_diag(np.array([iv.gyro_cov for iv in intervals]))
    prob = _Problem(raw, dt, starts, u, motions, durations, full_turns, means, earth)
    n_mean = 0 if means is None else means.size
    floor2 = 0.0  # the model error's variance on each rotation's residual, rad^2
    floor_m2 = 0.0  # ... on each still pose's gyro mean (with the latitude), (rad/s)^2

    def noise(lin: _Linearised) -> F64:
        """The residuals' covariance: their noise and the model error found so far."""
        v = measured(lin)
        if floor2 > 0:  # on the rotations' rows: hand motion, a pose that settled, drift
            n_rot = v.shape[0] - n_mean
            v[np.arange(n_rot), np.arange(n_rot)] += floor2
        if floor_m2 > 0:  # on the poses' means: the bias drifting through the session
            k = np.arange(v.shape[0] - n_mean, v.shape[0])
            v[k, k] += floor_m2
        return v

    def measured(lin: _Linearised) -> F64:
        """The residuals' covariance from the measured noise alone."""
        v = lin.d_u @ cov_u @ lin.d_u.T + lin.d_theta @ cov_theta @ lin.d_theta.T
        if means is not None:
            v += lin.d_m @ cov_m @ lin.d_m.T
        if not free_bias:
            d_b = lin.jac[:, B_COLS]
            v += d_b @ bias_cov @ d_b.T
        out: F64 = 0.5 * (v + v.T)
        return out

    def weights(lin: _Linearised) -> F64:
        out: F64 = np.asarray(np.linalg.inv(noise(lin)), dtype=np.float64)
        return out

    x = np.concatenate([np.eye(3).ravel(), b, [0.0]])
    cols = C_COLS + (B_COLS if free_bias else [])
    if earth is None:
        sol = _solve(lambda y: _linearise(prob, y), weights, x, cols)
    else:
        # without Earth first (C lands near its value), then the heading from a grid on the
        # circle at that C and b (the cost there can have two minima), then all together
        flat = replace(prob, earth=None)
        sol = _solve(lambda y: _linearise(flat, y), weights, x, cols)
        vinv = weights(sol.lin)
        grid = np.radians(np.arange(0.0, 360.0, 10.0))
        costs = []
        for psi in grid:
            y = sol.x.copy()
            y[PSI] = psi
            r = _linearise(prob, y, sol.lin.it).r
            costs.append(float(r @ vinv @ r))
        x = sol.x.copy()
        x[PSI] = grid[int(np.argmin(costs))]
        if earth.horizontal > 1e-12:  # at a pole Earth's rotation is vertical: no heading
            cols = [*cols, PSI]
        first_iterations = sol.iterations
        sol = _solve(lambda y: _linearise(prob, y), weights, x, cols)
        sol = replace(sol, iterations=sol.iterations + first_iterations)
    x, lin, iterations = sol.x, sol.lin, sol.iterations
    # a model error on the rotations, estimated only where the noise alone is refused, and the
    # fit redone with it in the weights (imud/calib/acceptance.py)
    floor = floor_m = 0.0
    for _ in range(10):
        if acceptance.strict:
            break
        mean_par = 0 if means is None else (4 if free_bias else 1)
        new = _rotation_floor(measured, lin, n_mean, len(cols), significance, mean_par)
        new_m = _means_floor(measured(lin), lin.r, n_mean, mean_par, significance)
        if abs(new - floor) <= 1e-3 * max(new, 1e-300) and abs(new_m - floor_m) <= 1e-3 * max(
            new_m, 1e-300
        ):
            break
        floor, floor2 = new, new * new
        floor_m, floor_m2 = new_m, new_m * new_m
        sol = _solve(lambda y: _linearise(prob, y), weights, x, cols)
        x, lin, iterations = sol.x, sol.lin, iterations + sol.iterations
    c, b = x[:9].reshape(3, 3).copy(), x[9:12].copy()
    vinv = weights(lin)
    jac = lin.jac[:, cols]
    info = jac.T @ vinv @ jac
    cov_x = np.asarray(
        np.linalg.inv(info + 1e-15 * float(np.trace(info)) * np.eye(len(cols))), np.float64
    )
    # the joint covariance of (vec C, b, heading): the fitted ones from the information, a fixed
    # bias with its own covariance and its effect on the fitted ones
    cov_all = np.zeros((13, 13))
    cov_all[np.ix_(cols, cols)] = cov_x
    if not free_bias:
        cross = -cov_x @ jac.T @ vinv @ lin.jac[:, B_COLS] @ bias_cov
        cov_all[np.ix_(cols, B_COLS)] = cross
        cov_all[np.ix_(B_COLS, cols)] = cross.T
        cov_all[np.ix_(B_COLS, B_COLS)] = bias_cov
    cov = cov_all[:12, :12]
    cov = 0.5 * (cov + cov.T)
    cov_c = cov_all[:9, :9]
    chi2 = float(lin.r @ np.linalg.solve(measured(lin), lin.r))  # against the noise alone
    dof = lin.r.shape[0] - len(cols)
    p_value = chi2_sf(chi2, dof) if dof > 0 else 1.0
    tolerance = acceptance.tolerance_for(Tolerance.GYRO_ROTATION)
    named = acceptance.source(Tolerance.GYRO_ROTATION)
    notes_floor = ""
    # Earth's rotation against the noise: over the longest motion, and in a still pose's mean
    longest = float(np.max(durations))
    se_pose = float(np.min([np.sqrt(np.max(np.diag(iv.gyro_cov))) for iv in intervals]))
    earth_turn = EARTH_RATE_RAD_S * math.sqrt(longest / n2) if n2 > 0 else math.inf
    earth_pose = EARTH_RATE_RAD_S / se_pose if se_pose > 0 else math.inf

    reasons: list[str] = []
    weak = _unobservable(cov_c)
    if weak is not None:
        reasons.append(weak)
    pose_part: tuple[float, int, float] | None = None
    if means is not None:
        # the still poses' means alone (their block of the noise, their rows' share of chi2)
        n_mean = means.size
        v_m = measured(lin)[-n_mean:, -n_mean:]
        r_m = lin.r[-n_mean:]
        chi2_m = float(r_m @ np.linalg.solve(v_m, r_m))
        dof_m = n_mean - (4 if free_bias else 1)  # less the bias and heading they determine
        pose_part = (chi2_m, dof_m, chi2_sf(chi2_m, dof_m) if dof_m > 0 else 1.0)
    if not acceptance.strict and floor > tolerance:
        reasons.append(
            f"the rotations hold a model error of {math.degrees(floor):.2f} deg each beyond "
            f"their noise ({math.degrees(math.sqrt(n2)):.3f} deg/sqrt(s)), more than the "
            f"tolerance of {math.degrees(tolerance):.2g} deg ({named}): a pose moved, "
            "the sensor was not still where it seemed, or samples were lost during a turn"
        )
    elif not acceptance.strict and floor > 0:
        notes_floor = (
            f"model error {math.degrees(floor):.2f} deg a rotation beyond the noise, within the "
            f"tolerance of {math.degrees(tolerance):.2g} deg ({named}); the parameters' "
            "uncertainty includes it"
        )
    notes_means = ""
    if means is not None and not acceptance.strict:
        tolerance_m = acceptance.tolerance_for(Tolerance.GYRO_BIAS)
        named_m = acceptance.source(Tolerance.GYRO_BIAS)
        if floor_m > tolerance_m:
            reasons.append(
                f"the still poses' gyro means scatter by a model error of {floor_m / DPH:.0f} "
                "deg/h beyond their noise and Earth's rotation, more than the tolerance of "
                f"{tolerance_m / DPH:g} deg/h ({named_m}): the bias drifted between poses (let "
                "the sensor warm up and its temperature settle), the gyro is sensitive to "
                "gravity (g-sensitivity), or the latitude is wrong"
            )
        elif floor_m > 0:
            notes_means = (
                f"the still poses' gyro means: model error {floor_m / DPH:.0f} deg/h beyond "
                f"their noise, within the tolerance of {tolerance_m / DPH:g} deg/h ({named_m}); "
                "the bias's and heading's uncertainty includes it"
            )
    if p_value < significance and acceptance.strict:
        poses_fail = pose_part is not None and pose_part[2] < significance
        if pose_part is not None and poses_fail:
            chi2_m, dof_m, _ = pose_part
            reasons.append(
                f"the still poses' gyro means differ by {math.sqrt(chi2_m / dof_m):.1f} times "
                f"what Earth's rotation and their noise allow (chi2 {chi2_m:.1f} on {dof_m} dof): "
                "the bias drifted between poses (let the sensor warm up), the gyro is sensitive "
                "to gravity (g-sensitivity), or the latitude is wrong"
            )
        if acceptance.strict and (
            not poses_fail or chi2 - (pose_part[0] if pose_part else 0.0) > 2 * dof
        ):
            earth_hint = (
                f", or Earth's rotation (it integrates to {earth_turn:.1f} times the noise over "
                "the longest rotation here: give the latitude, --latitude)"
                if earth is None and earth_turn >= 1.0
                else ""
            )
            reasons.append(
                f"the rotations disagree with gravity by {math.sqrt(chi2 / dof):.1f} times their "
                f"noise (chi2 {chi2:.1f}, dof {dof}, p {p_value:.2g}): a pose moved, the sensor "
                "was not still where it seemed, or samples were lost during a turn"
                + (", or a turn was not whole" if full_turns else "")
                + earth_hint
                + "; capture again"
            )
    outlier = _worst_rotation(lin, noise(lin), motions, full_turns, len(cols), significance)
    if outlier is not None:
        s_w, ratio, p_w = outlier
        m = motions[s_w]
        lost = " (samples are missing inside it)" if s_w in gaps else ""
        reasons.append(
            f"the rotation from pose {m.before + 1} to pose {m.after + 1} (at "
            f"{intervals[m.before].t0_s + intervals[m.before].duration_s:.1f} s){lost} misses "
            f"gravity {math.sqrt(ratio):.1f} times as far as the others do (F test, p {p_w:.1g} "
            "over all rotations): samples lost or a bump during it, or a pose that moved; "
            "capture that turn again, or cut it from the recording"
        )
    ok = not reasons
    if ok and not acceptance.strict and floor > 0:
        reasons.append(notes_floor)
    if ok and notes_means:
        reasons.append(notes_means)
    if gaps:
        reasons.append(
            f"samples are missing inside {len(gaps)} rotation(s) (the first after pose "
            f"{motions[gaps[0]].before + 1}): the integration holds the last rate over each gap"
        )
    it = lin.it
    motion_details = []
    for s, m in enumerate(motions):
        p = lin.poses[m.after].T @ lin.poses[m.before] @ u[m.before]
        turns = round(float(it.angle[s]) / (2 * math.pi)) if full_turns and m.returns else None
        motion_details.append(
            {
                "from_pose": m.before + 1,
                "to_pose": m.after + 1,
                "duration_s": float(durations[s]),
                "angle_deg": math.degrees(float(it.angle[s])),
                "residual_deg": math.degrees(float(np.linalg.norm(p - u[m.after]))),
                "turns": turns,
            }
        )
    details: dict[str, Any] = {
        "undetermined": weak,  # None, or which combination of C the rotations leave open
        "motions": motion_details,
        "residual_unit": "rad",
        "iterations": iterations,
        "accel_calibrated": accel is not None,
        "full_turns": full_turns,
        "partial_turns_about_vertical": partial,
        "earth_rate_rad_s": EARTH_RATE_RAD_S,
        "earth_over_turn_noise": earth_turn,
        "earth_over_pose_noise": earth_pose,
        "information_eigenvalues": np.linalg.eigvalsh(info).tolist(),
    }
    if earth is not None:
        psi = float(x[PSI])
        axis, heading = earth.heading(psi)
        e_body = earth.vector(psi)[0]
        fitted = PSI in cols
        details["earth"] = {
            "latitude_deg": latitude_deg,
            "heading_deg": heading if fitted else None,
            "heading_sigma_deg": (
                math.degrees(math.sqrt(max(float(cov_all[PSI, PSI]), 0.0))) if fitted else None
            ),
            "heading_of": f"body {axis} axis in the first still pose, degrees east of north",
            "rate_first_pose_rad_s": e_body.tolist(),
            "vertical_rad_s": earth.vertical,
            "horizontal_rad_s": earth.horizontal,
            "bias_from": "fitted with Earth's rotation" if free_bias else "given, held fixed",
            "pose_means_chi2": None if pose_part is None else pose_part[0],
            "pose_means_dof": None if pose_part is None else pose_part[1],
            # the heading's (rad) covariance with the written parameters, in Fit.names order
            "heading_cross_covariance": cov_all[PSI, :12].tolist(),
        }
    fit = Fit(
        (*C_NAMES, *BIAS_NAMES),
        np.concatenate([c.ravel(), b]),
        cov,
        {
            "rms": float(np.sqrt(np.mean(lin.r**2))),
            "chi2": chi2,
            "dof": float(dof),
            "p_value": p_value,
            "noise": math.sqrt(n2),
            "model_error": floor,  # rad, on each rotation's gravity direction
            "model_error_means": floor_m,  # rad/s, on each still pose's gyro mean (latitude)
        },
        details,
    )
    temps = [iv.temp_c for iv in intervals if iv.temp_c is not None]
    return AffineEstimate(
        sensor="gyro",
        procedure="gyro-full",
        bias=b,
        matrix=c,
        fit=fit,
        verdict=Verdict(ok, tuple(reasons)),
        temperature_c=float(np.mean(temps)) if temps else None,
        gravity=None if accel is None else accel.gravity,
    )
