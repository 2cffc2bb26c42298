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
# one sample beyond what any IMU reads is a corrupt line, not a reading: it would enter every
# fit (the gyro's g-sensitivity term applied to 1e30 m/s^2); twice the widest ranges parts
# offer (a 200 g accelerometer, a 4000 deg/s gyro, a 1 mT magnetometer)
_SAMPLE_LIMIT = {"accel": 4000.0, "gyro": 140.0, "mag": 2e-3}
_UNIT = {"accel": "m/s^2", "gyro": "rad/s", "mag": "T"}


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
    for sensor in ("accel", "gyro", "mag"):  # every column a fit reads, not only its own
        x = {"accel": rec.accel, "gyro": rec.gyro, "mag": rec.mag}[sensor]
        if x is None or np.isnan(x).all():
            continue
        with np.errstate(invalid="ignore"):
            beyond = np.flatnonzero(np.nanmax(np.abs(x), axis=1) > _SAMPLE_LIMIT[sensor])
        if beyond.size:
            k = int(beyond[0])
            t = float(rec.t_ns[k] - rec.t_ns[0]) * 1e-9
            # a few such samples are corrupt lines; many are a unit the file was misread in
            cause = (
                "a corrupt line; fix or drop it"
                if beyond.size <= max(3, rec.n // 1000)
                else _MAGNITUDE[sensor][3]
            )
            raise CalibrationRefused(
                f"{where}: {beyond.size} sample(s) read beyond what any IMU reads (up to "
                f"{_SAMPLE_LIMIT[sensor]:g} {_UNIT[sensor]} on the {_NAMES[sensor]}), the first "
                f"sample {k + 1} at {t:.3f} s ({np.abs(x[k]).max():.4g}): {cause}"
            )
