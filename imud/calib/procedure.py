"""The calibration procedures as the CLI runs them, live or offline: a recording in, an outcome
out (the estimate, a JSON-able report, the verdict, and how it updates the device's file).

The estimators (accel.py, gyro.py, temp.py, mag.py) know nothing of files or terminals; this
module is the one place that decides what a procedure reads from the existing calibration (a
temperature polynomial already in the file is applied before fitting bias and matrix, so the
new bias is the bias at the polynomial's reference temperature) and what it writes back.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from imud.calib.acceptance import Acceptance
from imud.calib.estimate import AffineEstimate, Fit, TempEstimate
from imud.calib.file import (
    CalibrationFile,
    sensor_model,
    with_affine,
    with_noise,
    with_temperature,
)
from imud.calib.gsens import GSensitivity, fit_g_sensitivity
from imud.calib.noise import measured_density, shortfall
from imud.calib.recording import Recording
from imud.calib.sanity import check_recording
from imud.calib.still import CalibrationRefused, StillInterval
from imud.units import STANDARD_GRAVITY

F64 = npt.NDArray[np.float64]
Kind = Literal["accel", "gyro", "temp", "mag"]


@dataclass
class Outcome:
    """What one procedure concluded. `update` applies it to a calibration file (only called when
    it was accepted)."""

    kind: Kind
    accepted: bool
    reasons: list[str]
    report: dict[str, Any]
    update: Callable[[CalibrationFile, str], CalibrationFile]
    plot: dict[str, Any] = field(default_factory=dict)  # arrays for --plot


def compensate(rec: Recording, cf: CalibrationFile | None) -> tuple[Recording, list[str]]:
    """The recording with the file's temperature polynomials already subtracted (the pipeline
    applies them before bias and matrix, so the new bias must be estimated after them), and
    notes saying which were applied."""
    if cf is None or rec.temp is None:
        return rec, []
    notes = []
    arrays: dict[str, F64 | None] = {"accel": rec.accel, "gyro": rec.gyro, "mag": rec.mag}
    for name in ("accel", "gyro", "mag"):
        table = cf.sensor(name)
        values = arrays[name]
        poly = None if table is None else sensor_model(table).temp
        if poly is None or values is None:
            continue
        offset, outside = poly.offset(rec.temp)
        arrays[name] = values - offset
        note = f"{name}: the file's temperature polynomial (reference {poly.reference_c:g} degC)"
        note += " applied first"
        if outside.any():
            note += f"; {int(outside.sum())} samples were outside its span and clamped"
        notes.append(note)
    if not notes:
        return rec, []
    accel, gyro = arrays["accel"], arrays["gyro"]
    assert accel is not None and gyro is not None
    return replace(rec, accel=accel, gyro=gyro, mag=arrays["mag"]), notes


# --- reports -------------------------------------------------------------------------------------


def _floats(a: Any) -> Any:
    arr = np.asarray(a, dtype=np.float64)
    return [_floats(x) for x in arr] if arr.ndim > 1 else [float(x) for x in arr]


def fit_report(fit: Fit) -> dict[str, Any]:
    sig = fit.sigma()
    return {
        "parameters": {
            n: {"value": float(v), "sigma": float(s)}
            for n, v, s in zip(fit.names, fit.values, sig, strict=True)
        },
        "covariance": _floats(fit.covariance),
        "residuals": {k: float(v) for k, v in fit.residuals.items()},
    }


def affine_report(est: AffineEstimate) -> dict[str, Any]:
    out: dict[str, Any] = {
        "sensor": est.sensor,
        "procedure": est.procedure,
        "bias": _floats(est.bias),
        "matrix": _floats(est.matrix),
        **fit_report(est.fit),
        "accepted": est.verdict.accepted,
        "reasons": list(est.verdict.reasons),
    }
    extras = {"temperature_c": est.temperature_c, "gravity": est.gravity, "field_t": est.field_t}
    out.update({k: float(v) for k, v in extras.items() if v is not None})
    return out


def temp_report(est: TempEstimate) -> dict[str, Any]:
    return {
        "sensor": est.sensor,
        "procedure": "temp",
        "reference_c": est.reference_c,
        "span_c": list(est.span_c),
        "order": est.order,
        "coefficients": _floats(est.coefficients),
        **fit_report(est.fit),
        "accepted": est.verdict.accepted,
        "reasons": list(est.verdict.reasons),
    }


def _affine_update(
    est: AffineEstimate,
    rec: Recording,
    still: list[StillInterval],
    report: dict[str, Any],
    g_sensitivity: F64 | None = None,
) -> Callable[[CalibrationFile, str], CalibrationFile]:
    """Bias and matrix, and the sensor's white noise measured in the still data (for its ROS 2
    covariances) when there is enough of it; the report says which."""
    sensor = est.sensor
    assert sensor in ("accel", "gyro")
    noise = measured_density(rec, still, sensor, est.matrix)
    if noise is None:
        report["noise"] = {"measured": False, "reason": shortfall(still, rec.rate_hz)}
        return lambda cf, source: with_affine(cf, est, source, g_sensitivity)
    report["noise"] = {
        "measured": True,
        "density": _floats(noise.density),
        "tau_s": noise.tau_s,
        "differences": noise.differences,
        "still_s": noise.still_s,
    }

    def update(cf: CalibrationFile, source: str) -> CalibrationFile:
        return with_noise(with_affine(cf, est, source, g_sensitivity), sensor, noise)

    return update


# --- the procedures ------------------------------------------------------------------------------


def run_accel(
    rec: Recording,
    gravity: float,
    model: Literal["full", "axes"],
    min_s: float = 2.0,
    significance: float = 0.01,
    acceptance: Acceptance | None = None,
    holdout: bool = False,
    compare: CalibrationFile | None = None,
    shots: bool = False,
) -> Outcome:
    """`shots`: each row of `rec` is one still pose (imud/calib/shots.py).
    Raises CalibrationRefused when no estimate can be formed at all. `holdout`: also judge
    the method on still windows it was not fitted to (imud/calib/holdout.py), beside the
    uncalibrated data, the seed's method and `compare`'s accelerometer table."""
    from imud.calib.accel import fit_accel

    check_recording(rec, ("accel",), min_samples=2 if shots else None)
    if shots:
        if holdout or compare is not None:
            raise CalibrationRefused(
                "--holdout needs still windows to split, and a shot list has one reading a "
                "pose: drop --holdout/--compare"
            )
        from imud.calib.shots import fit_accel_shots

        res = fit_accel_shots(rec, gravity, model, acceptance)
    else:
        res = fit_accel(
            rec, gravity, model, min_s=min_s, significance=significance, acceptance=acceptance
        )
    est = res.estimate
    report = affine_report(est)
    report["orientations"] = res.orientations
    report["poses"] = est.fit.details.get("poses", [])
    report["dropped"] = list(res.dropped)
    if res.seed is not None:
        report["seed_up_down"] = {"bias": _floats(res.seed.bias), "scale": _floats(res.seed.scale)}
    if holdout or compare is not None:
        from imud.calib.holdout import accel_holdout

        table = None if compare is None else compare.accel
        transform = None
        if table is not None:
            m = sensor_model(table)
            transform = lambda x: (x - m.bias) @ m.matrix.T  # noqa: E731
        try:
            report["holdout"] = accel_holdout(
                rec, res.intervals, gravity, model, acceptance, transform
            ).to_json()
        except CalibrationRefused as e:  # the evaluation cannot be made; the fit stands
            report["holdout"] = {"unavailable": str(e)}
    reasons = [*res.dropped, *est.verdict.reasons]
    return Outcome(
        "accel",
        est.verdict.accepted,
        reasons,
        report,
        _affine_update(est, rec, [] if shots else res.intervals, report),
        {"poses": report["poses"]},
    )


def run_mag(
    rec: Recording,
    field_t: float | None,
    acceptance: Acceptance | None = None,
    shots: bool = False,
) -> Outcome:
    """`shots`: each row of `rec` is one still pose's reading (imud/calib/mag.py)."""
    from imud.calib.mag import fit_mag

    check_recording(rec, ("mag",), min_samples=2 if shots else None)

    res = fit_mag(rec, field_t, acceptance, shots)
    est = res.estimate
    report = affine_report(est)
    report["coverage"] = {
        "fraction": res.coverage.fraction,
        # a shot list is judged by what its readings determine, not by cells filled
        "required": None if shots else res.coverage.required,
        "cells": res.coverage.cells,
        "missing": list(res.coverage.missing),
    }
    report["seed_min_max"] = {
        "bias": _floats(res.minmax.bias),
        "matrix": _floats(res.minmax.matrix),
    }
    # the figure magnetometer papers and tools quote: std(|m|) / mean(|m|) over the samples
    assert rec.mag is not None  # check_recording refused a recording without it
    m = rec.mag[np.all(np.isfinite(rec.mag), axis=1)]
    report["field_norm_spread"] = {
        "raw": _spread(m),
        "corrected": _spread((m - est.bias) @ est.matrix.T),
        "seed_min_max": _spread((m - res.minmax.bias) @ res.minmax.matrix.T),
    }
    plot = {"raw": rec.mag, "bias": est.bias, "matrix": est.matrix}
    return Outcome(
        "mag",
        est.verdict.accepted,
        list(est.verdict.reasons),
        report,
        lambda cf, source: with_affine(cf, est, source),
        plot,
    )


def _spread(v: F64) -> float:
    norm = np.linalg.norm(v, axis=1)
    return float(norm.std() / norm.mean()) if norm.size else float("nan")


def run_temp(
    rec: Recording, sensors: tuple[Literal["accel", "gyro"], ...], max_order: int
) -> Outcome:
    from imud.calib.temp import fit_temperature

    check_recording(rec, sensors)

    ests = [fit_temperature(rec, s, max_order) for s in sensors]
    accepted = all(e.verdict.accepted for e in ests)
    reasons = [f"{e.sensor}: {r}" for e in ests for r in e.verdict.reasons]

    def update(cf: CalibrationFile, source: str) -> CalibrationFile:
        for e in ests:
            cf = with_temperature(cf, e, source)
        return cf

    report = {"sensors": {e.sensor: temp_report(e) for e in ests}, "accepted": accepted}
    plot = {"temp": rec.temp, "estimates": ests, "accel": rec.accel, "gyro": rec.gyro}
    return Outcome("temp", accepted, reasons, report, update, plot)


def local_gravity(
    gravity: float | None, latitude: float | None, height: float | None
) -> tuple[float, str]:
    """The g a procedure uses, and where it came from (said in the output: the default is up
    to 0.27 % off, and that error lands in the scale factors)."""
    from imud.calib.gravity import normal_gravity

    if gravity is not None:
        if latitude is not None:
            raise ValueError("give --gravity or --latitude/--height, not both")
        return gravity, "given with --gravity"
    if latitude is not None:
        g = normal_gravity(latitude, height or 0.0)
        return g, f"normal gravity at latitude {latitude:g} deg, height {height or 0.0:g} m"
    if height is not None:
        raise ValueError("--height needs --latitude (normal gravity depends on both)")
    return STANDARD_GRAVITY, (
        "standard gravity 9.80665 m/s^2 (local g differs by up to 0.27 %, which lands in the "
        "scale factors: give --latitude/--height or --gravity)"
    )


def _gravity_corrected(rec: Recording, cf: CalibrationFile | None, notes: list[str]) -> Recording:
    """The recording with the file's accelerometer calibration applied (bias and matrix only:
    its temperature term, if any, was applied by `compensate`), when there is one."""
    if cf is None or cf.accel is None:
        return rec
    a = sensor_model(cf.accel)
    notes.append("accelerometer calibration from the file applied to the gravity directions")
    return replace(rec, accel=(rec.accel - a.bias) @ a.matrix.T)


def _gyro_rate(cf: CalibrationFile | None) -> Callable[[F64], F64] | None:
    """A calibration file's gyro correction as (N, 6) [raw gyro, specific force] -> rad/s."""
    if cf is None or cf.gyro is None:
        return None
    m = sensor_model(cf.gyro)
    g = np.zeros((3, 3)) if m.g_sensitivity is None else m.g_sensitivity

    def rate(x: F64) -> F64:
        out: F64 = (x[:, :3] - m.bias - x[:, 3:] @ g.T) @ m.matrix.T
        return out

    return rate


def _bias_estimate(gs: GSensitivity) -> AffineEstimate:
    """The G fit's intercept as the gyro-bias estimate the full fit holds fixed."""
    from imud.calib.estimate import Verdict
    from imud.calib.gyro import BIAS_NAMES

    fit = Fit(tuple(BIAS_NAMES), gs.bias, gs.bias_cov, {}, {})
    return AffineEstimate("gyro", "gyro-bias", gs.bias, np.eye(3), fit, Verdict(True))


def _without_g_sensitivity(
    rec: Recording,
    min_still_s: float,
    significance: float,
    notes: list[str],
    latitude_deg: float | None = None,
) -> tuple[Recording, GSensitivity | None]:
    """The gyro's g-sensitivity from the still poses (imud/calib/gsens.py) and, when the data ask
    for it, the recording with G a taken out of every gyro sample, so the bias and matrix fits
    see the gyro the pipeline will correct."""
    from imud.calib.still import find_still

    poses = find_still(rec, min_s=min_still_s)
    if len(poses) < 6:
        return rec, None
    gs = fit_g_sensitivity(
        np.array([p.gyro for p in poses]),
        np.array([p.gyro_cov for p in poses]),
        np.array([p.accel for p in poses]),
        significance,
        latitude_deg,
    )
    if gs is None or not gs.included:
        return rec, gs
    per_g = np.degrees(np.abs(gs.matrix).max()) * STANDARD_GRAVITY
    notes.append(
        f"g-sensitivity found in the still poses (up to {per_g:.3f} deg/s per g, each "
        f"element +-{np.degrees(gs.matrix_sigma.max()) * STANDARD_GRAVITY:.3f} or better; chi2 "
        f"{gs.chi2_without:.0f} without it, {gs.chi2_with:.0f} with it on {gs.dof_with} dof): "
        "taken out before the fit, written to the file, applied by the daemon"
    )
    return replace(rec, gyro=rec.gyro - rec.accel @ gs.matrix.T), gs


def _fit_full(
    rec: Recording,
    full_turns: bool,
    min_still_s: float,
    latitude_deg: float | None,
    significance: float = 0.01,
    acceptance: Acceptance | None = None,
    bias: AffineEstimate | None = None,
) -> AffineEstimate:
    """The gyro's full fit from the rotations between the recording's still poses."""
    from imud.calib.gyro import fit_gyro_full
    from imud.calib.still import find_still

    poses = find_still(rec, min_still_s)
    return fit_gyro_full(
        rec,
        poses,
        bias,
        full_turns,
        latitude_deg=latitude_deg,
        significance=significance,
        acceptance=acceptance,
    )


def gyro_needs_more(
    rec: Recording,
    full_turns: bool,
    cf: CalibrationFile | None = None,
    min_still_s: float = 2.0,
    latitude_deg: float | None = None,
) -> str | None:
    """For a live capture: what more the gyro fit needs before it can be formed and every part
    of C determined (None: nothing, or the sensor has been still all along, which is a bias
    capture). A capture on a bench goes on until then."""
    from imud.calib.still import CalibrationRefused, check_still

    rec = _gravity_corrected(rec, cf, [])
    try:
        if check_still(rec).still:
            return None
        est = _fit_full(rec, full_turns, min_still_s, latitude_deg)
    except CalibrationRefused as e:
        return str(e)
    weak = est.fit.details.get("undetermined")
    return str(weak) if weak else None


def run_gyro(
    rec: Recording,
    full_turns: bool,
    cf: CalibrationFile | None = None,
    min_still_s: float = 2.0,
    latitude_deg: float | None = None,
    significance: float = 0.01,
    acceptance: Acceptance | None = None,
    holdout: bool = False,
    compare: CalibrationFile | None = None,
) -> Outcome:
    """`holdout`: also judge the fit on rotations it did not see (imud/calib/holdout.py),
    beside the uncalibrated gyro, the seed's bias-only correction and `compare`'s gyro table.
    A still recording gives the bias; one with rotations between still poses gives the bias
    (from the poses) and the full matrix. The file's accelerometer calibration, when there is
    one, corrects the gravity directions first, so the gyro lands in the calibrated frame.
    With the latitude, Earth's rotation is modelled (imud/calib/gyro.py)."""
    from imud.calib.gyro import fit_gyro_bias
    from imud.calib.still import check_still, find_still, interval_stats

    gyro_only = bool(np.isnan(rec.accel).all())  # a still capture needs nothing more
    check_recording(rec, ("gyro",) if gyro_only else ("accel", "gyro"))
    notes: list[str] = []
    rec = rec if gyro_only else _gravity_corrected(rec, cf, notes)
    original = rec  # the accelerometer corrected, the gyro as recorded
    gsens = None
    if acceptance is not None:
        significance = acceptance.significance
    check = check_still(rec, significance)
    if check.still:
        est = fit_gyro_bias(rec, latitude_deg, significance, acceptance)
        still = [interval_stats(rec, 0, rec.n)]
        if gyro_only:
            notes.append(
                "no accelerometer columns: the bias alone, from the gyro (a slow turn during "
                "the capture cannot be seen without gravity's direction, so keep it on a table)"
            )
    elif gyro_only:
        raise CalibrationRefused(
            f"{rec.source or 'the recording'} moved and has no accelerometer columns: the "
            "gyro's matrix is fitted against gravity's directions between still poses, which "
            "only the accelerometer gives; record it too (or record the gyro still for its bias)"
        )
    else:
        poses = find_still(rec, min_s=min_still_s)
        if len(poses) < 2:  # neither a bias capture nor poses with turns between: say both
            raise CalibrationRefused(
                f"{check.reason}; nor does it hold the still poses with turns between them that "
                f"the full gyro fit needs (found {len(poses)})"
            )
        if cf is None or cf.accel is None:
            notes.append(
                "no accelerometer calibration in the file: the raw accelerometer's scale and "
                "misalignment enter the gravity directions the rotations are checked against "
                "(calibrate accel first, into the same file)"
            )
        rec, gsens = _without_g_sensitivity(rec, min_still_s, significance, notes, latitude_deg)
        # with G, the bias is the G fit's intercept, its covariance G's uncertainty included
        # (with the latitude the bias is fitted with Earth's rotation instead)
        bias = None
        if gsens is not None and gsens.included and latitude_deg is None:
            bias = _bias_estimate(gsens)
        still = find_still(rec, min_s=min_still_s)
        est = _fit_full(rec, full_turns, min_still_s, latitude_deg, significance, acceptance, bias)
    report = affine_report(est)
    report["notes"] = notes
    if gsens is not None:
        report["g_sensitivity"] = {
            "included": gsens.included,
            "matrix_rad_s_per_m_s2": _floats(gsens.matrix),
            "sigma_rad_s_per_m_s2": _floats(gsens.matrix_sigma),
            "chi2_without": gsens.chi2_without,
            "chi2_with": gsens.chi2_with,
            "dof_with": gsens.dof_with,
            "p_value": gsens.p_value,
        }
    d = est.fit.details
    keys = ("earth_rate_note", "earth", "earth_removed_rad_s", "earth_remaining_rad_s")
    earth = {k: d[k] for k in keys if k in d}
    if earth:
        report["earth_rotation"] = earth
    if d.get("motions"):
        report["motions"] = d["motions"]
    g = None if gsens is None or not gsens.included else gsens.matrix
    if (holdout or compare is not None) and d.get("motions"):
        from imud.calib.holdout import gyro_holdout

        try:
            report["holdout"] = gyro_holdout(
                original, min_still_s, full_turns, latitude_deg, acceptance, _gyro_rate(compare)
            ).to_json()
        except CalibrationRefused as e:  # the evaluation cannot be made; the fit stands
            report["holdout"] = {"unavailable": str(e)}
    update = _affine_update(est, rec, still, report, g)
    reasons = list(est.verdict.reasons)
    if not est.verdict.accepted and d.get("motions") and (cf is None or cf.accel is None):
        reasons.insert(
            0,
            "no accelerometer calibration in the file, so gravity's directions carry the raw "
            "accelerometer's errors, which the rotations are checked against: calibrate accel "
            "first, into the same --out, then the gyro",
        )
    return Outcome("gyro", est.verdict.accepted, reasons, report, update)
