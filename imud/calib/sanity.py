"""What a recording must be before any estimator looks at it, checked once, each failure a
`CalibrationRefused` naming the column, the value and the fix.

The CSV reader already refuses what cannot be numbers (NaN, infinities, time that does not
increase); this is what finite numbers can still get wrong: too few samples, a column that never
changes (a disconnected sensor, a column of zeros), and values whose size says the units are
wrong (raw counts, g or deg/s read as SI). The bounds are wide: a working sensor anywhere near
the Earth, held still or turned by hand, is far inside them.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Literal

import numpy as np

from imud.calib.recording import Recording
from imud.calib.still import CalibrationRefused
from imud.units import STANDARD_GRAVITY

Sensor = Literal["accel", "gyro", "mag"]
MIN_SAMPLES = 10
# the median magnitude a sensor at rest or turned by hand can have, and the units flag to give
_MAGNITUDE: dict[str, tuple[float, float, str, str]] = {
    # sensor: (low, high, unit, the fix)
    "accel": (0.3 * STANDARD_GRAVITY, 4.0 * STANDARD_GRAVITY, "m/s^2",
              "raw counts, or g read as m/s^2? give --accel-units (or scale the column)"),
    "gyro": (0.0, 35.0, "rad/s",  # 2000 deg/s: the widest MEMS range
             "deg/s read as rad/s, or raw counts? give --gyro-units (or scale the column)"),
    "mag": (1e-6, 1e-3, "T",
            "uT or gauss read as tesla, or raw counts? give --mag-units (or scale the column)"),
}  # fmt: skip
_NAMES = {"accel": "accelerometer", "gyro": "gyroscope", "mag": "magnetometer"}


def check_recording(
    rec: Recording, sensors: Iterable[Sensor], min_samples: int | None = None
) -> None:
    """Refuse `rec` for a calibration of `sensors` (the columns it reads) when it cannot be one.
    `min_samples`: fewer is refused (default MIN_SAMPLES; a shot list's rows are poses)."""
    where = rec.source or "the recording"
    if rec.n < (MIN_SAMPLES if min_samples is None else min_samples):
        raise CalibrationRefused(
            f"{where} has {rec.n} sample{'s' if rec.n != 1 else ''}; a calibration needs a "
            "recording of seconds to minutes (see docs/calibration.md for each procedure)"
        )
    for sensor in sensors:
        x = {"accel": rec.accel, "gyro": rec.gyro, "mag": rec.mag}[sensor]
        if x is None:
            raise CalibrationRefused(f"{where} has no {_NAMES[sensor]} columns")
        for axis, name in enumerate("xyz"):
            col = x[:, axis]
            if float(col.max()) == float(col.min()):
                raise CalibrationRefused(
                    f"{where}: the {_NAMES[sensor]}'s {name} axis reads {float(col[0]):g} in "
                    f"every one of its {rec.n} samples: a disconnected sensor, a column of "
                    "zeros, or the wrong column; check the recording"
                )
        lo, hi, unit, fix = _MAGNITUDE[sensor]
        median = float(np.median(np.linalg.norm(x, axis=1)))
        if not lo <= median <= hi:
            raise CalibrationRefused(
                f"{where}: the {_NAMES[sensor]}'s median magnitude is {median:.4g} {unit}, "
                f"outside what it can read here ({lo:.3g}-{hi:.3g} {unit}): {fix}"
            )
