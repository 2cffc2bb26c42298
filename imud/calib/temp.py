"""Temperature compensation of bias: a polynomial per axis, order 1-3 chosen by the fit.

Model. In a still recording (one orientation) across a temperature span, each axis reads
reading(T) = c0 + sum_{k=1..order} c_k (T - T_ref)^k + noise. The constant c0 is dropped. It
holds the orientation's share of gravity (accel), Earth rate and g-sensitivity (gyro), and the
bias at T_ref, which the accel and gyro calibrations estimate. What is kept is c_1..c_order as
an (order, 3) array: bias(T) - bias(T_ref). It is reported in details as `offset_at_reference`.

For the accelerometer, a scale factor that drifts with temperature (MPU6050: about 200 ppm/degC,
2 mg/degC on the axis carrying gravity) looks here like bias drift on that axis. The fit folds
it into the bias, which is exact for this orientation only.

Why T_ref defaults to the middle of the span: the fit runs in x = (T - T_ref) / h, with h the
half-span, so x stays in [-1, 1] and the columns 1, x, x^2, x^3 are bounded and nearly
orthogonal (odd against even). Take 10-50 degC against T_ref = 0 instead: T, T^2 and T^3 all
rise together, the normal matrix has a condition number ~1e12 (70 when centred and scaled),
and the coefficients come out strongly correlated. c0 is then also the bias mid-span, not an
extrapolation.

Why block means: the work scales with the number of 1 s blocks, not with millions of samples.
The noise of a block mean is measured from third differences of consecutive block means.
These also see noise correlated on the block time scale (flicker, bias wander), which
sigma/sqrt(n) from within a block misses. They cancel the slow temperature trend: with a
0.01 degC/s ramp its third difference is negligible.

Choosing the order: backward elimination against the measured noise. Start at the highest
order the span allows. Keep the top term when removing it raises chi2 by more than chance:
that increase is chi-squared with 3 degrees of freedom (one coefficient per axis), tested at
p < 0.01. The error of a noise estimate with thousands of degrees of freedom is negligible
against 3. Otherwise drop one order and repeat. Backward, not forward: a cubic that is nearly
odd about T_ref gains nothing from a quadratic term, and forward selection would stop at
order 1. BIC would judge the residuals by a noise taken from those same residuals.
Cross-validation spends data to learn what the independently measured noise already says.

Each block's residual variance is sigma_axis^2 + (slope * sigma_T)^2. The measured temperature
of a block is noisy too, and where the drift is steep (the ends of a cubic) that noise moves
the prediction by more than the readings' own noise.

Span rule: order k needs a span of at least 5*k degC (5, 10, 15), and at least k + 2 occupied
1 degC bins, each with 3 or more blocks. The temperature the die sensor reports leads or
lags the sensing element by a few tenths of a degree during a ramp (thermal lag, hysteresis).
Over less than ~5 degC that error is a sizeable fraction of the span, and the slope means
little. Each further order needs the curve seen over that much more span to separate its
term from the lower ones. k + 2 bins leaves a degree of freedom for the chi-squared test
beyond the k + 1 coefficients.

When the residuals fail the chi-squared test: a higher order the span allows, or one the user
capped, is named (a misfit). Residuals that move together from block to block are a bias that
wanders with time (bias instability), which every MEMS gyro has and no polynomial of
temperature holds: the fit is accepted, with the coefficients' covariance inflated by the
long-run factor of the residuals, and says so. Heating and cooling are compared too: the
residual means of heating and cooling blocks against the wander-inflated noise. A difference
(p < 0.01) is said, never refused: hysteresis or a lagging temperature sensor would show so,
but so does slow wander between two legs recorded minutes apart (the long-run factor is a
lower bound), and only recurrence over several cycles tells them apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from imud.calib.estimate import F64, Fit, TempEstimate, Verdict
from imud.calib.mag import chi2_scale, difference_noise, p_value
from imud.calib.model import TempPoly
from imud.calib.recording import Recording
from imud.calib.stats import chi2_sf
from imud.calib.still import CalibrationRefused

P_REJECT = 0.01
BLOCK_S = 1.0
MIN_BLOCK_SAMPLES = 10
MAX_BLOCKS = 20_000
MIN_BLOCKS = 20
SPAN_PER_ORDER_C = 5.0
BIN_C = 1.0
MIN_BLOCKS_PER_BIN = 3
P_MOTION = 1e-6
MOTION_FLOOR = 2.0
"""A block moves when its within-block variance (any axis of accel or gyro) exceeds the
recording's median block variance by the chi-squared quantile at p = 1e-6 (false alarms:
about 1 in 100 recordings of 10^4 blocks), and by at least 2x. The noise itself changes a
little with temperature, and 1/f noise adds within a block; at 1 kHz the bare quantile (~1.2x)
would flag that. Handling a device raises the variance far more than 2x."""
AXES = "xyz"


def temp_correction(
    coefficients: F64, reference_c: float, span_c: tuple[float, float], temp: F64
) -> tuple[F64, npt.NDArray[np.bool_]]:
    """The bias change to subtract at each temperature, (N, 3), and a mask of the samples
    whose temperature lay outside span_c (clamped to the nearer edge there; a non-finite
    temperature gets no correction and is flagged). The pipeline's own code
    (imud/calib/model.py `TempPoly.offset`), so a fit is checked with what will apply it."""
    poly = TempPoly(reference_c, np.asarray(coefficients, dtype=np.float64), span_c)
    return poly.offset(np.asarray(temp, dtype=np.float64).reshape(-1))


def _blocks(rec: Recording) -> tuple[int, int]:
    """Samples per block (~1 s, at least MIN_BLOCK_SAMPLES, grown so blocks stay below
    MAX_BLOCKS) and the number of whole blocks."""
    per = max(MIN_BLOCK_SAMPLES, round(rec.rate_hz * BLOCK_S) if rec.n > 1 else 1)
    per = max(per, math.ceil(rec.n / MAX_BLOCKS))
    return per, rec.n // per


def _chi2_quantile(p: float, dof: float) -> float:
    """x with chi2_sf(x, dof) = p, by bisection (called once per recording)."""
    lo, hi = 0.0, dof + 20.0 * math.sqrt(2.0 * dof) + 100.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if chi2_sf(mid, dof) > p else (lo, mid)
    return hi


def _moving_blocks(rec: Recording, per: int, nb: int) -> npt.NDArray[np.bool_]:
    """Blocks with motion (within-block variance far above the median block's, any axis of
    accel or gyro) or a saturated sample."""
    used = nb * per
    both = np.concatenate([rec.accel[:used], rec.gyro[:used]], axis=1).reshape(nb, per, 6)
    var = both.var(axis=1, ddof=1)
    median = np.median(var, axis=0)
    limit = max(_chi2_quantile(P_MOTION, per - 1) / (per - 1), MOTION_FLOOR)
    moving: npt.NDArray[np.bool_] = np.any(var > limit * np.maximum(median, 1e-300), axis=1)
    if rec.saturated is not None:
        moving |= rec.saturated[:used].reshape(nb, per).any(axis=1)
    return moving


def _span_rule(span: float, occupied: int, max_order: int) -> int:
    return min(max_order, int(span / SPAN_PER_ORDER_C + 1e-9), occupied - 2)


def _needs(order: int, span: float, occupied: int) -> str:
    need = SPAN_PER_ORDER_C * order
    parts = []
    if span < need - 1e-9:
        parts.append(f"a span of at least {need:.0f} degC ({need - span:.1f} degC more)")
    if occupied < order + 2:
        parts.append(
            f"{order + 2} temperatures {BIN_C:.0f} degC apart with at least "
            f"{MIN_BLOCKS_PER_BIN} s each (found {occupied})"
        )
    return " and ".join(parts)


def _lag1(z: F64, t_ns: npt.NDArray[np.int64]) -> tuple[float, float]:
    """Lag-1 correlation of standardised residuals between consecutive blocks (pooled over
    axes) and its z-score. A polynomial fit that holds leaves residuals as white as the
    noise, so r is near 0 within 1/sqrt(pairs). A slowly wandering bias, or hysteresis, leaves
    neighbours alike."""
    step = np.diff(t_ns)
    pair = step <= 1.5 * float(np.median(step)) if step.size else np.zeros(0, dtype=bool)
    num = float(np.sum(z[:-1][pair] * z[1:][pair]))
    den = float(np.sum(z * z))
    rho = num / den if den > 0 else 0.0
    return rho, rho * math.sqrt(max(3 * int(np.count_nonzero(pair)), 1))


def _long_run_factor(z: F64) -> float:
    """How much the residuals' slow part inflates the coefficients' sigmas, by block
    averaging (Flyvbjerg & Petersen). z is residual / measured block noise. Averaging 2^j
    neighbours scales white noise's variance by 2^-j, so var(mean) * 2^j stays at chi2/dof.
    A wandering bias keeps it growing with j. The largest value over levels with at least
    16 means estimates the long-run variance against the white noise: it is the factor that
    matters for coefficients, which are smooth weighted sums over many blocks. The sigma
    factor is its square root. It is a lower bound: the fitted polynomial absorbs the wander
    on the scale of the whole span (a simulated 100 s Gauss-Markov wander gave ~4x where the
    true factor was ~7x). Taken from the residuals, it is only used when the chi-squared test
    has already failed."""
    best, n = 1.0, z.shape[0]
    level = 1
    while n // level >= 16:
        k = n // level
        means = z[: k * level].reshape(k, level, -1).mean(axis=1)
        best = max(best, float(np.mean(means * means)) * level)
        level *= 2
    return math.sqrt(best)


SLOPE_HALF = 15  # blocks each side of the regression that tells heating from cooling


@dataclass(frozen=True)
class _Hysteresis:
    difference: F64  # mean residual while heating minus while cooling, per axis
    chi2: float
    p: float
    heating: int
    cooling: int


def _hysteresis(
    resid: F64, sigma: F64, temps: F64, t_ns: npt.NDArray[np.int64], sigma_t: float
) -> _Hysteresis | None:
    """Whether the residuals differ between heating and cooling blocks (3-dof chi-squared on
    the difference of their means, with `sigma` the block noise, wander included). Heating or
    cooling: the temperature's regression slope over 31 blocks, beyond 3 of its standard
    errors. None when the recording lacks either direction."""
    w = SLOPE_HALF
    n = temps.shape[0]
    if n < 2 * w + 1 + 2 * MIN_BLOCKS:
        return None
    t = (t_ns - t_ns[0]) / 1e9
    k = np.arange(-w, w + 1, dtype=np.float64)
    # slope per block of a least-squares line through its 2w + 1 neighbours (centred)
    num = np.convolve(temps, k[::-1], mode="valid")
    dt = np.convolve(t, k[::-1], mode="valid")  # sum k t: the same regression on time
    slope = num / np.where(dt > 0, dt, np.inf)
    se = sigma_t * math.sqrt(float(np.sum(k * k))) / np.where(dt > 0, dt, np.inf)
    direction = np.zeros(n, dtype=np.int8)
    direction[w : n - w] = np.where(slope > 3 * se, 1, np.where(slope < -3 * se, -1, 0))
    heating, cooling = direction == 1, direction == -1
    nh, nc = int(np.count_nonzero(heating)), int(np.count_nonzero(cooling))
    if nh < MIN_BLOCKS or nc < MIN_BLOCKS:
        return None
    up, down = resid[heating].mean(axis=0), resid[cooling].mean(axis=0)
    se_diff = sigma * math.sqrt(1.0 / nh + 1.0 / nc)
    chi2 = float(np.sum(((up - down) / se_diff) ** 2))
    return _Hysteresis(up - down, chi2, p_value(chi2, 3.0), nh, nc)


def _design(x: F64, order: int) -> F64:
    out: F64 = np.vander(x, order + 1, increasing=True)
    return out


@dataclass(frozen=True)
class _PolyFit:
    coef: F64  # (order + 1, 3) in x = (T - T_ref) / half
    resid: F64  # (n, 3)
    chi2: float
    var: F64  # (n, 3) effective variance of each residual
    inverse: F64  # (3, order + 1, order + 1): (X^T W_a X)^-1 per axis, the covariance


def _fit_order(x: F64, y: F64, sigma: F64, sigma_x: float, order: int) -> _PolyFit:
    """Weighted least squares per axis, with effective variance sigma_a^2 + (dy/dx sigma_x)^2.
    The measured temperature is noisy too. A block mean's temperature error moves its
    predicted bias by the local slope times that error, which the readings' own noise does not
    contain. Where the drift is steep (the ends of a cubic) this dominates. Two passes: the
    slope comes from the previous pass."""
    xd = _design(x, order)
    coef = np.asarray(np.linalg.lstsq(xd, y, rcond=None)[0], dtype=np.float64)
    deriv = _design(x, order - 1) * np.arange(1, order + 1) if order > 0 else np.zeros_like(xd)
    inverse = np.empty((3, order + 1, order + 1))
    var = np.empty_like(y)
    for _ in range(2):
        slope = deriv @ coef[1:]
        var = sigma**2 + (slope * sigma_x) ** 2
        for a in range(3):
            w = 1.0 / var[:, a]
            inverse[a] = np.linalg.inv(xd.T @ (xd * w[:, None]))
            coef[:, a] = inverse[a] @ (xd.T @ (w * y[:, a]))
    resid = y - xd @ coef
    return _PolyFit(coef, resid, float(np.sum(resid**2 / var)), var, inverse)


def fit_temperature(
    rec: Recording,
    sensor: Literal["accel", "gyro"],
    max_order: int = 3,
    reference_c: float | None = None,
) -> TempEstimate:
    """Bias-against-temperature polynomial for `sensor` from a still recording across a span.

    Raises CalibrationRefused (a ValueError) when no estimate can be formed: no temperature
    recorded, too short, or a span too small for even a linear fit (the message names the
    span needed). Returns an estimate whose verdict refuses motion or saturation, or residuals
    beyond the measured noise.
    """
    if sensor not in ("accel", "gyro"):
        raise ValueError(f"sensor must be 'accel' or 'gyro', not {sensor!r}")
    if not 1 <= max_order <= 3:
        raise ValueError(f"max_order must be 1, 2 or 3, not {max_order}")
    where = rec.source or "the recording"
    if rec.temp is None or not np.all(np.isfinite(rec.temp)):
        raise CalibrationRefused(
            f"{where} has no temperature (or non-finite values in it); record with the "
            "temperature column (temp) to fit temperature compensation"
        )
    per, nb = _blocks(rec)
    if nb < MIN_BLOCKS:
        raise CalibrationRefused(
            f"{where} holds {nb} blocks of {per} samples; the fit needs at least {MIN_BLOCKS}: "
            "record longer"
        )
    used = nb * per
    data = rec.accel if sensor == "accel" else rec.gyro
    means = data[:used].reshape(nb, per, 3).mean(axis=1)
    white = data[:used].reshape(nb, per, 3).var(axis=1, ddof=1).mean(axis=0) / per
    temps = rec.temp[:used].reshape(nb, per).mean(axis=1)
    mid_ns = rec.t_ns[:used].reshape(nb, per)[:, per // 2]
    moving = _moving_blocks(rec, per, nb)
    still = ~moving
    if np.count_nonzero(still) < MIN_BLOCKS:
        raise CalibrationRefused(
            f"{where} is still for only {np.count_nonzero(still)} of {nb} blocks; keep the "
            "device still in one orientation while the temperature changes"
        )
    y, t_block, t_ns = means[still], temps[still], mid_ns[still]
    lo, hi = float(t_block.min()), float(t_block.max())
    span = hi - lo
    bins = np.floor(t_block / BIN_C).astype(np.int64)
    _, counts = np.unique(bins, return_counts=True)
    occupied = int(np.count_nonzero(counts >= MIN_BLOCKS_PER_BIN))
    allowed = _span_rule(span, occupied, max_order)
    if allowed < 1:
        raise CalibrationRefused(
            f"the temperature span {span:.1f} degC ({lo:.1f} to {hi:.1f} degC) is too small "
            f"for even a linear fit: it needs {_needs(1, span, occupied)}; heat or cool the "
            "device while it stays still"
        )
    t_ref = 0.5 * (lo + hi) if reference_c is None else float(reference_c)
    if not math.isfinite(t_ref):
        raise ValueError(f"reference_c must be a finite temperature, not {reference_c}")
    half = 0.5 * span
    x = (t_block - t_ref) / half

    # block-mean noise: windows straddling a removed (moving) block show a time gap there
    sigma, noise_dof = difference_noise(y, t_ns)
    sigma = np.maximum(sigma, 1e-300)

    sigma_t = float(difference_noise(t_block[:, None], t_ns)[0][0])
    fits = {k: _fit_order(x, y, sigma, sigma_t / half, k) for k in range(1, allowed + 1)}
    order, tests = 1, []
    for k in range(allowed, 1, -1):
        gain = fits[k - 1].chi2 - fits[k].chi2
        p_gain = p_value(gain, 3.0)  # 3 of thousands of dof: the noise's error is negligible
        tests.append({"order": k, "chi2_drop": gain, "p": p_gain})
        if p_gain < P_REJECT:
            order = k
            break

    best = fits[order]
    coef, resid, chi2 = best.coef, best.resid, best.chi2
    n_still = y.shape[0]
    dof = float(3 * (n_still - order - 1))
    c = chi2_scale(dof, np.sum(sigma**2 / best.var, axis=0), noise_dof)
    scale = half ** -np.arange(order + 1)
    coefficients = coef[1:] * scale[1:, None]
    cov = np.zeros((3 * order, 3 * order))
    for a in range(3):
        idx = np.arange(order) * 3 + a
        cov[np.ix_(idx, idx)] = best.inverse[a][1:, 1:] * np.outer(scale[1:], scale[1:])
    rms_axis = np.sqrt(np.mean(resid**2, axis=0))
    residuals: dict[str, float] = {
        "rms": float(np.sqrt(np.mean(resid**2))),
        **{f"rms_{AXES[a]}": float(rms_axis[a]) for a in range(3)},
        "chi2": chi2,
        "dof": dof,
        "p_value": p_value(chi2, dof, c),
        "noise": float(np.sqrt(np.mean(sigma**2))),
    }

    reasons: list[str] = []
    accepted = True
    if np.any(moving):
        accepted = False
        first = (int(rec.t_ns[int(np.argmax(moving)) * per]) - int(rec.t_ns[0])) / 1e9
        cause = (
            "saturation or motion"
            if rec.saturated is not None and rec.saturated[:used].any()
            else "motion"
        )
        reasons.append(
            f"{cause} in {np.count_nonzero(moving)} of {nb} blocks (first at {first:.1f} s): "
            "the device must stay still in one orientation; redo the recording, or cut it to "
            "the still part"
        )
    limited = allowed < max_order
    rho, rho_z = _lag1(resid / np.sqrt(best.var), t_ns)
    wander = _long_run_factor(resid / sigma)
    hyst = _hysteresis(resid, sigma * wander, t_block, t_ns, sigma_t)
    inflation = 1.0
    if residuals["p_value"] < P_REJECT:
        hint = ""
        if limited:
            hint = f"; order {allowed + 1} would need {_needs(allowed + 1, span, occupied)}"
        elif order < 3 and order == max_order:
            hint = f"; allow a higher order than {max_order}"
        head = (
            f"residuals exceed the measured block noise at order {order} (chi2/dof = "
            f"{chi2 / dof:.2f}, p = {residuals['p_value']:.1e})"
        )
        if rho_z > 3.0 and not hint:
            # a bias that wanders with time: every MEMS gyro has it, no polynomial of
            # temperature holds it, and the polynomial is still right to within it
            inflation = wander
            cov = cov * wander**2
            reasons.append(
                f"{head}, and they drift together from block to block (lag-1 correlation "
                f"{rho:.2f}): the bias wanders with time (bias instability), not with "
                f"temperature. Accepted with the coefficients' sigmas inflated {wander:.1f}x "
                "for it (a lower bound: the wander's slowest part looks like temperature)"
            )
        else:
            accepted = False
            reasons.append(
                f"{head}: the bias does not follow one polynomial of temperature"
                + (
                    hint
                    or " (the temperature sensor lagging the sensing element?); ramp more slowly"
                )
            )
    if hyst is None:
        if accepted:
            reasons.append(
                "the temperature moved one way only: hysteresis between heating and cooling "
                "cannot be seen in this recording (a leg the other way would show it)"
            )
    elif hyst.p < P_REJECT:
        # said, never refused: the slowest part of a wandering bias, which the block noise
        # under-counts, separates two legs recorded minutes apart as well (the simulated
        # MPU6050, which has no hysteresis, reached p = 1.4e-6 over one chamber cycle); only
        # its recurrence over several cycles tells hysteresis from wander
        step = ", ".join(f"{v:+.3g}" for v in hyst.difference)
        reasons.append(
            f"the residuals differ between heating and cooling by ({step}) (p = {hyst.p:.1e} "
            "against the block noise, wander included): hysteresis, the temperature sensor "
            "lagging the sensing element, or slow bias wander; if it recurs over several "
            "cycles, it is hysteresis: ramp more slowly"
        )
    if accepted and limited:
        reasons.append(
            f"order limited to {allowed} by the data; order {allowed + 1} needs "
            f"{_needs(allowed + 1, span, occupied)}"
        )

    names = tuple(f"c{k}_{AXES[a]}" for k in range(1, order + 1) for a in range(3))
    grid = (np.linspace(lo, hi, 201) - t_ref) / half
    fit_curve = _design(grid, order)[:, 1:] @ coef[1:]
    details: dict[str, Any] = {
        "order_rule": "highest order whose term lowers chi2 beyond chance (3 dof, p < 0.01)",
        "order_tests": tests,
        "allowed_order": allowed,
        "block_samples": per,
        "n_blocks": nb,
        "n_blocks_moving": int(np.count_nonzero(moving)),
        "offset_at_reference": coef[0].tolist(),
        "noise_block": sigma.tolist(),
        "noise_block_white": np.sqrt(white).tolist(),
        "noise_dof_per_axis": noise_dof.tolist(),
        "chi2_scale": c,
        "noise_block_temperature_c": sigma_t,
        "residual_lag1_correlation": rho,
        "sigma_factor_long_run": wander,
        "sigma_inflation": inflation,
        "hysteresis": None
        if hyst is None
        else {
            "difference": hyst.difference.tolist(),
            "chi2": hyst.chi2,
            "p": hyst.p,
            "heating_blocks": hyst.heating,
            "cooling_blocks": hyst.cooling,
        },
        "drift_fitted_peak_to_peak": np.ptp(fit_curve, axis=0).tolist(),
        "temperature_bins": occupied,
    }
    return TempEstimate(
        sensor,
        t_ref,
        coefficients,
        (lo, hi),
        Fit(names, coefficients.reshape(-1), cov, residuals, details),
        Verdict(accepted, tuple(reasons)),
    )
