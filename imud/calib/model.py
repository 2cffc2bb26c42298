"""The sensor models the pipeline applies, as pure functions on NumPy batches.

Per sensor (accelerometer, gyroscope, magnetometer):

    corrected = C @ (raw - b - p(T))        p(T) = sum_k c_k (T - T_ref)^k,  k = 1..3

and for the gyroscope, when its calibration found g-sensitivity (imud/calib/gsens.py), the bias
also follows the specific force: raw - b - p(T) - G a, with a the sample's corrected
accelerometer reading (a delta angle takes the delta velocity over its period).

C undoes scale and misalignment (or soft iron), b is the bias (or hard iron) at T_ref, and p is
the bias's temperature polynomial, without a constant term (that is b). Outside the span the
polynomial was fitted on, T is clamped to the span's edge and the sample is flagged: a cubic
extrapolated past its data can be wildly wrong, and the consumer must know the correction there
is the edge value, not a fitted one.

Delta channels (the rotation or velocity change over one sample period, dt) get the same model
with the offsets scaled by dt, so a chip's gyro and its delta angles stay consistent.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from imud.channels import Channel

F64 = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class TempPoly:
    reference_c: float
    coefficients: F64  # (order, 3): row k-1 multiplies (T - reference_c)^k
    span_c: tuple[float, float]

    def offset(self, temp_c: F64) -> tuple[F64, Mask]:
        """p(T) per sample (N, 3), with T clamped to the span; and where T was outside it
        (or unknown: NaN, which leaves the term out)."""
        lo, hi = self.span_c
        unknown = ~np.isfinite(temp_c)  # no valid temperature yet: no term, and flagged
        outside = (temp_c < lo) | (temp_c > hi) | unknown
        x = np.where(unknown, 0.0, np.clip(temp_c, lo, hi) - self.reference_c)
        acc = np.zeros((x.shape[0], 3))
        for c in self.coefficients[::-1]:  # Horner, without the constant term
            acc = (acc + c) * x[:, None]
        return acc, outside


@dataclass(frozen=True)
class SensorModel:
    bias: F64  # (3,)
    matrix: F64  # (3, 3)
    temp: TempPoly | None = None
    g_sensitivity: F64 | None = None  # (3, 3) rad/s per m/s^2, gyroscope only


@dataclass(frozen=True)
class CalibrationModel:
    """What one device's calibration file says, ready to apply."""

    path: Path
    accel: SensorModel | None = None
    gyro: SensorModel | None = None
    mag: SensorModel | None = None

    def sensor(self, name: str) -> SensorModel | None:
        return {"accel": self.accel, "gyro": self.gyro, "mag": self.mag}[name]


# which sensor model corrects which channel, and whether the channel is a per-sample delta
_TARGETS: tuple[tuple[Channel, str, bool], ...] = (
    (Channel.ACCEL, "accel", False),
    (Channel.GYRO, "gyro", False),
    (Channel.MAG, "mag", False),
    (Channel.DELTA_VELOCITY, "accel", True),
    (Channel.DELTA_ANGLE, "gyro", True),
)


def fill_temperature(
    temp: F64 | None, n: int, last: float | None
) -> tuple[F64 | None, float | None]:
    """Temperature for every sample: a NaN (the chip marked it invalid) takes the last valid
    value before it, carried across batches in `last`. None when none is known yet."""
    if temp is None:
        return (None if last is None else np.full(n, last)), last
    if not np.isnan(temp).any():
        return temp, (float(temp[-1]) if n else last)
    ok = ~np.isnan(temp)
    if not ok.any():
        return (None if last is None else np.full(n, last)), last
    idx = np.where(ok, np.arange(n), -1)
    np.maximum.accumulate(idx, out=idx)
    first = np.full(n, np.nan if last is None else last)
    filled = np.where(idx >= 0, temp[np.maximum(idx, 0)], first)
    return filled, float(temp[ok][-1])


def apply(
    cal: CalibrationModel,
    si: dict[Channel, F64],
    temp_c: F64 | None,
    dt_s: float,
) -> tuple[dict[Channel, F64], Mask | None]:
    """Corrected channels (new arrays; `si` is untouched) and, per sample, whether a temperature
    correction was clamped at its span's edge (None when no sample was, or none applies).

    `temp_c`: the temperature of each sample (see `fill_temperature`), None when unknown: then
    temperature terms are left out and every sample they would apply to is flagged."""
    out = dict(si)
    flagged: Mask | None = None
    offsets: dict[str, F64 | npt.NDArray[np.float64]] = {}
    for ch, name, delta in _TARGETS:
        values = si.get(ch)
        model = cal.sensor(name)
        if values is None or model is None:
            continue
        off = offsets.get(name)
        if off is None:
            off = model.bias
            if model.temp is not None:
                if temp_c is None:
                    out_of_span = np.ones(values.shape[0], dtype=bool)
                else:
                    p, out_of_span = model.temp.offset(temp_c)
                    off = p + model.bias
                if out_of_span.any():
                    flagged = out_of_span if flagged is None else flagged | out_of_span
            offsets[name] = off
        total = off * dt_s if delta else off
        if model.g_sensitivity is not None:
            force = _specific_force(out, delta, dt_s)
            if force is not None:
                g_term = force @ model.g_sensitivity.T
                total = total + (g_term * dt_s if delta else g_term)
        out[ch] = (values - total) @ model.matrix.T
    return out, flagged


def _specific_force(out: dict[Channel, F64], delta: bool, dt_s: float) -> F64 | None:
    """The corrected specific force of each sample, for the gyro's g-sensitivity term: the
    accelerometer (for a delta angle, its delta velocity over the period when the chip gives
    one); None when the batch has neither."""
    if delta and Channel.DELTA_VELOCITY in out and dt_s > 0:
        return out[Channel.DELTA_VELOCITY] / dt_s
    return out.get(Channel.ACCEL)
