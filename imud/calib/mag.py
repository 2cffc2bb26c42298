"""Magnetometer calibration: hard iron and symmetric soft iron from a recording rotated through
many directions.

Model. The raw reading is m = S b + h + n: the local field b (constant magnitude, only its
direction in the body changes as the device turns) distorted by soft iron S and offset by hard
iron h, plus noise n. The readings therefore lie on an ellipsoid. The correction
corrected = matrix @ (m - bias) maps it back to a sphere of radius `field_t`. Only the ellipsoid
is observable, so any rotation Q of a valid correction is valid too (Q S^-1 for every
orthogonal Q). The fit reports the unique symmetric positive-definite matrix among them, the
polar factor P of S^-1 = U P. It adds no rotation, so the corrected frame stays the sensor's
own; aligning the sensor to the body is a separate question.

Method.
1. Li & Griffiths' ellipsoid-specific algebraic fit (closed form) gives the start. With the
   constraint 4J - I^2 = 1 it is guaranteed to return the ellipsoid while the shortest
   semi-axis is at least half the longest, far beyond real soft iron. If it returns none,
   the start is the min/max estimate.
2. Levenberg-Marquardt refines it on the geometric residual r_i = ||A (m_i - b)|| - 1, with
   A symmetric (6 parameters) and b (3). This is ||A' (m_i - b)|| - R with A' = R A: the
   10-parameter form has one redundant direction, since (A', R) and (k A', k R) describe the
   same surface, so A is fitted against R = 1. Each residual is weighted by its own predicted
   noise.
   This is maximum likelihood for Gaussian noise whose per-axis sizes are measured from the
   data. The sphere's radius is the gauge:
   - When the local field magnitude is known (`field_t`, e.g. from a world magnetic model),
     matrix = field_t * A. That is 9 free parameters, and the field is fixed, not fitted.
   - Otherwise the data hold no absolute scale: `matrix * k` with `field * k` fits equally
     well. The fit then fixes det(matrix) = 1, so the correction preserves volume, and
     reports field = det(A)^(-1/3), the geometric mean of the ellipsoid's semi-axes in tesla.
3. Covariance is (J^T W J)^-1 with W = 1/s_i^2, and s_i the predicted noise of residual i.
4. Acceptance is a chi-squared test of the residuals against that same measured noise.

Why the noise is measured separately from the residual: the residual is whatever the model
fails to explain. Noise is part of it, but so is every model error (a magnet that moved, a
motor current, a nonlinearity). "Noise" estimated from the residual is therefore model error
plus noise by construction. The chi-squared test against it would always give chi2/dof = 1 and
could never fail, and the covariance would silently absorb the misfit. Differences between
consecutive samples see the sensor's noise and never see the model, so they are an
independent yardstick. It also measures noise per axis, where the residual sees only the radial
component.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from imud.calib.acceptance import Acceptance, Tolerance, model_error_floor
from imud.calib.estimate import F64, AffineEstimate, Fit, Verdict
from imud.calib.recording import Recording
from imud.calib.stats import chi2_sf, t_sf_two_sided
from imud.calib.still import CalibrationRefused

P_REJECT = 0.01
MIN_SAMPLES = 200
"""At least ~3 readings per direction cell on average. The noise estimate then has ~90 degrees
of freedom (about 8 % in sigma), and the 9 parameters are overdetermined twenty times over."""

MIN_SHOTS = 18
"""A shot list (one reading a pose): twice the 9 parameters, so the residuals that give its
noise have as many degrees of freedom as the fit has parameters."""

WEAK_MATRIX_SIGMA = 0.03
"""A soft-iron element the readings leave this uncertain (1 sigma; the matrix is near the
identity) is named undetermined; a bias is, beyond the tolerance (a fraction of the field,
Tolerance.MAG)."""

MAX_AXIS_RATIO = 3.0
"""Largest ratio of the correction's longest to shortest axis. Real soft iron distorts by tens
of percent. A larger ratio means the fit has bent an ellipsoid around a cloud that fills no
ellipsoid (rotation in one plane, or an arc of directions). The algebraic start is
guaranteed only up to 2."""

COVERAGE_CELLS = 60
COVERAGE_REQUIRED = 0.75
"""Fraction of the 60 direction cells that must hold a reading. Any hemisphere holds half the
cells. With three quarters covered, at most a quarter of all cells is missing, so every
hemisphere is still at least half covered. Each axis's extreme is then seen from both
sides, and the soft-iron terms cannot trade against the hard iron along an unseen direction.
Below that the fit extrapolates a cap. Its covariance shows that only for the model: a field
that is not affine (a nearby magnet) goes unseen there."""

NAME_CAP_DEG = 35.0
NAME_EMPTY_SHARE = 2.0 / 3.0
_AXIS_WORDS = {
    "+x": "+x (front face pointing along the field)",
    "-x": "-x (back face pointing along the field)",
    "+y": "+y (left side pointing along the field)",
    "-y": "-y (right side pointing along the field)",
    "+z": "+z (top face pointing along the field)",
    "-z": "-z (bottom face pointing along the field)",
}
_SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))  # order of the 6 matrix parameters
SCALE_FIXED = "field fixed to field_t: matrix = field_t * A"
SCALE_FREE = "det(matrix) = 1: field = geometric mean of the ellipsoid's semi-axes"
MINMAX_METHOD = "per-axis mid-range and half-range (the seed's); no covariance"
NAMES = ("bias_x", "bias_y", "bias_z", "m_xx", "m_yy", "m_zz", "m_xy", "m_xz", "m_yz", "field")


@dataclass(frozen=True)
class Coverage:
    """Which directions of the corrected field the recording visited: cells of a Fibonacci
    sphere (equal areas), a cell counting once it holds a reading."""

    cells: int
    visited: int
    required: float
    missing: tuple[str, ...]  # in words, e.g. "-z (bottom face pointing along the field)"

    @property
    def fraction(self) -> float:
        return self.visited / self.cells

    @property
    def ok(self) -> bool:
        return self.fraction >= self.required


@dataclass(frozen=True)
class MagResult:
    """The ellipsoid fit, the seed's per-axis min/max on the same data (for comparison only),
    and the coverage report."""

    estimate: AffineEstimate
    minmax: AffineEstimate
    coverage: Coverage


# --- noise ----------------------------------------------------------------------------------

_D3_SUMSQ = 20.0  # third difference (1, -3, 3, -1): sum of squared coefficients
_D3_DOF_DIVISOR = 2.31  # 1 + 2 * sum of its squared autocorrelations (-15, 6, -1)/20


def difference_noise(x: F64, t_ns: npt.NDArray[np.int64] | None = None) -> tuple[F64, F64]:
    """Per-axis white-noise sigma of consecutive samples x (N, k), and the degrees of freedom
    of each sigma^2 (windows used / 2.31, since overlapping differences are correlated).

    Uses third differences. Rotation moves the field by about |B| w/f per sample (0.5 uT at
    1 rad/s and 100 Hz), and first differences would count that as noise. Each further
    difference multiplies the smooth part by another w/f. Third differences leave |B| (w/f)^3,
    which covers the chord curvature of a steady turn that second differences still keep.
    Windows that straddle a gap in time (more than 1.5 median periods) are left out. Spikes
    from a jerk are clipped at 5 robust sigmas, which drops a negligible 6e-7 of Gaussian
    mass.
    """
    d = np.diff(x, n=3, axis=0)
    ok = np.ones(d.shape[0], dtype=bool)
    if t_ns is not None and t_ns.shape[0] == x.shape[0] and d.shape[0] > 0:
        step = np.diff(t_ns)
        regular = step <= 1.5 * float(np.median(step))
        ok = regular[:-2] & regular[1:-1] & regular[2:]
    d = d[ok]
    scale = 1.4826 * np.median(np.abs(d), axis=0)
    keep = np.where(scale > 0, np.abs(d) <= 5.0 * scale, True)
    count = np.maximum(keep.sum(axis=0), 1)
    var = np.where(keep, d * d, 0.0).sum(axis=0) / count / _D3_SUMSQ
    sigma: F64 = np.sqrt(var)
    dof: F64 = count / _D3_DOF_DIVISOR
    return sigma, dof


def chi2_scale(dof: float, shares: F64, noise_dof: F64) -> float:
    """Satterthwaite's c for a chi2 whose noise was estimated, not known: chi2/c is close to
    chi-squared with dof/c degrees of freedom.

    chi2 = sum_i r_i^2 / s_i^2, with s_i^2 built from per-axis sigma_k^2 estimated on noise_dof[k]
    degrees of freedom. shares[k] = sum_i (axis k's part of s_i^2) / s_i^2. An error in sigma_k^2
    then moves chi2 by shares[k] times that relative error, which adds shares[k]^2 * 2/nu_k
    to the variance. Both the residuals and the third differences come from the same samples,
    so they are correlated (white noise: cov = 2 shares[k] / m_k, with m_k = 2.31 nu_k windows),
    which takes back 4 shares[k]^2 / m_k. Without the correction, a short recording's noise
    estimate would make false rejections far more common than the nominal 1 %. Treating the
    two as independent instead would make the test needlessly blunt."""
    per = (2.0 - 4.0 / _D3_DOF_DIVISOR) / np.maximum(noise_dof, 1.0)
    extra = float(np.sum(shares * shares * per))
    return 1.0 + max(extra, 0.0) / (2.0 * dof)


def p_value(chi2: float, dof: float, c: float = 1.0) -> float:
    """Upper-tail p of chi2 on dof degrees of freedom, widened by Satterthwaite's c."""
    return chi2_sf(chi2 / c, dof / c)


# --- algebra --------------------------------------------------------------------------------


def _sym(a6: F64) -> F64:
    m = np.empty((3, 3))
    for k, (i, j) in enumerate(_SYM):
        m[i, j] = m[j, i] = a6[k]
    return m


def _sym6(m: F64) -> F64:
    return np.array([m[i, j] for i, j in _SYM])


def _sqrtm_spd(q: F64) -> F64 | None:
    w, v = np.linalg.eigh(q)
    if not np.all(w > 0):
        return None
    out: F64 = (v * np.sqrt(w)) @ v.T
    return out


def li_griffiths(x: F64) -> tuple[F64, F64] | None:
    """Ellipsoid-specific algebraic fit (Li & Griffiths 2004): centre b and symmetric A with
    ||A (x - b)|| = 1 on the ellipsoid, or None when the data give no ellipsoid.

    The conic a x^2 + b y^2 + c z^2 + 2f yz + 2g xz + 2h xy + 2p x + 2q y + 2r z + d = 0
    minimises its algebraic distance under 4J - I^2 = 1, where I = a+b+c and
    J = ab+bc+ca-f^2-g^2-h^2. The linear part is eliminated (Schur complement), which leaves
    M v1 = lambda C1 v1. Its solution is the eigenvector of C1^-1 M with a positive eigenvalue
    (ordinary eigenproblem, C1 is invertible)."""
    X, Y, Z = x[:, 0], x[:, 1], x[:, 2]
    one = np.ones_like(X)
    d = np.stack([X * X, Y * Y, Z * Z, 2 * Y * Z, 2 * X * Z, 2 * X * Y, 2 * X, 2 * Y, 2 * Z, one])
    s = d @ d.T
    s11, s12, s22 = s[:6, :6], s[:6, 6:], s[6:, 6:]
    c1 = np.zeros((6, 6))
    c1[:3, :3] = 1.0  # k/2 - 1 = 1 off the diagonal for k = 4
    np.fill_diagonal(c1[:3, :3], -1.0)
    c1[3:, 3:] = -4.0 * np.eye(3)
    try:
        s22_s21 = np.linalg.solve(s22, s12.T)
        w, v = np.linalg.eig(np.linalg.solve(c1, s11 - s12 @ s22_s21))
    except np.linalg.LinAlgError:
        return None
    w, v = w.real, v.real
    good = [k for k in range(6) if w[k] > 0 and v[:, k] @ c1 @ v[:, k] > 0]
    if not good:
        return None
    v1 = v[:, max(good, key=lambda k: w[k])]
    v2 = -s22_s21 @ v1
    a, b, c, f, g, h = v1
    q = np.array([[a, h, g], [h, b, f], [g, f, c]])
    try:
        centre = -np.linalg.solve(q, v2[:3])
    except np.linalg.LinAlgError:
        return None
    level = centre @ q @ centre - v2[3]
    root = _sqrtm_spd(q / level) if level != 0 else None
    return None if root is None else (centre, root)


def _residuals(theta: F64, x: F64) -> tuple[F64, F64, F64]:
    """r_i = ||A (x_i - b)|| - 1, its Jacobian (N, 9) and dr/db (N, 3)."""
    b, a = theta[:3], _sym(theta[3:])
    d = x - b
    v = d @ a
    n = np.linalg.norm(v, axis=1)
    u = v / n[:, None]
    ua = u @ a
    jac = np.empty((x.shape[0], 9))
    jac[:, :3] = -ua
    for k, (i, j) in enumerate(_SYM):
        jac[:, 3 + k] = u[:, i] * d[:, j] + (u[:, j] * d[:, i] if i != j else 0.0)
    return n - 1.0, jac, ua


def _noise_of_residuals(ua: F64, sigma: F64) -> F64:
    """Predicted sigma of each residual: dr = (A u) . dm, so s_i^2 = sum_k (A u)_k^2 sigma_k^2."""
    s: F64 = np.sqrt((ua * ua) @ (sigma * sigma))
    return s


def levenberg_marquardt(theta: F64, x: F64, sigma: F64) -> tuple[F64, F64, int]:
    """Weighted LM on the 9 parameters (b, A). The weights are refreshed at each outer pass
    and held fixed inside it, so each inner loop minimises one well-defined cost. Returns
    theta, (J^T W J)^-1 and the number of iterations."""
    iterations = 0
    for _ in range(3):
        _, _, ua = _residuals(theta, x)
        w = 1.0 / _noise_of_residuals(ua, sigma)
        lam = 1e-3
        for _ in range(200):
            r, jac, _ = _residuals(theta, x)
            rw, jw = r * w, jac * w[:, None]
            h, g, cost = jw.T @ jw, jw.T @ rw, float(rw @ rw)
            new = cost
            step: F64 = np.zeros(9)
            while lam < 1e12:
                step = np.asarray(np.linalg.solve(h + lam * np.diag(np.diag(h)), -g))
                trial = theta + step
                rt = _residuals(trial, x)[0] * w
                new = float(rt @ rt)
                if np.isfinite(new) and new <= cost:
                    theta, lam = trial, max(lam / 3.0, 1e-12)
                    break
                lam *= 4.0
            iterations += 1
            if lam >= 1e12 or cost - new <= 1e-14 * cost:
                break
            if np.linalg.norm(step) < 1e-12 * (1.0 + np.linalg.norm(theta)):
                break
    _, jac, ua = _residuals(theta, x)
    jn = jac / _noise_of_residuals(ua, sigma)[:, None]
    cov: F64 = np.asarray(np.linalg.pinv(jn.T @ jn), dtype=np.float64)
    return theta, cov, iterations


# --- coverage -------------------------------------------------------------------------------


def fibonacci_sphere(n: int) -> F64:
    """n nearly equal-area cell centres on the unit sphere (golden-angle spiral)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    out: F64 = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    return out


def coverage(directions: F64) -> Coverage:
    """Cells visited by unit vectors (N, 3). Missing directions are named by body axis: an
    axis counts as missing when NAME_EMPTY_SHARE of the 5-6 cells within NAME_CAP_DEG of it
    are empty (so a band of directions around it, as from turning in one plane, does not name
    it). Otherwise the mean direction of the empty cells is given."""
    centres = fibonacci_sphere(COVERAGE_CELLS)
    hit = np.zeros(COVERAGE_CELLS, dtype=bool)
    hit[np.argmax(directions @ centres.T, axis=1)] = True
    missing: list[str] = []
    for axis, sign in ((2, -1), (2, 1), (0, 1), (0, -1), (1, 1), (1, -1)):
        near = sign * centres[:, axis] >= math.cos(math.radians(NAME_CAP_DEG))
        if np.count_nonzero(~hit & near) >= NAME_EMPTY_SHARE * np.count_nonzero(near):
            missing.append(_AXIS_WORDS[("+" if sign > 0 else "-") + "xyz"[axis]])
    if not missing and not hit.all():
        mean = centres[~hit].sum(axis=0)
        norm = float(np.linalg.norm(mean))
        if norm > 1e-9:
            mx, my, mz = mean / norm
            missing.append(f"the field toward ({mx:+.2f}, {my:+.2f}, {mz:+.2f}) in body axes")
        else:
            missing.append(f"{np.count_nonzero(~hit)} scattered directions")
    return Coverage(COVERAGE_CELLS, int(hit.sum()), COVERAGE_REQUIRED, tuple(missing))


# --- the procedure --------------------------------------------------------------------------


def _readings(rec: Recording) -> tuple[F64, npt.NDArray[np.int64], int, int]:
    """Finite, unsaturated, distinct readings. A magnetometer sampled slower than the IMU
    is held between its updates. Repeated rows would fake zero noise in the differences, so
    only rows that differ from the previous one are kept."""
    if rec.mag is None:
        raise CalibrationRefused(
            f"{rec.source or 'the recording'} has no magnetometer columns (mx, my, mz); "
            "record with the magnetometer enabled"
        )
    m = np.asarray(rec.mag, dtype=np.float64)
    keep = np.all(np.isfinite(m), axis=1)
    saturated = 0
    if rec.saturated is not None:
        saturated = int(np.count_nonzero(rec.saturated & keep))
        keep &= ~rec.saturated
    m, t = m[keep], rec.t_ns[keep]
    fresh = np.ones(m.shape[0], dtype=bool)
    fresh[1:] = np.any(m[1:] != m[:-1], axis=1)
    return m[fresh], t[fresh], saturated, int(np.count_nonzero(~fresh))


def _minmax(m: F64) -> tuple[F64, F64, float]:
    """The seed's method: hard iron = mid-range per axis, soft iron = diag(mean half-range /
    half-range). Uses 2 samples per axis, and cannot represent off-diagonal soft iron."""
    lo, hi = m.min(axis=0), m.max(axis=0)
    half = (hi - lo) / 2.0
    radius = float(half.mean())
    return (hi + lo) / 2.0, np.diag(radius / half), radius


def _residual_stats(
    m: F64, bias: F64, matrix: F64, field: float, sigma: F64, noise_dof: F64, n_par: int
) -> tuple[dict[str, float], F64, float]:
    """Residual statistics in tesla, the corrected unit vectors and Satterthwaite's c."""
    corrected = (m - bias) @ matrix.T
    norm = np.linalg.norm(corrected, axis=1)
    u = corrected / norm[:, None]
    ua = u @ matrix
    s = _noise_of_residuals(ua, sigma)
    r = norm - field
    chi2 = float(np.sum((r / s) ** 2))
    dof = float(m.shape[0] - n_par)
    shares = np.sum((ua * sigma) ** 2 / (s * s)[:, None], axis=0)
    c = chi2_scale(dof, shares, noise_dof)
    rms = float(np.sqrt(np.mean(r * r)))
    return (
        {
            "rms": rms,
            "norm_error_rms_pct": 100.0 * rms / field,
            "chi2": chi2,
            "dof": dof,
            "p_value": p_value(chi2, dof, c),
            "noise": float(np.sqrt(np.mean(s * s))),
        },
        u,
        c,
    )


def _floor(
    m: F64,
    bias: F64,
    matrix: F64,
    field: float,
    sigma: F64,
    residuals: dict[str, float],
    c: float,
    significance: float,
) -> float:
    """The model-error floor (imud/calib/acceptance.py) of the norm residuals, tesla; the
    chi-squared widened by Satterthwaite's c as the noise test is."""
    corrected = (m - bias) @ matrix.T
    norm = np.linalg.norm(corrected, axis=1)
    ua = (corrected / norm[:, None]) @ matrix
    r2 = (norm - field) ** 2
    var = _noise_of_residuals(ua, sigma) ** 2
    return model_error_floor(
        lambda s2: float(np.sum(r2 / (var + s2))) / c,
        residuals["dof"] / c,
        residuals["rms"],
        significance,
    )


def _report_jacobian(a: F64, field_t: float | None) -> tuple[F64, float]:
    """d(bias, matrix6, field)/d(b, A6) and the field: matrix = field * A, with
    field = field_t, or det(A)^(-1/3) so that det(matrix) = 1."""
    g = np.zeros((10, 9))
    g[:3, :3] = np.eye(3)
    if field_t is not None:
        g[3:9, 3:] = field_t * np.eye(6)
        return g, field_t
    field = float(np.linalg.det(a) ** (-1.0 / 3.0))
    inv = np.linalg.inv(a)
    dfield = np.array([-field / 3.0 * inv[i, j] * (1.0 if i == j else 2.0) for i, j in _SYM])
    g[3:9, 3:] = field * np.eye(6) + np.outer(_sym6(a), dfield)
    g[9, 3:] = dfield
    return g, field


def fit_mag(
    rec: Recording,
    field_t: float | None = None,
    acceptance: Acceptance | None = None,
    shots: bool = False,
) -> MagResult:
    """Hard iron (bias, tesla) and symmetric soft iron (matrix) from a recording rotated
    through many directions.

    Pass `field_t` when the local field magnitude is known. It then fixes the scale (9 free
    parameters). Otherwise det(matrix) = 1 and the field is fitted (see the module docstring).

    Raises CalibrationRefused (a ValueError) when nothing can be estimated: no magnetometer
    columns, fewer than MIN_SAMPLES distinct readings, or readings that span no ellipsoid.
    Otherwise it returns an estimate whose verdict refuses poor coverage (and names the
    missing directions) or residuals beyond the measured noise.

    shots: each row is one reading of a still pose (a shot list: no stream, so no noise to
    measure between samples). The noise is then what the residuals show, the readings need not
    fill the sphere's cells but must determine every parameter (named from the fit's sigmas
    otherwise), and the verdict accepts a residual RMS within the tolerance.
    """
    if field_t is not None and not (math.isfinite(field_t) and field_t > 0):
        raise ValueError(f"field_t must be a positive field magnitude in tesla, got {field_t}")
    m, t_ns, saturated, held = _readings(rec)
    where = rec.source or "the recording"
    need = MIN_SHOTS if shots else MIN_SAMPLES
    if m.shape[0] < need:
        more = (
            "take readings in new directions"
            if shots
            else "rotate the device slowly through all directions for longer"
        )
        raise CalibrationRefused(
            f"{where} has {m.shape[0]} distinct magnetometer readings; the fit needs at least "
            f"{need} ({need - m.shape[0]} more): {more}"
        )
    if shots:  # a nominal noise for the fit's weights; the residuals give the real one below
        spread = float(np.sqrt(np.mean(np.sum((m - m.mean(axis=0)) ** 2, axis=1))))
        sigma, noise_dof = np.full(3, spread * 1e-3), np.full(3, np.inf)
    else:
        sigma, noise_dof = difference_noise(m, t_ns)
    if not np.all(sigma > 0):
        raise CalibrationRefused(
            f"{where}: the magnetometer readings do not vary from sample to sample "
            "(stuck sensor?); check that it is enabled and updating"
        )
    # work in units of the cloud's size, centred: the algebraic fit squares the data
    c0 = m.mean(axis=0)
    s0 = float(np.sqrt(np.mean(np.sum((m - c0) ** 2, axis=1))))
    x = (m - c0) / s0
    sx = sigma / s0
    mm_bias, mm_matrix, mm_radius = _minmax(m)
    start = li_griffiths(x)
    start_name = "li-griffiths"
    if start is None:
        start = ((mm_bias - c0) / s0, mm_matrix / (mm_radius / s0))
        start_name = "min/max (the algebraic fit gave no ellipsoid)"
    theta0 = np.concatenate([start[0], _sym6(start[1])])
    try:
        theta, cov_scaled, iterations = levenberg_marquardt(theta0, x, sx)
        a_scaled = _sym(theta[3:])
        axes = np.linalg.eigvalsh(a_scaled) if np.all(np.isfinite(theta)) else np.zeros(3)
    except np.linalg.LinAlgError:
        axes = np.zeros(3)
    if not (axes[0] > 0 and axes[2] <= MAX_AXIS_RATIO * axes[0]):
        rough = coverage(_unit(m - mm_bias))
        raise CalibrationRefused(
            f"{where}: the readings span no plausible ellipsoid (a plane or an arc of "
            f"directions; about {rough.fraction:.0%} of directions around the mid-range "
            f"centre, missing the field along {', '.join(rough.missing) or 'nothing'}); "
            "rotate the device through all directions"
        )
    bias = c0 + s0 * theta[:3]
    a = a_scaled / s0
    to_si = np.diag([s0] * 3 + [1.0 / s0] * 6)
    g, field = _report_jacobian(a, field_t)
    jac = g @ to_si
    covariance = jac @ cov_scaled @ jac.T
    matrix = field * a
    residuals, u, c = _residual_stats(m, bias, matrix, field, sigma, noise_dof, 9)
    acceptance = acceptance or Acceptance(significance=P_REJECT)
    tolerance = acceptance.tolerance_for(Tolerance.MAG, field)
    named = acceptance.source(Tolerance.MAG)
    if shots:
        # the noise the residuals show, over their degrees of freedom: the weights were all
        # equal, so the fit stands and its covariance scales
        shown = residuals["rms"] * math.sqrt(m.shape[0] / residuals["dof"])
        ratio = shown / residuals["noise"]
        sigma, covariance = sigma * ratio, covariance * ratio * ratio
        residuals, u, c = _residual_stats(m, bias, matrix, field, sigma, noise_dof, 9)
        residuals["model_error"] = 0.0
        fixed = field_t is not None
        return _shots_result(
            rec, m, (bias, matrix, field, covariance), (sigma, noise_dof), residuals, u,
            (tolerance, named), fixed, acceptance.significance,
        )  # fmt: skip
    floor = _floor(m, bias, matrix, field, sigma, residuals, c, acceptance.significance)
    residuals["model_error"] = floor
    if floor > 0:
        # the model error in every sample's variance: the per-sample noise is nearly the same
        # for every sample, so the covariance scales by (noise^2 + s^2) / noise^2
        covariance = covariance * (1.0 + (floor / residuals["noise"]) ** 2)
    cover = coverage(u)

    reasons: list[str] = []
    accepted = True
    if not cover.ok:
        accepted = False
        reasons.append(
            f"directions cover {cover.fraction:.0%} of the sphere ({cover.visited} of "
            f"{cover.cells} cells), below the {cover.required:.0%} needed: no samples with "
            f"the field along {', '.join(cover.missing)}; rotate the device until those "
            "directions are filled"
        )
    beyond = (
        f"(chi2/dof = {residuals['chi2'] / residuals['dof']:.2f}, p = {residuals['p_value']:.1e})"
    )
    advice = (
        "the field is not an affine image of a sphere here; move away from iron and magnets, "
        "keep motors and currents steady, and rotate slowly"
    )
    if acceptance.strict and residuals["p_value"] < acceptance.significance:
        accepted = False
        reasons.append(f"residuals exceed the measured noise {beyond}, --strict: {advice}")
    elif not acceptance.strict and floor > tolerance:
        accepted = False
        reasons.append(
            f"the residuals hold a model error of {floor * 1e6:.3g} uT beyond the noise "
            f"({residuals['noise'] * 1e6:.3g} uT) {beyond}, more than the tolerance of "
            f"{tolerance * 1e6:.3g} uT ({named}): {advice}"
        )
    elif not acceptance.strict and floor > 0:
        reasons.append(
            f"model error {floor * 1e6:.3g} uT beyond the noise ({residuals['noise'] * 1e6:.3g}"
            f" uT), within the tolerance of {tolerance * 1e6:.3g} uT ({named})"
        )
    lower = 1.0 - p_value(residuals["chi2"], residuals["dof"], c)
    if lower < P_REJECT:
        reasons.append(
            f"residuals are well below the measured noise (chi2/dof = "
            f"{residuals['chi2'] / residuals['dof']:.2f}): rotation between samples inflated "
            "the noise estimate, so the reported uncertainty is conservative; rotate slower"
        )
    if saturated:
        reasons.append(f"{saturated} saturated samples were left out")

    details: dict[str, Any] = {
        "scale": SCALE_FIXED if field_t is not None else SCALE_FREE,
        "free_parameters": 9,
        "start": start_name,
        "iterations": iterations,
        "n_samples": int(m.shape[0]),
        "n_saturated_dropped": saturated,
        "n_held_repeats_dropped": held,
        "noise_per_axis_t": sigma.tolist(),
        "noise_dof_per_axis": noise_dof.tolist(),
        "chi2_scale": c,
        "coverage_fraction": cover.fraction,
        "coverage_missing": list(cover.missing),
    }
    fit = Fit(
        NAMES,
        np.concatenate([bias, _sym6(matrix), [field]]),
        covariance,
        residuals,
        details,
    )
    temperature = _mean_temperature(rec)
    estimate = AffineEstimate(
        "mag",
        "mag-ellipsoid",
        bias,
        matrix,
        fit,
        Verdict(accepted, tuple(reasons)),
        temperature_c=temperature,
        field_t=field,
    )
    mm_res, _, _ = _residual_stats(m, mm_bias, mm_matrix, mm_radius, sigma, noise_dof, 6)
    minmax = AffineEstimate(
        "mag",
        "mag-minmax",
        mm_bias,
        mm_matrix,
        Fit(
            NAMES,
            np.concatenate([mm_bias, _sym6(mm_matrix), [mm_radius]]),
            np.full((10, 10), np.nan),
            mm_res,
            {"method": MINMAX_METHOD},
        ),
        Verdict(False, ("the seed's per-axis min/max, shown for comparison only",)),
        temperature_c=temperature,
        field_t=mm_radius,
    )
    return MagResult(estimate, minmax, cover)


def _shots_result(
    rec: Recording,
    m: F64,
    solved: tuple[F64, F64, float, F64],
    noise: tuple[F64, F64],
    residuals: dict[str, float],
    u: F64,
    tolerances: tuple[float, str],
    field_fixed: bool,
    significance: float,
) -> MagResult:
    """A shot list's verdict: every parameter determined (from the fit's sigmas, not a count
    of cells), and the residual RMS within the tolerance. solved: bias, matrix, field and
    covariance; noise: the per-axis sigma the residuals show and its degrees of freedom."""
    bias, matrix, field, covariance = solved
    tolerance, named = tolerances
    sig = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    weak = [
        f"{name} (sigma {s * 1e6:.3g} uT)" if name.startswith("bias") else f"{name} (sigma {s:.2g})"
        for name, s in zip(NAMES[:9], sig[:9], strict=True)
        if not s <= (tolerance if name.startswith("bias") else WEAK_MATRIX_SIGMA)
    ]
    cover = coverage(u)
    reasons: list[str] = []
    rms = residuals["rms"]
    if weak:
        reasons.append(
            f"{m.shape[0]} readings leave {', '.join(weak)} undetermined: take readings with "
            f"the field along {', '.join(cover.missing) or 'directions between those taken'}"
        )
    r = np.linalg.norm((m - bias) @ matrix.T, axis=1) - field
    worst = int(np.argmax(np.abs(r)))
    # one reading off the others' ellipsoid (taken beside iron, or moving) hides in the RMS of
    # forty: judged against the others' scatter (the residuals but its own, over their degrees
    # of freedom: Student's t), Bonferroni over the readings
    dof = m.shape[0] - 1 - 9
    scatter = math.sqrt(max(float(r @ r) - float(r[worst]) ** 2, 0.0) / dof)
    z = abs(float(r[worst])) / scatter if scatter > 0 else math.inf
    if t_sf_two_sided(z, dof) * m.shape[0] < significance:
        reasons.append(
            f"reading {worst + 1} (line order) is {r[worst] * 1e6:+.3g} uT off the others' "
            f"ellipsoid, {z:.0f} times their scatter ({scatter * 1e6:.2g} uT): taken beside iron "
            "or a current, or while moving; take it again or leave it out"
        )
    elif rms > tolerance:
        reasons.append(
            f"a shot list's residuals are {rms * 1e6:.3g} uT RMS, more than the tolerance of "
            f"{tolerance * 1e6:.3g} uT ({named}): the worst is reading {worst + 1} "
            "(line order); readings near iron or a current, or taken while moving"
        )
    accepted = not reasons
    if accepted:
        reasons.append(
            f"a shot list (one reading a pose): its noise is taken from the residuals, "
            f"{rms * 1e6:.3g} uT RMS, within the tolerance of {tolerance * 1e6:.3g} uT ({named})"
        )
    details: dict[str, Any] = {
        "scale": SCALE_FIXED if field_fixed else SCALE_FREE,
        "free_parameters": 9,
        "n_samples": int(m.shape[0]),
        "shots": True,
        "noise_per_axis_t": noise[0].tolist(),
        "coverage_fraction": cover.fraction,
        "coverage_missing": list(cover.missing),
    }
    fit = Fit(NAMES, np.concatenate([bias, _sym6(matrix), [field]]), covariance, residuals, details)
    temperature = _mean_temperature(rec)
    estimate = AffineEstimate(
        "mag", "mag-ellipsoid", bias, matrix, fit, Verdict(accepted, tuple(reasons)),
        temperature_c=temperature, field_t=field,
    )  # fmt: skip
    mm_bias, mm_matrix, mm_radius = _minmax(m)
    mm_res, _, _ = _residual_stats(m, mm_bias, mm_matrix, mm_radius, *noise, 6)
    minmax = AffineEstimate(
        "mag", "mag-minmax", mm_bias, mm_matrix,
        Fit(NAMES, np.concatenate([mm_bias, _sym6(mm_matrix), [mm_radius]]),
            np.full((10, 10), np.nan), mm_res, {"method": MINMAX_METHOD}),
        Verdict(False, ("the seed's per-axis min/max, shown for comparison only",)),
        temperature_c=temperature, field_t=mm_radius,
    )  # fmt: skip
    return MagResult(estimate, minmax, cover)


def _unit(v: F64) -> F64:
    out: F64 = v / np.linalg.norm(v, axis=1)[:, None]
    return out


def _mean_temperature(rec: Recording) -> float | None:
    if rec.temp is None or not np.any(np.isfinite(rec.temp)):
        return None
    return float(np.nanmean(rec.temp))
