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

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import numpy.typing as npt

from imud.calib.acceptance import Acceptance
from imud.calib.recording import Recording
from imud.calib.still import CalibrationRefused, StillInterval, interval_stats

F64 = npt.NDArray[np.float64]
Transform = Callable[[F64], F64]  # (n, 3) readings -> (n, 3) corrected


@dataclass
class HoldoutReport:
    """|a| - g RMS (m/s^2) over the held-out windows, by method; None where a method had
    nothing to say (no six faces for the seed in a fold)."""

    windows: int
    rms: dict[str, float | None] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, object]:
        return {"windows": self.windows, "rms_m_s2": self.rms, "notes": self.notes}


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
