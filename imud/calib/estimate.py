"""What every procedure returns: the estimate in the form the pipeline applies, its parameters
with their covariance, residual statistics, and a verdict with its reasons.

Affine sensor model (accel, gyro, magnetometer): corrected = matrix @ (raw - bias).
Temperature model: raw_at_reference = raw - sum_k coefficients[k-1] * (T - reference_c)**k.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
Sensor = Literal["accel", "gyro", "mag"]


@dataclass(frozen=True)
class Verdict:
    """accepted: the estimate may be written. reasons: why not (or, when accepted, warnings a
    person should still read). Each reason is one sentence naming the cause and what to do."""

    accepted: bool
    reasons: tuple[str, ...] = ()


@dataclass(frozen=True)
class Fit:
    """Parameters by name with their covariance (same order), and residual statistics.

    residuals: at least "rms" (in the sensor's SI unit), "chi2", "dof", "p_value" (chance of a
    chi2 this large if the model were right and the noise as measured), "noise" (the per-sample
    or per-mean noise the test used); any procedure-specific extras (per-pose residuals,
    coverage) go in `details`."""

    names: tuple[str, ...]
    values: F64
    covariance: F64
    residuals: dict[str, float]
    details: dict[str, Any] = field(default_factory=dict)

    def sigma(self) -> F64:
        out: F64 = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        return out


@dataclass(frozen=True)
class AffineEstimate:
    """An accel, gyro or magnetometer calibration: corrected = matrix @ (raw - bias)."""

    sensor: Sensor
    procedure: str  # e.g. "accel-9" (upper-triangular + bias, gravity norm), "accel-axes",
    #                 "gyro-bias", "gyro-full", "mag-ellipsoid"
    bias: F64  # (3,) in the sensor's SI unit (tesla for mag)
    matrix: F64  # (3, 3) dimensionless
    fit: Fit
    verdict: Verdict
    temperature_c: float | None = None  # mean temperature of the data it came from
    gravity: float | None = None  # m/s^2 used (accel, gyro-full)
    field_t: float | None = None  # fitted field magnitude (mag), tesla


@dataclass(frozen=True)
class TempEstimate:
    """Bias against temperature for one sensor: bias(T) - bias(reference_c) =
    sum_k coefficients[k-1] * (T - reference_c)**k, per axis; valid on span_c."""

    sensor: Sensor
    reference_c: float
    coefficients: F64  # (order, 3)
    span_c: tuple[float, float]
    fit: Fit
    verdict: Verdict

    @property
    def order(self) -> int:
        return int(self.coefficients.shape[0])
