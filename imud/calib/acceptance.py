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

from collections.abc import Callable
from dataclasses import dataclass

from imud.calib.stats import chi2_sf
from imud.calib.still import CalibrationRefused

# default tolerances on the model-error floor, m/s^2 (accelerometer); why each in the docstring
# of `Acceptance.tolerance_for`
MG = 9.80665e-3
ACCEL_FULL_TOLERANCE = 5.0 * MG
ACCEL_AXES_TOLERANCE = 17.5 * MG  # per axis: ~1 deg a component, up to ~1.7 deg a pose
MAG_TOLERANCE_FRACTION = 0.03  # of the field: about 1.7 deg of heading error


@dataclass(frozen=True)
class Acceptance:
    """How an estimate is judged: `strict` the pure chi-squared test at `significance`; else the
    model-error floor against `tolerance` (None: the sensor's and model's default)."""

    strict: bool = False
    significance: float = 0.01
    tolerance: float | None = None

    def tolerance_for(self, default: float) -> float:
        """The tolerance in the sensor's SI unit. The accelerometer's defaults: 5 mg for the
        gravity-norm model (consumer MEMS calibrated on a table leave 1-3 mg; more is a pose
        that moved, drift or a wrong g), 17.5 mg (about 1 deg of pose error) for the six-face
        model, which also counts how far each pose is from its face."""
        return default if self.tolerance is None else self.tolerance


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
