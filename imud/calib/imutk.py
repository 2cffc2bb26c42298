"""imu_tk's recordings: a pair of text files, accelerometer and gyroscope apart, each line
`t x y z` (time in seconds, three raw counts), whitespace-separated, no header (imu_tk's
"Matlab ASCII" files, e.g. its own test data `xsens_acc.mat`, `xsens_gyro.mat`).

The counts become SI with the nominal scale the user states (`--accel-counts 414,32768`: counts
per m/s^2 and the zero's count; `--gyro-counts` per rad/s), so the calibration imud writes maps
the nominal-scale SI reading to the calibrated one, like every other imud calibration (a
calibration of counts would be the same fit with the scale folded in).

Every refusal is an `ImuTkError` naming the file, the line and what to do.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt

from imud.calib.csvio import AccelUnits, GyroUnits, unit_problems
from imud.calib.recording import Recording
from imud.units import STANDARD_GRAVITY

F64 = npt.NDArray[np.float64]


class ImuTkError(ValueError):
    pass


def is_imu_tk(path: Path) -> bool:
    """The file's first non-empty line is four numbers and no comma: imu_tk's format."""
    try:
        with open(path, "rb") as f:
            for raw in f:
                line = raw.decode("ascii", "replace").strip()
                if not line:
                    continue
                parts = line.split()
                return "," not in line and len(parts) == 4 and all(map(_number, parts))
    except OSError:
        return False
    return False


def _number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def parse_counts(text: str, what: str) -> tuple[float, float]:
    """`--accel-counts 414,32768` (counts per unit, and the count that reads zero; 0 when
    left out) -> (scale, zero). Raises ImuTkError naming the option."""
    parts = text.split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) not in (1, 2) or not all(math.isfinite(v) for v in values) or values[0] <= 0:
        raise ImuTkError(
            f"--{what}-counts {text!r}: give counts per unit and, if the sensor's zero is not "
            f"count 0, that count, e.g. --{what}-counts 414,32768"
        )
    return values[0], values[1] if len(values) == 2 else 0.0


def _read(path: Path) -> tuple[F64, npt.NDArray[np.int64]]:
    """The file's rows (n, 4) and each row's line number."""
    try:
        text = path.read_bytes().decode("utf-8", errors="replace")
    except OSError as e:
        raise ImuTkError(f"{path}: cannot read: {e.strerror}") from None
    rows = []
    numbers = []
    for number, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 4:
            raise ImuTkError(
                f"{path}:{number}: {len(parts)} fields; imu_tk's files have four per line (t x y z)"
            )
        try:
            values = [float(p) for p in parts]
        except ValueError:
            bad = next(p for p in parts if not _number(p))
            raise ImuTkError(f"{path}:{number}: {bad!r} is not a number") from None
        if not all(math.isfinite(v) for v in values):
            raise ImuTkError(f"{path}:{number}: a value is not finite")
        rows.append(values)
        numbers.append(number)
    if len(rows) < 2:
        raise ImuTkError(f"{path}: {len(rows)} sample(s): at least 2 are needed")
    out = np.array(rows)
    lines = np.array(numbers, dtype=np.int64)
    steps = np.diff(out[:, 0])
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0))
        raise ImuTkError(
            f"{path}:{lines[k + 1]}: the time does not increase ({float(out[k, 0])!r} s on "
            f"line {lines[k]}, then {float(out[k + 1, 0])!r} s)"
        )
    return out, lines


def is_imu_tk_calibration(path: Path) -> bool:
    """imu_tk's calibration file: 21 numbers (T 3x3, K 3x3, B 3), no TOML."""
    try:
        words = path.read_text(errors="replace").split()
    except OSError:
        return False
    return len(words) == 21 and all(map(_number, words))


def read_imu_tk_calibration(
    path: Path, counts: tuple[float, float], unit_si: float = 1.0
) -> tuple[F64, F64]:
    """imu_tk's calibration (calibrated = T K (counts - B), in SI) as imud's affine model of the
    nominal-scale reading x = (counts - zero) / per_unit * unit_si: calibrated = C (x - b) with
    C = T K per_unit / unit_si and b = (B - zero) / per_unit * unit_si. Returns (C, b)."""
    v = np.array(path.read_text().split(), dtype=np.float64)
    t, k, b = v[:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:21]
    per, zero = counts
    matrix: F64 = t @ k * (per / unit_si)
    bias: F64 = (b - zero) / per * unit_si
    return matrix, bias


def read_imu_tk(
    accel_path: Path,
    gyro_path: Path,
    accel_counts: tuple[float, float],
    gyro_counts: tuple[float, float],
    units: tuple[AccelUnits, GyroUnits] = ("m/s2", "rad/s"),
    gravity: float = STANDARD_GRAVITY,
) -> Recording:
    """The pair as one recording, in SI at the nominal scales. The two files must hold the same
    instants (imu_tk pairs them by line). The counts are per unit of `units` (counts per g with
    "g", per deg/s with "dps"); a scale or zero that gives no gravity, or a gyro far from zero
    at rest, is refused naming the option."""
    acc, acc_lines = _read(accel_path)
    gyr, _ = _read(gyro_path)
    if acc.shape[0] != gyr.shape[0] or not np.array_equal(acc[:, 0], gyr[:, 0]):
        n = min(acc.shape[0], gyr.shape[0])
        diff = np.flatnonzero(acc[:n, 0] != gyr[:n, 0])
        k = int(diff[0]) if diff.size else 0
        where = (
            f"line {acc_lines[k]}: {float(acc[k, 0])!r} against {float(gyr[k, 0])!r} s"
            if diff.size
            else f"{acc.shape[0]} samples against {gyr.shape[0]}"
        )
        raise ImuTkError(
            f"{accel_path} and {gyro_path} do not hold the same instants ({where}): imu_tk "
            "pairs them by line; give the two files of one recording"
        )
    t_ns = np.round(acc[:, 0] * 1e9).astype(np.int64)
    accel = (acc[:, 1:] - accel_counts[1]) / accel_counts[0]
    gyro = (gyr[:, 1:] - gyro_counts[1]) / gyro_counts[0]
    problems = unit_problems(
        accel, gyro, None, None, (*units, "T"), gravity, frozenset({"accel", "gyro"})
    )
    if problems:
        raise ImuTkError(f"{accel_path} + {gyro_path}: " + "; ".join(p for _, p in problems))
    if units[0] == "g":
        accel *= gravity
    if units[1] == "dps":
        gyro *= math.pi / 180
    return Recording(t_ns, accel, gyro, source=f"{accel_path.name} + {gyro_path.name}")
