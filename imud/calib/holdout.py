"""Held-out evaluation of an accelerometer calibration (`imud calibrate accel --holdout`): how
well it does on data it was not fitted to, beside the uncalibrated readings, the seed's six-face
method and any calibration file given with `--compare`.

Every still pose is split in time: a calibration fitted on the first halves of all poses is
judged on their second halves, and one fitted on the second halves on the first (two folds, so
every window is judged once, by a fit that did not see it). The figure is what a user of an
accelerometer cares about at rest: |a| - g, RMS over the judged windows. A window's mean keeps
the noise of half a pose; the same windows judge every method, so the comparison is fair
whatever that noise is.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
import numpy.typing as npt

from imud.calib.acceptance import Acceptance
from imud.calib.recording import Recording
from imud.calib.still import CalibrationRefused, StillInterval, interval_stats

F64 = npt.NDArray[np.float64]
MIN_GYRO_POSES = 12  # two halves of at least five rotations, the full fit's least
Transform = Callable[[F64], F64]  # (n, 3) readings -> (n, 3) corrected


@dataclass
class HoldoutReport:
    """RMS over the held-out windows (accelerometer: |a| - g, m/s^2) or rotations (gyro: the
    gravity direction carried, degrees), by method; None where a method had nothing to say (no
    six faces for the seed in a fold). `windows`: how many were judged."""

    windows: int
    unit: str = "m/s^2"
    rms: dict[str, float | None] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    at_rest: dict[str, float | None] | None = None  # gyro: RMS |mean rate| in held-out poses

    def to_json(self) -> dict[str, object]:
        out: dict[str, object] = {
            "windows": self.windows, "unit": self.unit, "rms": self.rms, "notes": self.notes
        }  # fmt: skip
        if self.at_rest is not None:
            out["at_rest_deg_h"] = self.at_rest
        return out


def _halves(poses: list[StillInterval]) -> tuple[list[int], list[int], list[int]]:
    starts = [p.start for p in poses]
    mids = [(p.start + p.end) // 2 for p in poses]
    ends = [p.end for p in poses]
    return starts, mids, ends


def _norm_errors(readings: F64, transform: Transform, gravity: float) -> F64:
    out: F64 = np.linalg.norm(transform(readings), axis=1) - gravity
    return out


def accel_holdout(
    rec: Recording,
    poses: list[StillInterval],
    gravity: float,
    model: Literal["full", "axes"],
    acceptance: Acceptance | None = None,
    compare: Transform | None = None,
) -> HoldoutReport:
    """Two folds over the halves of `poses` (see the module docstring). Raises
    CalibrationRefused when a half cannot be fitted (too few poses)."""
    from imud.calib.accel import fit_accel_intervals

    starts, mids, ends = _halves(poses)
    halves = [list(zip(starts, mids, strict=True)), list(zip(mids, ends, strict=True))]
    errors: dict[str, list[float]] = {"calibrated": [], "uncalibrated": [], "seed": []}
    if compare is not None:
        errors["compare"] = []
    report = HoldoutReport(windows=0)
    seed_missing = False
    for fit_half, judge_half in ((halves[0], halves[1]), (halves[1], halves[0])):
        fit = [interval_stats(rec, a, b) for a, b in fit_half if b - a >= 2]
        try:
            res = fit_accel_intervals(fit, gravity, model, acceptance=acceptance)
        except CalibrationRefused as e:
            raise CalibrationRefused(f"--holdout: half of every pose is too little: {e}") from None
        est = res.estimate
        means = np.array([rec.accel[a:b].mean(axis=0) for a, b in judge_half])
        report.windows += means.shape[0]

        def calibrated(m: F64, c: F64 = est.matrix, b: F64 = est.bias) -> F64:
            out: F64 = (m - b) @ c.T
            return out

        errors["calibrated"] += _norm_errors(means, calibrated, gravity).tolist()
        errors["uncalibrated"] += _norm_errors(means, lambda m: m, gravity).tolist()
        if res.seed is None:
            seed_missing = True
        else:
            seed = res.seed

            def seeded(m: F64, s: F64 = seed.scale, b: F64 = seed.bias) -> F64:
                out: F64 = (m - b) / s
                return out

            errors["seed"] += _norm_errors(means, seeded, gravity).tolist()
        if compare is not None:
            errors["compare"] += _norm_errors(means, compare, gravity).tolist()
    for name, errs in errors.items():
        report.rms[name] = float(np.sqrt(np.mean(np.square(errs)))) if errs else None
    if seed_missing:
        report.rms["seed"] = None
        report.notes.append("the seed's six-face method needs all six faces in each half")
    return report


def _carried_error(
    rec: Recording, before: StillInterval, after: StillInterval, rate: Transform
) -> float:
    """Degrees between the gravity direction `rate` (corrected gyro of samples, given their
    corrected specific force) carries over the rotation from `before` to `after`, and the one
    the accelerometer sees in `after`."""
    from imud import rotations as so3

    sel = np.arange(before.end - 1, after.start)
    dt = (rec.t_ns[sel + 1] - rec.t_ns[sel]).astype(np.float64) * 1e-9
    w = rate(np.concatenate([rec.gyro[sel], rec.accel[sel]], axis=1))
    e, _ = so3.exp_and_jr(w * dt[:, None])
    turn = so3.cumulative_product(e)[-1]
    u0 = before.accel / np.linalg.norm(before.accel)
    u1 = after.accel / np.linalg.norm(after.accel)
    cos = float(np.clip((turn.T @ u0) @ u1, -1.0, 1.0))
    return float(np.degrees(np.arccos(cos)))


def gyro_holdout(
    rec: Recording,
    min_still_s: float,
    full_turns: bool,
    latitude_deg: float | None,
    acceptance: Acceptance | None,
    compare: Transform | None = None,
) -> HoldoutReport:
    """The recording's rotations split in time (the first half of its still poses and the
    rotations between them, and the second): each half's calibration, fitted as `imud calibrate
    gyro` fits it (g-sensitivity included when found), judged on the other half's rotations by
    the gravity direction it carries across each, in degrees; beside the uncalibrated gyro and
    the seed's bias-only correction (the still poses' mean gyro, no matrix). `rec`'s
    accelerometer must already be calibrated. `compare`: (N, 6) [gyro, specific force] -> rad/s."""
    from imud.calib.gsens import fit_g_sensitivity
    from imud.calib.gyro import fit_gyro_full
    from imud.calib.still import find_still

    poses = find_still(rec, min_s=min_still_s)
    if len(poses) < MIN_GYRO_POSES:
        raise CalibrationRefused(
            f"--holdout: {len(poses)} still poses; splitting the rotations between them in two "
            f"halves a fit each needs at least {MIN_GYRO_POSES} (five rotations a half)"
        )
    half = len(poses) // 2
    # disjoint halves: the rotation between them is judged by neither fit, and no pose is seen
    # by both
    folds = [(poses[:half], poses[half:]), (poses[half:], poses[:half])]
    acceptance = acceptance or Acceptance()
    errors: dict[str, list[float]] = {"calibrated": [], "uncalibrated": [], "seed": []}
    if compare is not None:
        errors["compare"] = []
    rest: dict[str, list[float]] = {k: [] for k in errors}
    report = HoldoutReport(windows=0, unit="deg")
    for fit_poses, judge_poses in folds:
        gs = fit_g_sensitivity(
            np.array([p.gyro for p in fit_poses]),
            np.array([p.gyro_cov for p in fit_poses]),
            np.array([p.accel for p in fit_poses]),
            acceptance.significance,
            latitude_deg,
        )
        g = gs.matrix if gs is not None and gs.included else np.zeros((3, 3))
        fitted = rec if not g.any() else replace(rec, gyro=rec.gyro - rec.accel @ g.T)
        try:
            est = fit_gyro_full(
                fitted, fit_poses, None, full_turns, latitude_deg=latitude_deg,
                acceptance=acceptance,
            )  # fmt: skip
        except CalibrationRefused as e:
            raise CalibrationRefused(f"--holdout: half of the rotations are too few: {e}") from None
        seed_bias = np.mean([p.gyro for p in fit_poses], axis=0)

        def calibrated(x: F64, c: F64 = est.matrix, b: F64 = est.bias, gm: F64 = g) -> F64:
            out: F64 = (x[:, :3] - b - x[:, 3:] @ gm.T) @ c.T
            return out

        def seeded(x: F64, b: F64 = seed_bias) -> F64:
            out: F64 = x[:, :3] - b
            return out

        methods: dict[str, Transform] = {
            "calibrated": calibrated,
            "uncalibrated": lambda x: x[:, :3],
            "seed": seeded,
        }
        if compare is not None:
            methods["compare"] = compare
        for before, after in itertools.pairwise(judge_poses):
            if after.start <= before.end - 1:
                continue
            report.windows += 1
            for name, rate in methods.items():
                errors[name].append(_carried_error(rec, before, after, rate))
        # at rest: a held-out pose's corrected mean rate (Earth's 15 deg/h at most, and noise)
        for p in judge_poses:
            x = np.concatenate([p.gyro, p.accel])[None, :]
            for name, rate in methods.items():
                rest[name].append(float(np.linalg.norm(rate(x)[0])) * 180 / np.pi * 3600)
    for name, errs in errors.items():
        report.rms[name] = float(np.sqrt(np.mean(np.square(errs)))) if errs else None
    report.at_rest = {
        name: float(np.sqrt(np.mean(np.square(v)))) if v else None for name, v in rest.items()
    }
    return report
