"""Accepting a calibration made on a real sensor: the residuals as noise plus a model-error floor.

A pure chi-squared test asks whether the residuals are white noise of the size measured. Real
recordings never are: a pose a fraction of a degree off its face, a bias that drifts between
poses, a sensor a little non-linear, each leaves a residual that no noise estimate covers, and
ten seconds of averaging makes the noise so small that any of them fails the test. So each
residual is taken as noise plus an independent model error of one common size s, and s is the
value at which the residuals are as large as that says (the method of moments, as a
random-effects meta-analysis estimates its between-study variance, DerSimonian & Laird 1986):

    sum_k r_k^T (C_k + s^2 I)^-1 r_k = dof,

and s = 0 when the residuals pass the chi-squared test as they are (Cochran's test of
heterogeneity: a floor is estimated only where the noise alone is refused, so the data a right
model fits keep the Cramer-Rao bound).

s is reported in physical units, the parameters' covariance is recomputed with it (their
uncertainty then includes the model error), and the calibration is accepted when s is within a
tolerance the user can set, with a default per sensor named in the output. `--strict` keeps the
pure noise test for a lab set-up (a precision rig, a thermally settled sensor).

What a tolerance bounds: s is the model error on one component of a residual. The gravity-norm
accelerometer fit has one a pose (the norm); the six-face fit three (a pose's misfit vector, up to
sqrt(3) s: about 1.7 deg of pose error at the 17.5 mg default); the gyro's rotations two (the
carried gravity direction's error, up to sqrt(2) s); the magnetometer one (the field's norm).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

from imud.calib.stats import chi2_sf
from imud.calib.still import CalibrationRefused

MG = 9.80665e-3
DPH = math.radians(1.0) / 3600.0  # a degree an hour, rad/s


class Grade(StrEnum):
    """A sensor's class, which sets the default tolerances: a consumer MEMS part (phones,
    hobby boards), an industrial one (ADIS-class, bias stability of a few deg/h), a tactical
    one (STIM-class, under 1 deg/h). A chip says its own (ChipSpec.grade); --grade overrides."""

    CONSUMER = "consumer"
    INDUSTRIAL = "industrial"
    TACTICAL = "tactical"


class Tolerance(StrEnum):
    """What a model-error floor is measured on, each with its option and unit."""

    ACCEL_FULL = "accel"  # a pose's gravity norm, m/s^2
    ACCEL_AXES = "accel-axes"  # each component of a six-face pose's misfit, m/s^2
    GYRO_ROTATION = "gyro-rotation"  # each component of a rotation's carried gravity, rad
    GYRO_BIAS = "gyro-bias"  # the still poses' gyro means (with the latitude), rad/s
    MAG = "mag"  # the field's norm, as a fraction of the field


# The defaults, per grade, in SI (MAG: a fraction of the fitted field). The accelerometer's
# 5 mg: consumer MEMS calibrated on a table leave 1-3 mg, more is a pose that moved, drift or a
# wrong g; better parts hold their calibration to 1-2 mg and below. The six-face model counts
# how far each pose is from its face (about 1 deg at 17.5 mg), the rotations how far a hand
# moved a pose (1 deg): the set-up's, whatever the part. The gyro's still poses scatter by the
# bias's drift over the session: 0.1 deg/s for a consumer part, its bias instability's order for
# better ones. The magnetometer's 3 % (about 1.7 deg of heading) is the room's, not the part's.
DEFAULTS: dict[Tolerance, dict[Grade, float]] = {
    Tolerance.ACCEL_FULL: {Grade.CONSUMER: 5 * MG, Grade.INDUSTRIAL: 2 * MG, Grade.TACTICAL: MG},
    Tolerance.ACCEL_AXES: dict.fromkeys(Grade, 17.5 * MG),
    Tolerance.GYRO_ROTATION: dict.fromkeys(Grade, math.radians(1.0)),
    Tolerance.GYRO_BIAS: {
        Grade.CONSUMER: 360 * DPH,
        Grade.INDUSTRIAL: 100 * DPH,
        Grade.TACTICAL: 10 * DPH,
    },
    Tolerance.MAG: dict.fromkeys(Grade, 0.03),
}
OPTIONS = {
    Tolerance.ACCEL_FULL: "--tolerance-mg",
    Tolerance.ACCEL_AXES: "--tolerance-mg",
    Tolerance.GYRO_ROTATION: "--tolerance-deg",
    Tolerance.GYRO_BIAS: "--tolerance-dph",
    Tolerance.MAG: "--tolerance-ut",
}


@dataclass(frozen=True)
class Acceptance:
    """How an estimate is judged: `strict` the pure chi-squared test at `significance`; else the
    model-error floor against `tolerance` (the main residual's, in SI; None: the grade's
    default) and, for the gyro's still poses, `bias_tolerance` (rad/s)."""

    strict: bool = False
    significance: float = 0.01
    tolerance: float | None = None
    grade: Grade = Grade.CONSUMER
    bias_tolerance: float | None = None

    def _given(self, kind: Tolerance) -> float | None:
        return self.bias_tolerance if kind is Tolerance.GYRO_BIAS else self.tolerance

    def tolerance_for(self, kind: Tolerance, scale: float = 1.0) -> float:
        """The tolerance in the sensor's SI unit (`scale`: what a fractional default is of)."""
        given = self._given(kind)
        return DEFAULTS[kind][self.grade] * scale if given is None else given

    def source(self, kind: Tolerance) -> str:
        """Where the tolerance came from, for the output: the option, or the grade's default."""
        if self._given(kind) is not None:
            return OPTIONS[kind]
        return f"the {self.grade}-grade default; {OPTIONS[kind]}"


def model_error_floor(
    chi2_at: Callable[[float], float], dof: float, scale: float, significance: float = 0.01
) -> float:
    """s such that chi2_at(s^2) = dof; 0 when the residuals are consistent with the noise alone
    (chi2_at(0) passes the chi-squared test at `significance`), so data a right model fits keep
    their parameters' covariance at the Cramer-Rao bound. `chi2_at` falls as s^2 grows;
    `scale` is a size of the residuals (their RMS) that bounds s from above."""
    if dof <= 0 or chi2_sf(chi2_at(0.0), dof) >= significance:
        return 0.0
    lo, hi = 0.0, max(scale, 1e-300) ** 2
    while chi2_at(hi) > dof:  # the bound doubles until it brackets the root
        hi *= 4.0
        if not hi < 1e300:  # no finite model error explains them: residuals that are no numbers
            raise CalibrationRefused(
                "the residuals are not finite numbers: the fit diverged; check the recording"
            )
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if chi2_at(mid) > dof:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-12 * hi:
            break
    return float((0.5 * (lo + hi)) ** 0.5)
