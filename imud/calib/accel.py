"""Accelerometer calibration from still poses: corrected = C (raw - b).

Physics: at rest an accelerometer measures the reaction to gravity, a vector of known magnitude g
(local gravity, see imud/calib/gravity.py) pointing up. Each still pose gives one mean reading m_i
with a measured covariance; nothing else about the pose need be known.

Two models:

- "full" (default, procedure "accel-9"): C upper-triangular (6 entries) and b (3), found by
  minimising sum_i (||C (m_i - b)|| - g)^2 / sigma_i^2. Only the magnitude is used, so the pose
  directions are free and any still pose counts. A general C cannot be found from magnitudes
  (any rotation Q C fits equally), so the frame is tied to the chip: the corrected x axis is the
  chip's x axis and the corrected xy plane is the chip's xy plane, which is exactly what an
  upper-triangular C means. sigma_i^2 = u_i^T C S_i C^T u_i is the noise of pose i's mean (S_i,
  measured from its samples by block averaging) projected on its gravity direction u_i: only
  that component changes the norm. Gauss-Newton with Levenberg-Marquardt damping and an analytic
  Jacobian, started from the axis-aligned (diagonal C) ellipsoid solved linearly. Nine parameters
  need nine distinct gravity directions (closer than 10 degrees count as one); tilted poses
  (resting on an edge or a corner) fix the cross terms that faces alone leave free.
- "axes" (procedure "accel-axes", the Ferraris six-position assumption): each pose is taken to be
  exactly one of the six faces (the one the reading is nearest to) with gravity g e_k known, so
  m = A a + b is linear in a general A (9) and b (3): generalised least squares with each
  pose's full covariance, then C = A^-1. With one pose per face and equal noise this is exactly
  the Ferraris solution (b = mean of the six, A's columns = (up - down) / 2g); more poses per face
  only average. The frame is then the jig's, and any error in placing the poses goes straight into
  C: the chi-squared test below catches it when it exceeds the noise.

Uncertainty: covariance = (J^T W J)^-1 with W the measured inverse variances, not rescaled by
the reduced chi-squared: the chi-squared itself (dof = n - p) tests the noise model, and a
failure (p < 0.01) rejects the fit, naming the worst pose, rather than being absorbed into
wider error bars that would hide a moving pose or a temperature drift.

The seed's per-axis up/down formula (bias = (up + down)/2, scale = (up - down)/2g) is computed
whenever all six faces are present and returned beside every result for comparison.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import partial
from itertools import product
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from imud.calib.acceptance import MG, Acceptance, Tolerance, model_error_floor
from imud.calib.estimate import AffineEstimate, Fit, Verdict
from imud.calib.recording import Recording
from imud.calib.stats import chi2_sf
from imud.calib.still import (
    Activity,
    CalibrationRefused,
    StillInterval,
    find_still,
)

F64 = npt.NDArray[np.float64]
Model = Literal["full", "axes"]

DISTINCT_DEG = 10.0  # gravity directions closer than this are one orientation
FULL_PARAMS = 9
TEMP_LIMIT_C = 0.2  # a temperature change beyond this moves a MEMS bias by more than its noise
GRAVITY_RANGE = (9.7, 9.9)  # anywhere on Earth's surface or in its air
AXES = "xyz"
FACES = ("+x", "-x", "+y", "-y", "+z", "-z")
FULL_NAMES = ("C_xx", "C_xy", "C_xz", "C_yy", "C_yz", "C_zz", "b_x", "b_y", "b_z")
UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
AXES_NAMES = (*(f"C_{AXES[i]}{AXES[j]}" for i in range(3) for j in range(3)), "b_x", "b_y", "b_z")


@dataclass(frozen=True)
class SeedComparison:
    """The seed's per-axis six-position result: bias = (up + down) / 2, scale = (up - down) / 2g
    (raw = scale * a + bias per axis, so its matrix is diag(1 / scale))."""

    bias: F64
    scale: F64

    @property
    def matrix(self) -> F64:
        out: F64 = np.diag(1.0 / self.scale)
        return out


@dataclass(frozen=True)
class AccelResult:
    """The estimate, the still intervals it used, the seed's up/down comparison (None unless all
    six faces are present), and notes on poses dropped before the fit."""

    estimate: AffineEstimate
    intervals: list[StillInterval]
    seed: SeedComparison | None
    orientations: int
    dropped: list[str] = field(default_factory=list)

    @property
    def verdict(self) -> Verdict:
        return self.estimate.verdict


def _pose_name(k: int, iv: StillInterval) -> str:
    return f"pose {k + 1} ({iv.t0_s:.1f}-{iv.t0_s + iv.duration_s:.1f} s)"


def orientation_labels(means: F64, max_deg: float = DISTINCT_DEG) -> tuple[list[int], F64]:
    """Cluster gravity directions: a pose joins the first cluster whose founding direction is
    within max_deg. Returns each pose's cluster and the cluster directions (unit rows)."""
    u = means / np.linalg.norm(means, axis=1, keepdims=True)
    cos_lim = math.cos(math.radians(max_deg))
    reps: list[F64] = []
    labels = []
    for v in u:
        for k, r in enumerate(reps):
            if float(v @ r) > cos_lim:
                labels.append(k)
                break
        else:
            labels.append(len(reps))
            reps.append(v)
    return labels, np.array(reps).reshape(-1, 3)


def _direction_name(d: F64) -> str:
    return "".join(f"{'+' if c > 0 else '-'}{AXES[i]}" for i, c in enumerate(d) if c != 0) + " up"


def suggest_poses(directions: F64, count: int) -> list[str]:
    """Up to `count` poses (faces, edges, corners) farthest from the directions already held."""
    cands = [np.array(c, dtype=float) for c in product((-1, 0, 1), repeat=3) if any(c)]
    have = [d / np.linalg.norm(d) for d in directions]
    out = []
    for _ in range(count):
        best, best_cos = None, 2.0
        for c in cands:
            cu = c / np.linalg.norm(c)
            closest = max((float(cu @ h) for h in have), default=-1.0)
            if closest < best_cos:
                best, best_cos = c, closest
        if best is None:
            break
        have.append(best / np.linalg.norm(best))
        kind = {1: "a face", 2: "an edge", 3: "a corner"}[int(np.count_nonzero(best))]
        out.append(f"{_direction_name(best)} (on {kind})")
    return out


def face_of(mean: F64) -> int:
    """Index into FACES of the face nearest to a reading (the axis reading most of g)."""
    k = int(np.argmax(np.abs(mean)))
    return 2 * k + (0 if mean[k] > 0 else 1)


def seed_comparison(intervals: list[StillInterval], gravity: float) -> SeedComparison | None:
    """The seed's formula from the poses within DISTINCT_DEG of a face (the only ones it is
    meant for); None unless all six faces are held."""
    cos_lim = math.cos(math.radians(DISTINCT_DEG))
    means = np.array([iv.accel for iv in intervals])
    unit = np.abs(means) / np.linalg.norm(means, axis=1, keepdims=True)
    near = np.max(unit, axis=1) > cos_lim
    faces = [face_of(m) if ok else -1 for m, ok in zip(means, near, strict=True)]
    if len(set(faces) - {-1}) < 6:
        return None
    per_face = np.array([means[[f == k for f in faces]].mean(axis=0) for k in range(6)])
    up = np.array([per_face[2 * k, k] for k in range(3)])
    down = np.array([per_face[2 * k + 1, k] for k in range(3)])
    return SeedComparison(bias=(up + down) / 2.0, scale=(up - down) / (2.0 * gravity))


def _check_gravity(gravity: float) -> None:
    lo, hi = GRAVITY_RANGE
    if not (math.isfinite(gravity) and lo <= gravity <= hi):
        raise ValueError(
            f"gravity {gravity!r} m/s^2 is outside {lo}..{hi}: give local gravity in m/s^2 "
            "(or latitude and height to compute it)"
        )


def fit_accel(
    rec: Recording,
    gravity: float,
    model: Model = "full",
    intervals: list[StillInterval] | None = None,
    min_s: float = 2.0,
    significance: float = 0.01,
    acceptance: Acceptance | None = None,
) -> AccelResult:
    """Calibrate the accelerometer from the still poses of a recording (see module docstring).

    intervals: None finds them (imud/calib/still.py); given ones are re-checked for motion
    against the recording's own noise floor and any that moved are dropped and named, as are
    poses whose samples hit full scale. Raises CalibrationRefused when no estimate can be formed
    (no still data, too few orientations, missing faces for "axes"); otherwise the verdict says
    whether the estimate may be used."""
    _check_gravity(gravity)
    act = Activity.of(rec)
    dropped: list[str] = []
    if intervals is None:
        intervals = find_still(rec, min_s=min_s, activity=act)
    else:
        kept = []
        for k, iv in enumerate(intervals):
            moved = act.moving_windows(iv.start, iv.end)
            if moved:
                a, b = moved[0]
                t0 = float(rec.t_ns[a] - rec.t_ns[0]) * 1e-9
                t1 = float(rec.t_ns[min(b, rec.n) - 1] - rec.t_ns[0]) * 1e-9
                dropped.append(
                    f"{_pose_name(k, iv)} was dropped: the sensor moved during it at "
                    f"{t0:.1f}-{t1:.1f} s; hold each pose still, or capture it again"
                )
            else:
                kept.append(iv)
        intervals = kept
    if not intervals and not dropped:
        still_s = float(np.sum(act.still)) / rec.rate_hz
        raise CalibrationRefused(
            f"no still interval of at least {min_s:g} s in {rec.source or 'the recording'} "
            f"(still {still_s:.1f} s of {rec.n / rec.rate_hz:.1f} s in total): the sensor moved "
            "throughout; hold each pose still for a few seconds"
        )
    return fit_accel_intervals(intervals, gravity, model, dropped, significance, acceptance)


def fit_accel_intervals(
    intervals: list[StillInterval],
    gravity: float,
    model: Model = "full",
    dropped: list[str] | None = None,
    significance: float = 0.01,
    acceptance: Acceptance | None = None,
) -> AccelResult:
    """The fit itself, from pose means alone (fit_accel adds detection and motion checks).
    `acceptance` None: the model-error floor against the default tolerance, `significance`
    for the strict test's threshold."""
    acceptance = acceptance or Acceptance(significance=significance)
    _check_gravity(gravity)
    notes = list(dropped or [])
    used = []
    for k, iv in enumerate(intervals):
        if iv.saturated:
            notes.append(
                f"{_pose_name(k, iv)} was dropped: its samples hit full scale; use a wider range "
                "or capture that pose again"
            )
        else:
            used.append(iv)
    if not used:
        raise CalibrationRefused(
            "no usable still pose: " + "; ".join(notes) if notes else "no still poses were given"
        )
    means = np.array([iv.accel for iv in used])
    labels, dirs = orientation_labels(means)
    n_orient = dirs.shape[0]
    seed = seed_comparison(used, gravity)
    if model == "full":
        if len(used) < FULL_PARAMS:
            need = FULL_PARAMS - n_orient  # repeats of an orientation add little
            tips = suggest_poses(dirs, max(need, 3))
            extra = f" ({'; '.join(notes)})" if notes else ""
            raise CalibrationRefused(
                f"found {n_orient} distinct orientations in {len(used)} still intervals{extra}; "
                f"the 9-parameter fit needs {FULL_PARAMS}: add {need} more, tilted ones help most "
                f"(e.g. {', '.join(tips)})"
            )
        est, poses = _fit_full(used, gravity, acceptance.significance)
        # every pose counts: what they determine is read from the fit's own uncertainty, not
        # from a count of well-separated orientations (hand-held sessions hold many poses a
        # few degrees apart)
        weak = _weak_parameters(est)
        if weak:
            raise CalibrationRefused(
                f"{len(used)} still poses in {n_orient} distinct orientations leave "
                f"{', '.join(weak)} undetermined: add poses, tilted ones help most "
                f"(e.g. {', '.join(suggest_poses(dirs, 3))})"
            )
    elif model == "axes":
        faces = {face_of(m) for m in means}
        missing = [FACES[k] for k in range(6) if k not in faces]
        if missing:
            raise CalibrationRefused(
                f"the six-position model needs every face up once; missing: "
                f"{', '.join(f + ' up' for f in missing)}; capture those poses, or use the default "
                "model, which takes any orientations"
            )
        est, poses = _fit_axes(used, gravity, acceptance.significance)
    else:
        raise ValueError(f"unknown accel model {model!r}: use 'full' or 'axes'")
    for p, lab in zip(poses, labels, strict=True):
        p["orientation"] = lab
    reasons, ok = _verdict(used, poses, est, model, acceptance)
    details: dict[str, Any] = {
        **est.details,
        "poses": poses,
        "orientations": n_orient,
        "dropped": notes,
        "seed": None
        if seed is None
        else {"bias": seed.bias.tolist(), "scale": seed.scale.tolist()},
    }
    fit = Fit(est.names, est.values, est.covariance, est.residuals, details)
    temps = [iv.temp_c for iv in used if iv.temp_c is not None]
    estimate = AffineEstimate(
        sensor="accel",
        procedure="accel-9" if model == "full" else "accel-axes",
        bias=est.bias,
        matrix=est.matrix,
        fit=fit,
        verdict=Verdict(ok, tuple(notes + reasons)),  # dropped poses: warnings, fit went on
        temperature_c=float(np.mean(temps)) if temps else None,
        gravity=gravity,
    )
    return AccelResult(estimate, used, seed, n_orient, notes)


@dataclass(frozen=True)
class _Solved:
    names: tuple[str, ...]
    values: F64
    covariance: F64
    matrix: F64
    bias: F64
    residuals: dict[str, float]
    details: dict[str, Any]


def _full_unpack(p: F64) -> tuple[F64, F64]:
    c = np.zeros((3, 3))
    for k, (i, j) in enumerate(UPPER):
        c[i, j] = p[k]
    return c, p[6:9].copy()


def _full_model(
    p: F64, means: F64, covs: F64, g: float, floor2: float = 0.0
) -> tuple[F64, F64, F64]:
    """Residuals ||C(m - b)|| - g, their Jacobian (n, 9), and their sigmas (the poses' noise
    and a model-error variance `floor2`)."""
    c, b = _full_unpack(p)
    d = means - b
    v = d @ c.T
    nv = np.linalg.norm(v, axis=1)
    u = v / nv[:, None]
    r = nv - g
    jac = np.empty((means.shape[0], 9))
    for k, (i, j) in enumerate(UPPER):
        jac[:, k] = u[:, i] * d[:, j]
    uc = u @ c  # u^T C per pose
    jac[:, 6:9] = -uc
    sig = np.sqrt(np.einsum("ni,nij,nj->n", uc, covs, uc) + floor2)
    return r, jac, sig


def _norm_chi2(r2: F64, var: F64, s2: float) -> float:
    """The residuals' chi-squared with a model-error variance s2 added to each pose's."""
    return float(np.sum(r2 / (var + s2)))


def _diagonal_start(means: F64, g: float) -> F64:
    """Axis-aligned ellipsoid sum_k s_k^2 (m_k - b_k)^2 = g^2, linear in
    (s^2, -2 s^2 b, const): the six-position/diagonal solution as a starting point."""
    # sum alpha m^2 + beta . m + kappa = 0 (homogeneous: the null vector of the design), with
    # beta = -2 alpha b and kappa = sum alpha b^2 - g^2 fixing the scale afterwards
    x = np.column_stack([means**2, means, np.ones(means.shape[0])])
    sol = np.linalg.svd(x)[2][-1]
    alpha, beta, kappa = sol[:3], sol[3:6], sol[6]
    if np.all(alpha > 0) or np.all(alpha < 0):
        b = -beta / (2.0 * alpha)
        lam = g * g / (float(np.sum(alpha * b * b)) - kappa)
        s = np.sqrt(np.abs(lam * alpha))
    else:  # degenerate geometry: start from identity scaled to g
        b = np.zeros(3)
        s = np.full(3, g / float(np.median(np.linalg.norm(means, axis=1))))
    return np.array([s[0], 0.0, 0.0, s[1], 0.0, s[2], *b])


def _gauss_newton(
    p: F64, means: F64, covs: F64, g: float, max_iter: int = 100, floor2: float = 0.0
) -> tuple[F64, int]:
    """Levenberg-Marquardt on the 9 parameters; weights re-evaluated at each accepted step."""
    lam = 1e-3
    for it in range(max_iter):
        r, jac, sig = _full_model(p, means, covs, g, floor2)
        w = 1.0 / sig**2
        cost = float(np.sum(w * r * r))
        a = jac.T @ (jac * w[:, None])
        grad = jac.T @ (w * r)
        while True:
            step = np.linalg.solve(a + lam * np.diag(np.diag(a)), -grad)
            trial = p + step
            r2, _, _ = _full_model(trial, means, covs, g, floor2)
            cost2 = float(np.sum(w * r2 * r2))
            if cost2 <= cost or lam > 1e12:
                break
            lam *= 10.0
        p = trial
        lam = max(lam / 10.0, 1e-12)
        # converged when the step is negligible against the parameters' own uncertainty
        sig_p = np.sqrt(np.abs(np.diag(np.linalg.pinv(a))))
        if np.all(np.abs(step) <= 1e-8 * np.maximum(sig_p, 1e-300)) or cost - cost2 < 1e-12 * (
            1.0 + cost
        ):
            return p, it + 1
    return p, max_iter


def _fit_full(
    used: list[StillInterval], g: float, significance: float
) -> tuple[_Solved, list[dict[str, Any]]]:
    means = np.array([iv.accel for iv in used])
    covs = np.array([iv.accel_cov for iv in used])
    p, iters = _gauss_newton(_diagonal_start(means, g), means, covs, g)
    r, jac, sig = _full_model(p, means, covs, g)
    info = jac.T @ (jac / sig[:, None] ** 2)
    ev, vec = np.linalg.eigh(info)
    if ev[0] <= 1e-12 * ev[-1]:
        # the parameters the data cannot tell apart: the weakest direction's main components
        weakest = np.abs(vec[:, 0])
        names = [FULL_NAMES[k] for k in np.argsort(weakest)[::-1] if weakest[k] > 0.3]
        raise CalibrationRefused(
            f"the poses do not pin down all nine parameters ({', '.join(names)} undetermined: "
            "their gravity directions lie on a plane or a cone): add poses resting on edges "
            "and corners, e.g. " + ", ".join(suggest_poses(orientation_labels(means)[1], 3))
        )
    dof = len(used) - FULL_PARAMS
    floor = 0.0
    for _ in range(20):
        # a model error weighs every pose alike: the fit is redone with it in the weights (a
        # random-effects estimate), so poses whose noise is tiny do not outweigh the others
        r2, v = r * r, sig * sig
        new = model_error_floor(
            partial(_norm_chi2, r2, v), dof, float(np.sqrt(np.mean(r2))), significance
        )
        if abs(new - floor) <= 1e-3 * max(new, 1e-300):
            break
        floor = new
        p, iters = _gauss_newton(p, means, covs, g, floor2=floor * floor)
        r, jac, sig = _full_model(p, means, covs, g)
    chi2 = float(np.sum((r / sig) ** 2))
    rms = float(np.sqrt(np.mean(r * r)))
    # the parameters' covariance with the model error counted as noise of every pose
    var = sig * sig + floor * floor
    cov = np.linalg.inv(jac.T @ (jac / var[:, None]))
    cov = 0.5 * (cov + cov.T)
    c, b = _full_unpack(p)
    residuals = {
        "rms": rms,
        "chi2": chi2,
        "dof": float(dof),
        "p_value": chi2_sf(chi2, dof) if dof > 0 else 1.0,
        "noise": float(np.sqrt(np.mean(sig * sig))),
        "model_error": floor,
    }
    poses = [
        {
            "mean": iv.accel.tolist(),
            "residual": float(r[k]),
            "sigma": float(sig[k]),
            "duration_s": iv.duration_s,
            "t0_s": iv.t0_s,
            "face": FACES[face_of(iv.accel)],
        }
        for k, iv in enumerate(used)
    ]
    details = {"model": "full", "iterations": iters}
    return _Solved(FULL_NAMES, p, cov, c, b, residuals, details), poses


def _fit_axes(
    used: list[StillInterval], g: float, significance: float
) -> tuple[_Solved, list[dict[str, Any]]]:
    means = np.array([iv.accel for iv in used])
    covs = np.array([iv.accel_cov for iv in used])
    n = len(used)
    grav = np.zeros((n, 3))
    for k, m in enumerate(means):
        f = face_of(m)
        grav[k, f // 2] = g if f % 2 == 0 else -g
    # m_i = A a_i + b, theta = [A row-major (9), b (3)]; X_i is (3, 12)
    x = np.zeros((n, 3, 12))
    for j in range(3):
        x[:, j, 3 * j : 3 * j + 3] = grav
        x[:, j, 9 + j] = 1.0
    winv = np.linalg.inv(covs)
    dof = 3 * n - 12

    def solve(w: F64) -> tuple[F64, F64]:
        """theta by weighted least squares with weights w (n, 3, 3), and the misfits."""
        normal = np.einsum("nji,njk,nkl->il", x, w, x)
        rhs = np.einsum("nji,njk,nk->i", x, w, means)
        th: F64 = np.linalg.solve(normal, rhs)
        return th, means - np.einsum("nij,j->ni", x, th)

    theta, e = solve(winv)
    floor = 0.0
    for _ in range(20):
        # as the 9-parameter fit: the model error (poses off their faces) in every pose's
        # weight, and the fit redone with it
        def chi2_at(s2: float, e: F64 = e) -> float:
            w = np.linalg.inv(covs + s2 * np.eye(3))
            return float(np.einsum("ni,nij,nj->", e, w, e))

        new = model_error_floor(chi2_at, dof, float(np.sqrt(np.mean(e * e))), significance)
        if abs(new - floor) <= 1e-3 * max(new, 1e-300):
            break
        floor = new
        theta, e = solve(np.asarray(np.linalg.inv(covs + floor * floor * np.eye(3)), np.float64))
    a = theta[:9].reshape(3, 3)
    b = theta[9:]
    chi2 = float(np.einsum("ni,nij,nj->", e, winv, e))
    # the parameters' covariance with the model error counted in
    winf = np.linalg.inv(covs + floor * floor * np.eye(3))
    cov_theta = np.linalg.inv(np.einsum("nji,njk,nkl->il", x, winf, x))
    c: F64 = np.asarray(np.linalg.inv(a), dtype=np.float64)
    # d vec(C) = -(C kron C^T) d vec(A) for row-major vec
    jac = np.zeros((12, 12))
    kron = np.asarray(np.kron(c, c.T), dtype=np.float64)
    jac[:9, :9] = -kron
    jac[9:, 9:] = np.eye(3)
    cov = jac @ cov_theta @ jac.T
    cov = 0.5 * (cov + cov.T)
    corrected = (means - b) @ c.T
    nc = np.linalg.norm(corrected, axis=1)
    u = corrected / nc[:, None]
    uc = u @ c
    sig = np.sqrt(np.einsum("ni,nij,nj->n", uc, covs, uc))
    tilt = np.degrees(np.arccos(np.clip(np.sum(u * grav / g, axis=1), -1.0, 1.0)))
    residuals = {
        "rms": float(np.sqrt(np.mean(e * e))),
        "chi2": chi2,
        "dof": float(dof),
        "p_value": chi2_sf(chi2, dof) if dof > 0 else 1.0,
        "noise": float(np.sqrt(np.mean(np.einsum("nii->ni", covs)))),
        "model_error": floor,
    }
    poses = [
        {
            "mean": iv.accel.tolist(),
            "residual": float(nc[k] - g),
            "sigma": float(sig[k]),
            "duration_s": iv.duration_s,
            "t0_s": iv.t0_s,
            "face": FACES[face_of(iv.accel)],
            "misfit": e[k].tolist(),
            "off_face_deg": float(tilt[k]),
        }
        for k, iv in enumerate(used)
    ]
    values = np.concatenate([c.ravel(), b])
    details = {"model": "axes"}
    return _Solved(AXES_NAMES, values, cov, c, b, residuals, details), poses


def _verdict(
    used: list[StillInterval],
    poses: list[dict[str, Any]],
    est: _Solved,
    model: Model,
    acceptance: Acceptance,
) -> tuple[list[str], bool]:
    """Strict: the chi-squared test at `acceptance.significance` (the chance of refusing a right
    model with right noise). Else the model-error floor against the tolerance, and the
    calibration must improve the poses' |a| - g over the raw readings (imud/calib/acceptance.py)."""
    reasons: list[str] = []
    ok = True
    res = est.residuals
    floor = res["model_error"]
    kind = Tolerance.ACCEL_FULL if model == "full" else Tolerance.ACCEL_AXES
    tolerance = acceptance.tolerance_for(kind)
    if res["dof"] <= 0:
        # an exact fit passes any data through, a pose that moved included, and its sigmas
        # may be huge (nine poses near a cone): nothing says it is right
        ok = False
        reasons.append(
            f"{len(used)} poses for {len(est.names)} parameters: the fit is exact and its "
            "residuals cannot be tested; add at least one more pose (three or more make the "
            "test worth having)"
        )
    elif acceptance.strict and res["p_value"] < acceptance.significance:
        ok = False
        reasons.append(
            f"the residuals are {math.sqrt(res['chi2'] / res['dof']):.1f} times the poses' "
            f"noise (chi2 {res['chi2']:.1f}, dof {res['dof']:.0f}, p {res['p_value']:.2g}), "
            f"--strict: {_worst(used, poses, model)}"
        )
    elif not acceptance.strict and floor > tolerance:
        ok = False
        reasons.append(
            f"the residuals hold a model error of {floor / MG:.2f} mg beyond the poses' noise "
            f"({res['noise'] / MG:.3f} mg), more than the tolerance of {tolerance / MG:g} mg "
            f"({acceptance.source(kind)}): {_worst(used, poses, model)}"
        )
    elif not acceptance.strict and floor > 0:
        reasons.append(
            f"model error {floor / MG:.2f} mg beyond the poses' noise ({res['noise'] / MG:.3f} "
            f"mg), within the tolerance of {tolerance / MG:g} mg ({acceptance.source(kind)}); "
            "the parameters' uncertainty includes it"
        )
    if ok and not acceptance.strict and res["dof"] > 0:
        raw, fixed = _norm_errors(poses, est)
        if fixed >= raw:
            ok = False
            reasons.append(
                f"the calibration does not improve the still poses' |a| - g (raw "
                f"{raw / MG:.2f} mg RMS, calibrated {fixed / MG:.2f} mg): the poses do not "
                "determine it; capture more orientations"
            )
    warm = [
        f"{_pose_name(k, iv)} {iv.temp_change_c:+.2f} degC"
        for k, iv in enumerate(used)
        if iv.temp_change_c is not None and abs(iv.temp_change_c) > TEMP_LIMIT_C
    ]
    if warm:
        reasons.append(
            f"the temperature changed by more than {TEMP_LIMIT_C} degC within "
            f"{', '.join(warm)}: the bias moves with it; let the sensor warm up first"
        )
    temps = [iv.temp_c for iv in used if iv.temp_c is not None]
    if temps and max(temps) - min(temps) > TEMP_LIMIT_C:
        ok = False
        reasons.append(
            f"the temperature changed by {max(temps) - min(temps):.2f} degC across the capture "
            f"({min(temps):.2f} to {max(temps):.2f} degC), more than {TEMP_LIMIT_C} degC: the "
            "bias moved between poses; let the sensor reach a steady temperature and capture "
            "again, or calibrate temperature first"
        )
    return reasons, ok


# a parameter whose sigma exceeds these is not determined by the poses: a scale or misalignment
# term known to worse than 1 % (an uncalibrated MEMS part's own error), a bias to worse than
# 50 mg (beyond any MEMS part's zero-g offset)
WEAK_MATRIX_SIGMA = 0.01
WEAK_BIAS_SIGMA = 50 * MG


def _weak_parameters(est: _Solved) -> list[str]:
    """Each parameter the fit leaves undetermined, named with its sigma."""
    sig = np.sqrt(np.clip(np.diag(est.covariance), 0.0, None))
    out = []
    for name, s in zip(est.names, sig, strict=True):
        limit = WEAK_BIAS_SIGMA if name.startswith("b_") else WEAK_MATRIX_SIGMA
        if not s <= limit:
            unit = f"{s / MG:.3g} mg" if name.startswith("b_") else f"{s:.2g}"
            out.append(f"{name} (sigma {unit})")
    return out


def _worst(used: list[StillInterval], poses: list[dict[str, Any]], model: Model) -> str:
    """The pose that fits worst, and what usually makes it so."""
    if model == "axes":
        worst = max(range(len(poses)), key=lambda k: poses[k]["off_face_deg"])
        return (
            f"the poses are not the six faces (worst: {_pose_name(worst, used[worst])}, "
            f"{poses[worst]['off_face_deg']:.2f} deg off its face); use the default model, "
            "which does not assume aligned poses"
        )
    z = [abs(p["residual"]) / p["sigma"] for p in poses]
    worst = int(np.argmax(z))
    return (
        f"worst {_pose_name(worst, used[worst])}: {poses[worst]['residual']:.2e} m/s^2, "
        f"{z[worst]:.1f} sigma: a pose moved, the temperature drifted, the gravity value is "
        "wrong or the sensor is not linear; capture again"
    )


def _norm_errors(poses: list[dict[str, Any]], est: _Solved) -> tuple[float, float]:
    """RMS over the poses of |a| - g, raw and calibrated (g: the fit's own, from its poses)."""
    means = np.array([p["mean"] for p in poses])
    fixed = np.linalg.norm((means - est.bias) @ est.matrix.T, axis=1)
    g = float(np.median(fixed))
    raw = np.linalg.norm(means, axis=1)
    return float(np.sqrt(np.mean((raw - g) ** 2))), float(np.sqrt(np.mean((fixed - g) ** 2)))
