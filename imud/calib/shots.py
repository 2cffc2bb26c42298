"""Shot lists: a recording of one reading a pose (`--shots`), as a tool that logs a reading on
a button press writes them: no stream, so no noise can be measured within a pose.

Each row is a still pose. The accelerometer fit runs on them as on any poses, first with a
nominal noise, then again with the noise the residuals themselves show (their RMS over the
degrees of freedom), so the parameters' uncertainty is the data's. With the noise taken from the
residuals no test can separate noise from model error: the calibration is accepted when that
residual RMS is within the tolerance (`--tolerance-mg`, the same defaults as a stream's model
error), and refused beyond it naming the worst reading.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, Literal

import numpy as np
import numpy.typing as npt

from imud.calib.acceptance import MG, Acceptance, Tolerance
from imud.calib.estimate import Verdict
from imud.calib.recording import Recording
from imud.calib.still import CalibrationRefused, StillInterval

if TYPE_CHECKING:
    from imud.calib.accel import AccelResult

F64 = npt.NDArray[np.float64]
NOMINAL_SIGMA = 1e-3  # m/s^2, the first pass's noise: only its ratio to the residuals matters


def shot_poses(rec: Recording, sigma: float) -> list[StillInterval]:
    """Each row a still pose whose mean has noise `sigma` per axis."""
    nan3 = np.full((3, 3), np.nan)
    return [
        StillInterval(
            start=k,
            end=k + 1,
            t0_s=float(rec.t_ns[k] - rec.t_ns[0]) * 1e-9,
            duration_s=0.0,
            accel=rec.accel[k],
            gyro=rec.gyro[k],
            accel_cov=np.eye(3) * sigma * sigma,
            gyro_cov=nan3,
        )
        for k in range(rec.n)
    ]


def fit_accel_shots(
    rec: Recording,
    gravity: float,
    model: Literal["full", "axes"],
    acceptance: Acceptance | None = None,
) -> AccelResult:
    """The accelerometer calibration of a shot list (an `AccelResult`); raises
    CalibrationRefused as a stream's fit does (too few poses, undetermined parameters)."""
    from imud.calib.accel import fit_accel_intervals

    acceptance = acceptance or Acceptance()
    first = fit_accel_intervals(
        shot_poses(rec, NOMINAL_SIGMA), gravity, model, acceptance=acceptance
    )
    res = first.estimate.fit.residuals
    per_pose = 1 if model == "full" else 3
    n_res = per_pose * len(first.intervals)
    if res["dof"] <= 0:
        return first  # exact: its own verdict refuses it, untestable
    sigma = float(res["rms"]) * math.sqrt(n_res / res["dof"])
    if not sigma > 0:
        raise CalibrationRefused("the shot list's readings fit exactly: they cannot be real ones")
    second = fit_accel_intervals(shot_poses(rec, sigma), gravity, model, acceptance=acceptance)
    est = second.estimate
    kind = Tolerance.ACCEL_FULL if model == "full" else Tolerance.ACCEL_AXES
    tolerance = acceptance.tolerance_for(kind)
    reasons = [r for r in est.verdict.reasons if "model error" not in r]
    ok = est.verdict.accepted
    rms = float(est.fit.residuals["rms"])
    if rms > tolerance:
        poses = est.fit.details.get("poses", [])
        worst = max(range(len(poses)), key=lambda k: abs(poses[k]["residual"])) if poses else 0
        ok = False
        reasons.insert(
            0,
            f"a shot list's residuals are {rms / MG:.2f} mg RMS, more than the tolerance of "
            f"{tolerance / MG:g} mg ({acceptance.source(kind)}): the worst is reading "
            f"{worst + 1} (line order); a reading taken while moving, or the wrong gravity",
        )
    else:
        reasons.append(
            f"a shot list (one reading a pose): its noise is taken from the residuals, "
            f"{rms / MG:.2f} mg RMS, within the tolerance of {tolerance / MG:g} mg "
            f"({acceptance.source(kind)})"
        )
    return replace(second, estimate=replace(est, verdict=Verdict(ok, tuple(reasons))))
