"""Recordings as CSV files: read (any tool's, with unit options) and written (imud's own).

The format is in docs/recording-csv.md. Reading is built for files of an hour at 100 Hz or ten
minutes at 1 kHz (about 100 MB): one vectorised pass over the bytes finds the lines, comments
and field counts, then np.loadtxt's C parser converts the columns imud uses. Only when the parser
refuses a file does more work follow: a bisection with the same parser finds the first line it
refuses, so the message can name that line and column.

Every refusal is a `CsvError` naming the file, the line (1-based, as an editor numbers it) and
the column (as the file's header writes it), because the person fixing the file will open it in
an editor at that line.

Files from other tools are read as they are, apart from unit options: their column names go
through a closed table (acc_x, gyr_x, field.angular_velocity.x, ...; never a guess that could
mix up sensors, and two columns for one quantity are refused), the time comes from a column
in the unit its name states or `time_units` says, or from a sample counter and `rate_hz`, and
a unit stated in a name is checked against the options.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Literal, Self

import numpy as np
import numpy.typing as npt

from imud.calib import memory
from imud.calib.recording import Recording
from imud.channels import SATURATED
from imud.units import STANDARD_GRAVITY

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

AccelUnits = Literal["m/s2", "g"]
GyroUnits = Literal["rad/s", "dps"]
MagUnits = Literal["T", "uT"]
TimeUnits = Literal["s", "ms", "us", "ns"]

REQUIRED = ("timestamp_ns", "ax", "ay", "az", "gx", "gy", "gz")  # as imud writes them
INTEGER_COLUMNS = frozenset({"timestamp_ns", "flags"})
SATURATED_MASK = int(sum(int(f) for f in SATURATED.values()))  # bits 16-19 of the flags
FLOAT_FORMAT = "%.9g"  # 9 significant digits: every float32 reads back to the same float32

# Plausibility limits for the unit checks. Wrong units are off by a factor of 9.8 (g against
# m/s^2), 57 (deg/s against rad/s) or 1e6 (uT against T), so the bands below are wide: a real
# recording in the declared units is never near their edges.
ACCEL_RATIO = 3.0  # the median |accel| must lie within g/3 .. 3g (a still or hand-held session)
GYRO_MAX_RAD_S = 35.0  # 2000 deg/s = 34.9 rad/s, the widest range MEMS gyros offer
MAG_RANGE_T = (1e-6, 1e-3)  # the Earth's 25-65 uT, with room for hard iron up to 1 mT
TEMP_RANGE_C = (-60.0, 150.0)  # beyond any IMU's operating range

# What reading a row costs beyond its columns' 16 bytes each (the parsed table, then the
# recording's arrays): the parser's slack. Measured with tracemalloc on a 2,000,000-row
# recording: reading peaks at 83 bytes a row beyond the file's bytes and its line index (which
# are freed before a calibration's own still detection and fit, about 50 bytes a row)
BYTES_PER_ROW = 16

_CHUNK_ROWS = 65536  # rows formatted at once by the writer (bounds its memory)


class CsvError(ValueError):
    """A recording that cannot be read as it is: the message names the file, the line and the
    column, and says what to change."""

    def __init__(
        self, path: Path | str, message: str, line: int | None = None, column: str | None = None
    ) -> None:
        self.path = Path(path)
        self.line = line
        self.column = column
        self.reason = message
        where = str(path) if line is None else f"{path}:{line}"
        if column is not None:
            where += f": column {column}"
        super().__init__(f"{where}: {message}")


# ---------------------------------------------------------------------------------------------
# reading


@dataclass(frozen=True)
class _Lines:
    """Where each line of the file lies, found with array operations over the bytes.

    start/end: the line's first byte and its newline (or the end of the file); stop: where its
    content ends (a '#' starts a comment); content: the line has something before the comment
    that is not white space; commas: how many commas it has before the comment."""

    start: I64
    stop: I64
    end: I64
    content: Bool
    commas: I64


def _positions(mask: Bool) -> I64:
    return np.flatnonzero(mask).astype(np.int64, copy=False)


_SCAN_BYTES = 1 << 24  # bytes scanned at once: bounds the scan's temporaries, whatever the file


def _scan(data: npt.NDArray[np.uint8]) -> _Lines:
    """The lines of `data`, scanned in pieces that each end after a newline (a line never spans
    two), so the masks the scan builds stay a piece's size."""
    n = int(data.shape[0])
    pieces: list[_Lines] = []
    a = 0
    while a < n or not pieces:
        b = min(a + _SCAN_BYTES, n)
        b = _after_newline(data, b)
        pieces.append(_scan_piece(data[a:b], a))
        a = b
    if len(pieces) == 1:
        return pieces[0]

    def joined(part: Callable[[_Lines], npt.NDArray[np.generic]]) -> Any:
        return np.concatenate([part(p) for p in pieces])

    return _Lines(
        joined(lambda p: p.start),
        joined(lambda p: p.stop),
        joined(lambda p: p.end),
        joined(lambda p: p.content),
        joined(lambda p: p.commas),
    )


def _after_newline(data: npt.NDArray[np.uint8], b: int) -> int:
    """Where the line holding byte b ends (just after its newline), or the end of data."""
    n, w = int(data.shape[0]), 1 << 12
    while b < n:
        nl = np.flatnonzero(data[b : b + w] == ord("\n"))
        if nl.size:
            return b + int(nl[0]) + 1
        b, w = b + w, w * 2
    return n


def _scan_piece(data: npt.NDArray[np.uint8], offset: int) -> _Lines:
    n = int(data.shape[0])
    newlines = _positions(data == ord("\n"))
    start = np.concatenate([np.zeros(1, np.int64), newlines + 1])
    end = np.concatenate([newlines, np.full(1, n, np.int64)])
    if n == 0 or data[-1] == ord("\n"):  # the piece ends with a newline: no line after it
        start, end = start[:-1], end[:-1]
    hashes = _positions(data == ord("#"))
    first_hash = np.append(hashes, n)[np.searchsorted(hashes, start)]
    stop = np.minimum(end, first_hash)
    # white space (a byte <= 0x20; the newline never falls inside start..stop) is rare in a
    # CSV, so count it by its positions rather than a cumulative sum over every byte
    spaces = _positions(data <= ord(" "))
    blank = np.searchsorted(spaces, stop) - np.searchsorted(spaces, start)
    commas = _positions(data == ord(","))
    n_commas = np.searchsorted(commas, stop) - np.searchsorted(commas, start)
    return _Lines(start + offset, stop + offset, end + offset, (stop - start) > blank, n_commas)


def _data_rows(
    buf: bytes, data: npt.NDArray[np.uint8], lines: _Lines, rows: I64
) -> tuple[bytes, I64]:
    """The data lines alone, comments and blank lines cut out, so that row k of np.loadtxt is
    data line k (and its line number is known); and where each row begins in them. The usual
    file (nothing but data after the header) is returned as it is, not copied."""
    first = int(lines.start[rows[0]])
    clean = rows.size == lines.start.size - rows[0] and bool(
        np.all(lines.stop[rows] == lines.end[rows])
    )
    if clean:
        return buf, lines.start[rows]
    marks = np.zeros(data.shape[0] + 1, np.int8)
    marks[lines.start[rows]] = 1
    marks[lines.stop[rows]] = -1
    keep = np.cumsum(marks[:-1], dtype=np.int8) > 0
    newline = lines.end[rows]
    keep[newline[newline < data.shape[0]]] = True
    del marks, first
    text = data[keep].tobytes()
    ends = _positions(np.frombuffer(text, np.uint8) == ord("\n"))
    return text, np.concatenate([np.zeros(1, np.int64), ends + 1])[: rows.size]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _normalise(name: str) -> str:
    return name.strip().strip("\"'").strip().lower()


# --- column names ------------------------------------------------------------------------------
#
# Other tools' names are read as imud's through a closed table (no pattern guessing): a name in
# the table is unambiguous, and two columns that read as one quantity are refused, naming both.
# Names are compared after _key(): lower case, a trailing unit in brackets cut off and kept
# ("Time (s)", "w_RS_S_x [rad s^-1]"), every run of other characters than letters, digits and
# '%' made one "_" ("field.angular_velocity.x" -> "field_angular_velocity_x").

TIME, COUNTER = "time", "counter"  # the two ways a file says when each sample was taken
ROW = "row"  # or neither: each row one sample at a stated rate
_ACCEL_WORDS = ("acc", "accel", "accelerometer", "acceleration", "linear_acceleration",
                "field_linear_acceleration", "alpha", "a_rs_s")  # fmt: skip
_GYRO_WORDS = ("gyr", "gyro", "gyroscope", "angular_velocity", "field_angular_velocity", "omega",
               "w_rs_s")  # fmt: skip
_MAG_WORDS = ("mag", "magn", "magnetometer", "magnetic_field", "field_magnetic_field")
_COMPACT = ("acc", "accel", "gyr", "gyro", "mag", "magn")  # also written without "_": AccX
_TEMP_NAMES = ("temp", "temperature", "temp_c", "temperature_c")
_COUNTER_NAMES = ("n_samples", "sample", "sample_index", "sample_number", "sample_nr",
                  "sample_count", "sample_counter", "counter", "index", "seq",
                  "field_header_seq")  # fmt: skip
# a time column: its name, then the unit it may carry ("timestamp_ns", "time_s")
_TIME_NAME = re.compile(r"^(?:timestamp|time|stamp|t|field_header_stamp)(?:_(s|sec|ms|us|ns))?$")
_TIME_IMPLIED = {"millis": "ms", "micros": "us"}  # Arduino's millis() and micros() clocks
NS_PER_UNIT = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
# Sample rates every IMU lies within (1 Hz temperature logs to 32 kHz gyros, with margin). A time
# column in the wrong unit is off by a factor of 1000 or more, which puts a 100 Hz..1 kHz
# recording outside this band.
RATE_RANGE_HZ = (0.5, 50_000.0)

# units a header may state in brackets, per quantity, normalised to the option's value
_UNIT_WORDS: dict[str, dict[str, str]] = {
    "a": {"m/s^2": "m/s2", "m/s2": "m/s2", "m/s²": "m/s2", "m s^-2": "m/s2", "m s-2": "m/s2",
          "ms^-2": "m/s2", "g": "g"},
    "g": {"rad/s": "rad/s", "rad s^-1": "rad/s", "rad s-1": "rad/s", "deg/s": "dps",
          "dps": "dps", "°/s": "dps", "degrees/s": "dps"},
    "m": {"t": "T", "tesla": "T", "ut": "uT", "µt": "uT", "μt": "uT", "microtesla": "uT"},
    TIME: {"s": "s", "sec": "s", "seconds": "s", "ms": "ms", "us": "us", "µs": "us",
           "μs": "us", "ns": "ns"},
}  # fmt: skip
_UNIT_NOTE = re.compile(r"^(.*?)\s*[\[(]([^\[\]()]*)[\])]$")


def _aliases() -> dict[str, str]:
    """Normalised name -> quantity (ax..gz, mx..mz, temp, counter, flags)."""
    out: dict[str, str] = {"flags": "flags"}
    for prefix, words in (("a", _ACCEL_WORDS), ("g", _GYRO_WORDS), ("m", _MAG_WORDS)):
        for axis in "xyz":
            out[prefix + axis] = prefix + axis
            for w in words:
                out[f"{w}_{axis}"] = prefix + axis
                if w in _COMPACT:
                    out[f"{w}{axis}"] = prefix + axis
    out.update(dict.fromkeys(_TEMP_NAMES, "temp"))
    out.update(dict.fromkeys(_COUNTER_NAMES, COUNTER))
    return out


_ALIASES = _aliases()


def _key(label: str) -> tuple[str, str | None]:
    """A header name as the table compares it, and the unit a trailing bracket states."""
    name, note = label.strip().lower(), None
    m = _UNIT_NOTE.match(name)
    if m is not None and m.group(1):
        name, note = m.group(1), " ".join(m.group(2).split())
    return re.sub(r"[^a-z0-9%]+", "_", name).strip("_"), note


def _quantity(key: str) -> tuple[str, str | None] | None:
    """The quantity a normalised name reads as, and the unit the name itself says."""
    if key in _ALIASES:
        return _ALIASES[key], None
    if key in _TIME_IMPLIED:
        return TIME, _TIME_IMPLIED[key]
    m = _TIME_NAME.match(key)
    if m is not None:
        unit = m.group(1)
        return TIME, "s" if unit == "sec" else unit
    return None


_WHAT = {TIME: "the time", COUNTER: "the sample counter"}


@dataclass(frozen=True)
class _Column:
    """One column imud reads: its field (0-based), its name as the header writes it (every
    message uses that name), and the unit the name states (None when it states none)."""

    field: int
    label: str
    unit: str | None


_FOREIGN_HINTS: tuple[tuple[str, re.Pattern[str]], ...] = tuple(
    (ours, re.compile(rf"^(?:\w*?_)?(?:{words}){tail}"))
    for ours, words, tail in (
        ("a", "linear_acceleration|acceleration|accelerometer|accel|acc|a", r"_?([xyz])(?:_|$)"),
        ("g", "angular_velocity|gyroscope|gyro|gyr|omega|w|g", r"_?([xyz])(?:_|$)"),
        ("m", "magnetic_field|magnetometer|magn|mag|m", r"_?([xyz])(?:_|$)"),
        ("timestamp_ns", "timestamp|time|stamp|t", r"(?:_(?:ns|us|ms|s|sec))?$"),
        ("temp", "temperature|temp|tmp", r"(?:_\w+)?$"),
    )
)


def _suggest(labels: list[str], known: set[str]) -> dict[str, str]:
    """Names outside the table that look like a quantity the header lacks (imu_acc_x,
    AccelerometerX_raw, %time), mapped to imud's name: a hint, never applied."""
    out: dict[str, str] = {}
    for label in labels:
        key = _key(label)[0].removeprefix("%")
        for ours, pattern in _FOREIGN_HINTS:
            m = pattern.match(key)
            if m is None:
                continue
            target = ours + m.group(1) if m.groups() else ours
            if target not in known and target not in out.values():
                out[_normalise(label)] = target
            break
    return out


def _columns(
    path: Path,
    header_line: int,
    labels: list[str],
    units: dict[str, str],
    need: tuple[str, ...] = ("accel", "gyro"),
    rate_known: bool = False,
) -> dict[str, _Column]:
    """Quantity -> the column that holds it, with every header problem refused: two columns
    for one quantity, a unit in a name that contradicts the options, missing columns."""
    if labels and all(_is_number(h) for h in labels):
        raise CsvError(
            path,
            "the first row is data, not a header: add a header row naming the columns, e.g. "
            + ",".join(REQUIRED),
            header_line,
        )
    found: dict[str, list[_Column]] = {}
    for i, label in enumerate(labels):
        key, note = _key(label)
        hit = _quantity(key)
        if hit is not None:
            found.setdefault(hit[0], []).append(_Column(i, label, hit[1] or note))
    out: dict[str, _Column] = {}
    for q, cols in found.items():
        if len(cols) > 1 and (q != COUNTER or TIME not in found):  # a counter beside a time
            # column is not read, so two of them are no ambiguity
            a, b = cols[0], cols[1]
            if _normalise(a.label) == _normalise(b.label):
                msg = f"appears twice (fields {a.field + 1} and {b.field + 1})"
                raise CsvError(path, msg, header_line, a.label)
            raise CsvError(
                path,
                f"both read as {_WHAT.get(q, q)} (fields {a.field + 1} and "
                f"{b.field + 1}): imud cannot tell which to use; delete one, or rename it to a "
                f"name imud does not read (e.g. unused_{_key(b.label)[0]})",
                header_line,
                f"{a.label}, {b.label}",
            )
        out[q] = cols[0]
    options = {"a": "--accel-units", "g": "--gyro-units", "m": "--mag-units"}
    for q, col in out.items():
        if len(q) != 2 or q[0] not in options:  # a sensor axis: ax .. mz
            continue
        said = _UNIT_WORDS[q[0]].get(col.unit or "")
        if said is not None and said != units[q[0]]:
            raise CsvError(
                path,
                f"its name says {col.unit} but the file is being read as {units[q[0]]}: "
                f"pass {options[q[0]]} {said}",
                header_line,
                col.label,
            )
    axes = {"accel": ["ax", "ay", "az"], "gyro": ["gx", "gy", "gz"], "mag": ["mx", "my", "mz"]}
    required = [c for sensor in need for c in axes[sensor]]
    # without a time column or a counter, a rate (--rate, or the preamble's) times the rows
    untimed = TIME not in out and COUNTER not in out and not rate_known
    missing = (["timestamp_ns"] if untimed else []) + [c for c in required if c not in out]
    if missing:
        msg = f"missing required columns {', '.join(missing)}; the header has: {', '.join(labels)}"
        raw = ",".join(labels)
        if len(labels) == 1 and (";" in raw or "\t" in raw):
            msg += "; the fields look separated by ';' or tabs: imud reads comma-separated files"
        if "timestamp_ns" in missing:
            msg += (
                "; the time may be any column named timestamp_ns, time, timestamp or t (with "
                "--time-units), or a sample counter such as n_samples (with --rate); a shot "
                "list (one reading a still pose, no time) needs --shots"
            )
        used = {c.field for c in out.values()}
        guess = _suggest([lb for i, lb in enumerate(labels) if i not in used], set(out))
        guess = {k: v for k, v in guess.items() if v in missing or v in ("temp", "mx", "my", "mz")}
        if guess:
            renames = ", ".join(f"{k} -> {v}" for k, v in guess.items())
            msg += (
                f"; these look like another tool's names: rename {renames} (and pass the unit "
                "options if that tool's units are not SI)"
            )
        raise CsvError(path, msg, header_line)
    for cs in axes.values():  # a sensor is all there or not at all
        present = [c for c in cs if c in out]
        if 0 < len(present) < 3:
            lacking = ", ".join(c for c in cs if c not in out)
            have = ", ".join(out[c].label for c in present)
            raise CsvError(path, f"has {have} but not {lacking}", header_line)
    return out


def _time_plan(
    path: Path,
    header_line: int,
    cols: dict[str, _Column],
    time_units: TimeUnits | None,
    rate_hz: float | None,
) -> tuple[str, str | None]:
    """Which column gives the time and in which unit: (TIME, unit or None when nothing says)
    or (COUNTER, None) with rate_hz. Contradictions between the file and the options are
    refused here, before any parsing."""
    if TIME in cols:
        col = cols[TIME]
        said = None
        if col.unit is not None:
            said = _UNIT_WORDS[TIME].get(col.unit)
            if said is None:
                raise CsvError(
                    path,
                    f"its name says {col.unit!r}, not a time unit imud reads (s, ms, us, ns): "
                    "convert the column",
                    header_line,
                    col.label,
                )
        if rate_hz is not None:
            raise CsvError(
                path,
                "the file has a time column, and --rate is only for a file with a sample "
                "counter and no time: drop --rate",
                header_line,
                col.label,
            )
        if said is not None and time_units is not None and said != time_units:
            raise CsvError(
                path,
                f"its name says {said} but --time-units is {time_units}: drop --time-units",
                header_line,
                col.label,
            )
        return TIME, said or time_units
    if COUNTER not in cols:
        if rate_hz is None:
            raise CsvError(
                path,
                "no time column and no sample counter: name the time column timestamp_ns, "
                "time, timestamp or t (with --time-units), or give the rate of a file whose rows "
                "are one sample each (--rate HZ, or a preamble line such as Fs,50)",
                header_line,
            )
        return ROW, None
    col = cols[COUNTER]
    if time_units is not None:
        raise CsvError(
            path,
            f"--time-units is for a time column; this file has none, only the sample counter "
            f"{col.label}: drop --time-units (and give --rate)",
            header_line,
            col.label,
        )
    if rate_hz is None:
        raise CsvError(
            path,
            "a sample counter and no time column: pass the rate it counts at, --rate HZ (each "
            f"sample's time is then {col.label} / rate)",
            header_line,
            col.label,
        )
    return COUNTER, None


def _first_bad_row(
    text: bytes, starts: I64, usecols: list[int], dtype: np.dtype[np.void]
) -> tuple[int, bytes]:
    """The first row np.loadtxt refuses (its index and bytes), by bisection with np.loadtxt
    itself over the rows' byte ranges, so the answer agrees with the parser exactly (about
    twice the work of one pass). starts: where each row begins in text."""
    bounds = np.append(starts, len(text))
    lo, hi = 0, int(starts.size)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        try:
            _loadtxt(text[bounds[lo] : bounds[mid]], usecols, dtype)
        except ValueError:
            hi = mid
        else:
            lo = mid
    return lo, text[bounds[lo] : bounds[lo + 1]].rstrip(b"\n")


def _loadtxt(
    text: bytes,
    usecols: list[int],
    dtype: np.dtype[np.void],
    start: int = 0,
    max_rows: int | None = None,
) -> npt.NDArray[np.void]:
    """np.loadtxt of the rows of text from byte `start` (BytesIO shares text's bytes: no copy)."""
    f = io.BytesIO(text)
    f.seek(start)
    out: npt.NDArray[np.void] = np.loadtxt(
        f,
        delimiter=",",
        comments=None,
        dtype=dtype,
        usecols=usecols,
        ndmin=1,
        encoding="utf-8",
        max_rows=max_rows,
    )
    return out


def _conversion_error(
    path: Path,
    line: int,
    row: bytes,
    cols: dict[str, _Column],
    dtype: np.dtype[np.void],
) -> CsvError:
    fields = row.split(b",")
    for name, col in cols.items():
        if name not in (dtype.names or ()):
            continue
        text = fields[col.field].decode("utf-8", "replace").strip()
        if not text:
            return CsvError(path, "empty value", line, col.label)
        try:
            _loadtxt(fields[col.field], [0], np.dtype([(name, dtype[name])]))
        except ValueError:
            pass
        else:
            continue
        if dtype[name] == np.int64 and _is_number(text):
            what = {"flags": "is a bit field", COUNTER: "counts samples"}.get(
                name, "counts nanoseconds"
            )
            return CsvError(
                path, f"{text!r} is not an integer ({col.label} {what})", line, col.label
            )
        return CsvError(path, f"{text!r} is not a number", line, col.label)
    return CsvError(path, f"cannot read the line {row.decode('utf-8', 'replace')!r}", line)


def _median_norm(v: F64) -> float:
    return float(np.median(np.sqrt(np.einsum("ij,ij->i", v, v))))


def unit_problems(
    accel: F64 | None,
    gyro: F64 | None,
    temp: F64 | None,
    mag: F64 | None,
    units: tuple[AccelUnits, GyroUnits, MagUnits],
    gravity: float,
    counted: frozenset[str] = frozenset(),
) -> list[tuple[tuple[str, ...], str]]:
    """(columns, what is wrong) for each sensor whose values are off by orders of magnitude
    in the declared units. The values are in those units, before conversion to SI. counted:
    the sensors ("accel", "gyro", "mag") whose values came from raw counts by the user's
    --*-counts, so a wrong value points at that option."""
    accel_units, gyro_units, mag_units = units
    out: list[tuple[tuple[str, ...], str]] = []
    out += _counted_problems(accel, gyro, units, gravity, counted)
    if out:
        return out

    a = _median_norm(accel) if accel is not None else gravity
    a_si = a * (gravity if accel_units == "g" and accel is not None else 1.0)
    if accel is not None and not gravity / ACCEL_RATIO <= a_si <= gravity * ACCEL_RATIO:
        said = f"the median |accel| is {a:.4g} {accel_units}, not near gravity ({gravity:g} m/s^2)"
        if accel_units == "m/s2" and 1 / ACCEL_RATIO <= a <= ACCEL_RATIO:
            hint = "looks like g: pass --accel-units g"
        elif accel_units == "g" and gravity / ACCEL_RATIO <= a <= gravity * ACCEL_RATIO:
            hint = "looks like m/s^2: pass --accel-units m/s2"
        elif a_si < gravity / 30:
            hint = "is gravity removed (linear acceleration)? calibration needs what the chip read"
        else:
            hint = (
                "milli-g? convert to m/s^2 or g; raw counts? give --accel-counts "
                "PER_UNIT,ZERO (counts per unit of --accel-units, and the count that reads 0)"
            )
        out.append((("ax", "ay", "az"), f"{said}: {hint}"))

    w = float(np.percentile(np.max(np.abs(gyro), axis=1), 99)) if gyro is not None else 0.0
    w_si = w * (math.pi / 180 if gyro_units == "dps" else 1.0)
    if w_si > GYRO_MAX_RAD_S:
        said = (
            f"|gyro| reaches {w:.4g} {gyro_units} in 1 % of samples, beyond any MEMS gyro's range "
            f"({GYRO_MAX_RAD_S:g} rad/s = 2000 deg/s)"
        )
        if gyro_units == "rad/s" and w * math.pi / 180 <= GYRO_MAX_RAD_S:
            hint = "looks like dps: pass --gyro-units dps"
        else:
            hint = (
                "raw counts? give --gyro-counts PER_UNIT,ZERO (counts per unit of "
                "--gyro-units, and the count that reads 0)"
            )
        out.append((("gx", "gy", "gz"), f"{said}: {hint}"))

    if mag is not None:
        m = _median_norm(mag)
        m_si = m * (1e-6 if mag_units == "uT" else 1.0)
        lo, hi = MAG_RANGE_T
        if not lo <= m_si <= hi:
            said = (
                f"the median |mag| is {m:.4g} {mag_units}, not near the Earth's field "
                "(25-65 uT = 2.5e-5..6.5e-5 T)"
            )
            if mag_units == "T" and lo * 1e6 <= m <= hi * 1e6:
                hint = "looks like uT: pass --mag-units uT"
            elif mag_units == "uT" and lo <= m <= hi:
                hint = "looks like tesla: pass --mag-units T"
            elif 0.1 <= m < 1:
                hint = "looks like gauss: multiply by 100 and pass --mag-units uT"
            elif m > 1.0:
                hint = "raw counts? give --mag-counts, the counts a microtesla (its datasheet's "
                hint += "LSB/gauss divided by 100)"
            else:
                hint = "convert to tesla or uT"
            out.append((("mx", "my", "mz"), f"{said}: {hint}"))

    if temp is not None:
        c = float(np.median(temp))
        if not TEMP_RANGE_C[0] <= c <= TEMP_RANGE_C[1]:
            hint = "looks like kelvin" if 200 <= c <= 450 else "raw counts?"
            out.append(
                (("temp",), f"the median temp is {c:.4g}, not degC: {hint}; convert to degC")
            )
    return out


GYRO_ZERO_MAX_RAD_S = 1.0  # a gyro's median over a calibration recording (mostly still)


def _counted_problems(
    accel: F64 | None,
    gyro: F64 | None,
    units: tuple[AccelUnits, GyroUnits, MagUnits],
    gravity: float,
    counted: frozenset[str],
) -> list[tuple[tuple[str, ...], str]]:
    """What a wrong --accel-counts / --gyro-counts does: gravity far from g (the scale, or
    the unit it is per), a gyro whose median is far from zero (the zero count)."""
    out: list[tuple[tuple[str, ...], str]] = []
    if accel is not None and "accel" in counted:
        a = _median_norm(accel) * (gravity if units[0] == "g" else 1.0)
        if not gravity / 1.5 <= a <= gravity * 1.5:
            ratio = a / gravity
            per_g = ratio * 9.80665 if units[0] == "m/s2" else None
            hint = (
                "counts per g? add --accel-units g"
                if per_g is not None and 0.8 <= 1 / per_g <= 1.25
                else "is the zero count right (offset-binary 16-bit parts read 0 at 32768)?"
            )
            out.append(
                (
                    ("ax", "ay", "az"),
                    f"with --accel-counts the median |accel| is {a:.4g} m/s^2, {ratio:.3g} times "
                    f"gravity: check the counts per {units[0]} ({hint})",
                )
            )
    if gyro is not None and "gyro" in counted:
        scale = math.pi / 180 if units[1] == "dps" else 1.0
        median = np.median(gyro, axis=0) * scale
        worst = int(np.argmax(np.abs(median)))
        if abs(float(median[worst])) > GYRO_ZERO_MAX_RAD_S:
            per_deg = (
                " or are the counts per deg/s (then add --gyro-units dps)?"
                if units[1] == "rad/s"
                and abs(float(median[worst])) * math.pi / 180 <= GYRO_ZERO_MAX_RAD_S
                else ""
            )
            out.append(
                (
                    ("gx", "gy", "gz"),
                    f"with --gyro-counts the gyro's median on {'xyz'[worst]} is "
                    f"{float(median[worst]):.4g} rad/s, far from zero for a recording that is "
                    "mostly still: is the zero count right (--gyro-counts PER_UNIT,ZERO; "
                    "offset-binary 16-bit parts read 0 at 32768)?" + per_deg,
                )
            )
    return out


def read_csv(
    path: Path,
    accel_units: AccelUnits = "m/s2",
    gyro_units: GyroUnits = "rad/s",
    mag_units: MagUnits = "T",
    gravity: float = STANDARD_GRAVITY,
    *,
    time_units: TimeUnits | None = None,
    rate_hz: float | None = None,
    need: tuple[str, ...] = ("accel", "gyro"),
    mag_per_ut: float | None = None,
    untimed_rate_hz: float | None = None,
    accel_counts: tuple[float, float] | None = None,
    gyro_counts: tuple[float, float] | None = None,
) -> Recording:
    """Read a recording (docs/recording-csv.md) into SI units.

    need: the sensors whose columns must be there ("accel", "gyro", "mag"): a recording holds
    what it measured, so a magnetometer session needs no accelerometer; a sensor not needed and
    not in the file reads as NaN (never as a value). mag_per_ut: the magnetometer columns are
    raw counts, this many a microtesla; accel_counts / gyro_counts: those columns are raw
    counts, (counts per unit of accel_units / gyro_units, the count that reads 0).
    untimed_rate_hz: the rate of rows with no time column, counter, --rate or preamble (a shot
    list's rows need none). Lines before the header of the
    form `name,number` are the file's preamble (a tool's `Fs,50.00`): `Fs`, `rate` or
    `sample_rate` gives the rate of a file with neither a time column nor a sample counter,
    each row then one sample.

    accel_units "g" multiplies by `gravity` (pass the local g the file's tool used, if it said);
    gyro_units "dps" converts deg/s to rad/s; mag_units "uT" converts to tesla. Other tools'
    column names are read through a closed table (acc_x, gyr_x, field.angular_velocity.x, ...).
    time_units: the unit of a time column whose name does not say it (time, timestamp, t);
    rate_hz: the rate of a sample counter (n_samples, sample, index, ...) in a file without a
    time column, each sample's time being counter / rate. Raises CsvError for a file that cannot
    be used as it is, naming the line and column."""
    path = Path(path)
    if accel_units not in ("m/s2", "g"):
        raise ValueError(f"accel_units must be 'm/s2' or 'g', not {accel_units!r}")
    if gyro_units not in ("rad/s", "dps"):
        raise ValueError(f"gyro_units must be 'rad/s' or 'dps', not {gyro_units!r}")
    if mag_units not in ("T", "uT"):
        raise ValueError(f"mag_units must be 'T' or 'uT', not {mag_units!r}")
    if time_units is not None and time_units not in NS_PER_UNIT:
        raise ValueError(f"time_units must be 's', 'ms', 'us' or 'ns', not {time_units!r}")
    if rate_hz is not None and not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a positive number of Hz, not {rate_hz!r}")
    if not (math.isfinite(gravity) and gravity > 0):
        raise ValueError(f"gravity must be a positive number of m/s^2, not {gravity!r}")
    if mag_per_ut is not None and not (math.isfinite(mag_per_ut) and mag_per_ut > 0):
        raise ValueError(f"mag_per_ut must be a positive number of counts, not {mag_per_ut!r}")

    try:
        counts = {"accel": accel_counts, "gyro": gyro_counts, "mag": mag_per_ut}
        return _read(path, accel_units, gyro_units, mag_units, gravity, time_units, rate_hz,
                     need, counts, untimed_rate_hz)  # fmt: skip
    except MemoryError:
        raise CsvError(
            path,
            f"not enough memory to read its {memory.size_text(_file_size(path))}: a "
            "calibration needs minutes of data, not hours; "
            "cut the recording (its first million rows: `head -n 1000001 FILE > part.csv`)",
        ) from None


def _read(
    path: Path,
    accel_units: AccelUnits,
    gyro_units: GyroUnits,
    mag_units: MagUnits,
    gravity: float,
    time_units: TimeUnits | None,
    rate_hz: float | None,
    need: tuple[str, ...],
    counts: Mapping[str, tuple[float, float] | float | None],
    untimed_rate_hz: float | None,
) -> Recording:
    buf = path.read_bytes()
    buf = buf.removeprefix(b"\xef\xbb\xbf")  # the UTF-8 byte order mark some editors write
    if b"\r" in buf:  # Windows (CRLF) or old Mac (CR) line ends
        buf = buf.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    data = np.frombuffer(buf, np.uint8)
    lines = _scan(data)
    content = np.flatnonzero(lines.content)
    if content.size == 0:
        raise CsvError(path, "no header row: the file has only comments or blank lines")
    h = int(content[0])
    header_text = buf[lines.start[h] : lines.stop[h]].decode("utf-8", "replace")
    rows = content[1:]
    preamble: dict[str, float] = {}
    while rows.size and (item := _preamble_item(header_text)) is not None:
        preamble[item[0]] = item[1]  # `Fs,50.00` above the header: the tool's own notes
        if item[0] in _RATE_NAMES and not (math.isfinite(item[1]) and item[1] > 0):
            raise CsvError(
                path,
                f"the preamble's rate {item[1]!r} is not a positive number of Hz: fix the line, "
                "or give --rate",
                h + 1,
            )
        h, rows = int(rows[0]), rows[1:]
        header_text = buf[lines.start[h] : lines.stop[h]].decode("utf-8", "replace")
    said = next((v for k, v in preamble.items() if k in _RATE_NAMES), None)
    if said is not None and rate_hz is not None and not math.isclose(said, rate_hz, rel_tol=1e-6):
        raise CsvError(
            path,
            f"--rate {rate_hz:g} Hz, but the file's preamble says {said:g} Hz: drop --rate (the "
            "file knows its rate), or fix the preamble",
        )
    stated = untimed_rate_hz if said is None else said
    commented = _commented_header(buf, lines, h, header_text)
    if commented is not None:  # EuRoC style: "#timestamp [ns],w_RS_S_x [rad s^-1],..."
        h, header_text = commented
        rows = content
    header_line = h + 1
    labels = [x.strip().strip("\"'").strip() for x in header_text.split(",")]
    units: dict[str, str] = {"a": accel_units, "g": gyro_units, "m": mag_units}
    cols = _columns(
        path, header_line, labels, units, need, rate_hz is not None or stated is not None
    )
    if TIME not in cols and COUNTER not in cols and rate_hz is None and stated is not None:
        rate_hz = stated  # the preamble's rate, for a file of rows one sample each
    when, unit = _time_plan(path, header_line, cols, time_units, rate_hz)
    if when == TIME:
        cols.pop(COUNTER, None)  # a counter beside a time column is not read

    line_of = rows + 1  # line number (1-based) of each data row
    wrong = np.flatnonzero(lines.commas[rows] != len(labels) - 1)
    if wrong.size:
        k = int(wrong[0])
        found = int(lines.commas[rows[k]]) + 1
        column = (labels[found] or None) if found < len(labels) else None
        raise CsvError(
            path,
            f"{found} fields where the header (line {header_line}) names {len(labels)}"
            + (": the line ends before this column" if column else "")
            + " (a truncated or merged line?)",
            int(line_of[k]),
            column,
        )
    if rows.size < 2:
        plural = "" if rows.size == 1 else "s"
        raise CsvError(path, f"{rows.size} sample{plural}: at least 2 are needed")

    names = list(cols)
    integer = {"flags", COUNTER} | ({TIME} if unit == "ns" else set())
    dtype = np.dtype([(n, np.int64 if n in integer else np.float64) for n in names])
    usecols = [cols[n].field for n in names]
    # what the rest costs, asked of the machine before it is spent: a refusal that says so
    # beats a process the kernel kills half-way (the bytes read so far are already counted)
    cost = rows.size * (BYTES_PER_ROW + 16 * len(names))
    short = memory.shortfall(cost, f"its {rows.size:,} rows")
    if short is not None:
        raise CsvError(path, short)
    text, starts = _data_rows(buf, data, lines, rows)
    del data, lines, content, buf
    try:
        table = _loadtxt(text, usecols, dtype, int(starts[0]), int(rows.size))
    except ValueError:
        k, row = _first_bad_row(text, starts, usecols, dtype)
        raise _conversion_error(path, int(line_of[k]), row, cols, dtype) from None
    del text, starts
    t_ns = _times(path, table, cols, (header_line, line_of), when, unit, rate_hz)
    return _recording(
        path, table, cols, t_ns, line_of, (accel_units, gyro_units, mag_units), gravity, counts
    )


def _file_size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


_RATE_NAMES = frozenset({"fs", "rate", "rate_hz", "sample_rate", "sampling_rate"})


def _preamble_item(text: str) -> tuple[str, float] | None:
    """`name,number` (a preamble line a tool writes above its header), normalised name."""
    fields = [f.strip() for f in text.split(",")]
    if len(fields) != 2 or _is_number(fields[0]) or not _is_number(fields[1]):
        return None
    return _normalise(fields[0]), float(fields[1])


def _commented_header(
    buf: bytes, lines: _Lines, first: int, first_text: str
) -> tuple[int, str] | None:
    """The header some tools write as a comment (EuRoC/ASL: "#timestamp [ns],w_RS_S_x ..."):
    when the first content line is all numbers, the comment line just before it is the header
    if it names as many fields as that line holds and they are not numbers."""
    fields = first_text.split(",")
    if not all(_is_number(f) for f in fields):
        return None
    k = first - 1
    while k >= 0 and not buf[lines.start[k] : lines.end[k]].strip():
        k -= 1  # blank lines between
    if k < 0:
        return None
    text = buf[lines.start[k] : lines.end[k]].decode("utf-8", "replace").strip()
    if not text.startswith("#"):
        return None
    names = text[1:].split(",")
    if len(names) != len(fields) or any(_is_number(n) or not n.strip() for n in names):
        return None
    return k, text[1:]


def _times(
    path: Path,
    table: npt.NDArray[np.void],
    cols: dict[str, _Column],
    lines: tuple[int, I64],
    when: str,
    unit: str | None,
    rate_hz: float | None,
) -> I64:
    """Each sample's time in integer nanoseconds, from a time column in its unit or a counter
    and the rate; refused when it does not strictly increase, when no unit was said, or when
    the unit gives a sample rate no IMU has. lines: the header's line and each row's."""
    header_line, line_of = lines
    if when == ROW:
        assert rate_hz is not None
        n = table.shape[0]
        return np.round(np.arange(n, dtype=np.float64) * (1e9 / rate_hz)).astype(np.int64)
    col = cols[when]
    v = np.ascontiguousarray(table[when])
    if when == TIME and v.dtype == np.float64:
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            k = int(bad[0])
            raise CsvError(path, f"{v[k]} is not a finite number", int(line_of[k]), col.label)
    back = np.flatnonzero(np.diff(v) <= 0)
    if back.size:
        k = int(back[0])
        what = (
            "a sample counter must strictly increase (a duplicated row, or a counter that "
            "wrapped around: unwrap it first)"
            if when == COUNTER
            else "timestamps must strictly increase (a duplicated or reordered row?)"
        )
        raise CsvError(
            path,
            f"{v[k + 1]} is not after {v[k]} on line {line_of[k]}: {what}",
            int(line_of[k + 1]),
            col.label,
        )
    if when == COUNTER:
        assert rate_hz is not None
        t: I64 = np.round(v.astype(np.float64) * (1e9 / rate_hz)).astype(np.int64)
        return t
    step = float(np.median(np.diff(v)))
    if unit is None:
        raise CsvError(
            path,
            "its name does not say its unit: pass --time-units s, ms, us or ns"
            + _time_hint(step, None),
            header_line,
            col.label,
        )
    scale = NS_PER_UNIT[unit]
    rate = 1e9 / (step * scale)
    lo, hi = RATE_RANGE_HZ
    if not lo <= rate <= hi:
        raise CsvError(
            path,
            f"read as {unit}, its median step {step:.4g} {unit} is a rate of {rate:.4g} Hz, "
            f"outside any IMU's ({lo:g} Hz .. {hi:g} Hz)" + _time_hint(step, unit),
            None,
            col.label,
        )
    if v.dtype == np.int64:
        return v
    t = np.round((v - v[0]) * scale).astype(np.int64) + round(float(v[0]) * scale)
    same = np.flatnonzero(np.diff(t) <= 0)
    if same.size:
        k = int(same[0])
        raise CsvError(
            path,
            f"{v[k + 1]!r} {unit} is within a nanosecond of {v[k]!r} on line {line_of[k]}: "
            "timestamps must strictly increase",
            int(line_of[k + 1]),
            col.label,
        )
    return t


def _time_hint(step: float, unit: str | None) -> str:
    """': looks like X: ...' when one time unit makes the median step a common IMU rate
    (10 Hz .. 10 kHz; the units are 1000 apart, so at most one does)."""
    for u, scale in NS_PER_UNIT.items():
        if u != unit and 10.0 <= 1e9 / (step * scale) < 10_000.0:
            rate = 1e9 / (step * scale)
            return f": looks like {u} ({rate:.4g} Hz): pass --time-units {u}"
    return ""


def _recording(
    path: Path,
    table: npt.NDArray[np.void],
    cols: dict[str, _Column],
    t: I64,
    line_of: I64,
    units: tuple[AccelUnits, GyroUnits, MagUnits],
    gravity: float,
    counts: Mapping[str, tuple[float, float] | float | None],
) -> Recording:
    """Checks on the parsed values (finite, plausible units), then SI units. counts: the
    sensors given as raw counts (accel/gyro: per unit and zero; mag: per uT)."""
    names = table.dtype.names or ()
    first_bad: dict[str, int] = {}  # column -> first row where it is NaN or infinite
    for name in names:
        if name not in (TIME, COUNTER, "flags"):
            bad = np.flatnonzero(~np.isfinite(table[name]))
            if bad.size:
                first_bad[name] = int(bad[0])
    if first_bad:
        name = min(first_bad, key=lambda n: (first_bad[n], cols[n].field))
        k = first_bad[name]
        raise CsvError(
            path,
            f"{table[name][k]} is not a finite number (a sample marked invalid? drop the row)",
            int(line_of[k]),
            cols[name].label,
        )
    saturated = None
    if "flags" in names:
        flags = table["flags"]
        out_of_range = np.flatnonzero((flags < 0) | (flags > 0xFFFFFFFF))
        if out_of_range.size:
            k = int(out_of_range[0])
            raise CsvError(
                path, f"{flags[k]} is not a 32-bit flag word", int(line_of[k]), cols["flags"].label
            )
        saturated = (flags & SATURATED_MASK) != 0

    def vec(a: str, b: str, c: str) -> F64:
        return np.column_stack([table[a], table[b], table[c]])

    n = table.shape[0]
    absent = np.full((n, 3), np.nan)  # a sensor the recording does not hold: never a value
    accel = vec("ax", "ay", "az") if "ax" in names else None
    gyro = vec("gx", "gy", "gz") if "gx" in names else None
    temp = np.ascontiguousarray(table["temp"], np.float64) if "temp" in names else None
    mag = vec("mx", "my", "mz") if "mx" in names else None
    counted: set[str] = set()
    mag_per_ut = counts.get("mag")
    if mag is not None and isinstance(mag_per_ut, int | float):
        mag = mag / float(mag_per_ut)  # counts -> uT, then checked and converted as uT
        units = (units[0], units[1], "uT")
        counted.add("mag")
    accel_counts, gyro_counts = counts.get("accel"), counts.get("gyro")
    if accel is not None and isinstance(accel_counts, tuple):
        accel = (accel - accel_counts[1]) / accel_counts[0]  # counts -> --accel-units
        counted.add("accel")
    if gyro is not None and isinstance(gyro_counts, tuple):
        gyro = (gyro - gyro_counts[1]) / gyro_counts[0]
        counted.add("gyro")
    problems = unit_problems(accel, gyro, temp, mag, units, gravity, frozenset(counted))
    if problems:
        cols_text = "; ".join(", ".join(cols[q].label for q in qs) for qs, _ in problems)
        raise CsvError(path, "; ".join(p for _, p in problems), None, cols_text)
    accel_units, gyro_units, mag_units = units
    if accel is not None and accel_units == "g":
        accel *= gravity
    if gyro is not None and gyro_units == "dps":
        gyro *= math.pi / 180
    if mag is not None and mag_units == "uT":
        mag *= 1e-6
    return Recording(
        t,
        absent if accel is None else accel,
        absent.copy() if gyro is None else gyro,
        temp,
        mag,
        saturated,
        str(path),
    )


def read_comments(path: Path) -> dict[str, str]:
    """The `# key: value` lines before the header (imud writes device, chip, samples raw or
    corrected, date there), read without reading the rest of the file."""
    out: dict[str, str] = {}
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        for raw in f:
            line = raw.strip()
            if not line:
                continue
            if not line.startswith("#"):
                break
            key, sep, value = line[1:].partition(":")
            if sep and key.strip():
                out[key.strip()] = value.strip()
    return out


# ---------------------------------------------------------------------------------------------
# writing


class CsvWriter:
    """Writes a recording in imud's CSV format; a context manager.

    The rows go to a temporary file beside `path`, renamed onto `path` by close(): a reader
    never sees half a file. If the block raises (or abort() is called) the rows so far are kept
    as `<path>.partial` and the exception gets a note saying where. The writer refuses what
    read_csv would refuse (NaN, timestamps not increasing), so every file it closes reads back.
    """

    def __init__(
        self,
        path: Path,
        *,
        has_temp: bool = False,
        has_mag: bool = False,
        has_flags: bool = False,
        comments: Mapping[str, str] | None = None,
    ) -> None:
        self.path = Path(path)
        self.has_temp, self.has_mag, self.has_flags = has_temp, has_mag, has_flags
        self.columns = (
            list(REQUIRED)
            + (["temp"] if has_temp else [])
            + (["mx", "my", "mz"] if has_mag else [])
            + (["flags"] if has_flags else [])
        )
        self._row = ",".join("%d" if c in INTEGER_COLUMNS else FLOAT_FORMAT for c in self.columns)
        self._row += "\n"
        self.rows = 0
        self.partial_path: Path | None = None
        self._last_t: int | None = None
        fd, tmp = tempfile.mkstemp(
            prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent
        )
        self._tmp = Path(tmp)
        self._file = os.fdopen(fd, "w", encoding="utf-8", newline="\n")
        lines = [
            "# format: imud recording, SI units (m/s^2, rad/s, degC, tesla), docs/recording-csv.md"
        ]
        for key, value in (comments or {}).items():
            k = " ".join(str(key).replace(":", " ").split())
            lines.append(f"# {k}: {' '.join(str(value).split())}")
        self._file.write("\n".join(lines) + "\n" + ",".join(self.columns) + "\n")

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc is None:
            self.close()
            return
        if self._file.closed:  # closed (complete) or aborted already: nothing left to keep
            return
        kept = self.abort()
        exc.add_note(f"the {self.rows} rows written so far are kept in {kept}")

    def write(
        self,
        t_ns: npt.ArrayLike,
        accel: npt.ArrayLike,
        gyro: npt.ArrayLike,
        temp: npt.ArrayLike | None = None,
        mag: npt.ArrayLike | None = None,
        flags: npt.ArrayLike | None = None,
    ) -> None:
        """Append N samples: t_ns (N,) integer ns, accel (N, 3), gyro (N, 3), temp (N,),
        mag (N, 3), flags (N,) (each optional one exactly when the writer was opened with it)."""
        t = np.asarray(t_ns)
        if t.ndim != 1 or not np.issubdtype(t.dtype, np.integer):
            raise ValueError(
                f"t_ns must be a 1-D integer array of nanoseconds, not {t.dtype}{t.shape}"
            )
        n = t.shape[0]
        cols: list[npt.NDArray[np.generic]] = [t.astype(np.int64)]
        for name, arr, width, wanted in (
            ("accel", accel, 3, True),
            ("gyro", gyro, 3, True),
            ("temp", temp, 1, self.has_temp),
            ("mag", mag, 3, self.has_mag),
            ("flags", flags, 1, self.has_flags),
        ):
            if (arr is None) == wanted:
                said = "missing: the writer was opened with" if wanted else "given: no"
                raise ValueError(f"{name} {said} that column")
            if arr is None:
                continue
            shape = (n,) if width == 1 else (n, width)
            if name == "flags":
                f = np.asarray(arr)
                if f.shape != shape or not np.issubdtype(f.dtype, np.integer):
                    raise ValueError(f"flags must be (N,) integers, not {f.dtype}{f.shape}")
                if f.size and (int(f.min()) < 0 or int(f.max()) > 0xFFFFFFFF):
                    raise ValueError("flags must be 32-bit unsigned words")
                cols.append(f.astype(np.int64))
                continue
            a = np.asarray(arr, np.float64)
            if a.shape != shape:
                raise ValueError(f"{name} has shape {a.shape}, expected {shape}")
            a = a.reshape(n, width)
            bad = np.flatnonzero(~np.isfinite(a).all(axis=1))
            if bad.size:
                raise ValueError(f"{name} is not finite in sample {bad[0]} of this batch")
            cols.extend(a.T)
        if n == 0:
            return
        steps = np.diff(t.astype(np.int64))
        back = np.flatnonzero(steps <= 0)
        if back.size or (self._last_t is not None and int(t[0]) <= self._last_t):
            at = int(back[0]) + 1 if back.size else 0
            raise ValueError(f"t_ns does not increase at sample {at} of this batch")
        self._write_rows(cols, n)
        self._last_t = int(t[-1])
        self.rows += n

    def _write_rows(self, cols: list[npt.NDArray[np.generic]], n: int) -> None:
        """One %-format of a repeated row template over all values: the formatting loop runs in
        C, twice as fast as np.savetxt (which formats row by row in Python)."""
        table = np.empty((n, len(cols)), dtype=object)
        for j, c in enumerate(cols):
            table[:, j] = c.tolist()  # Python ints stay exact: int64 ns need all 19 digits
        for a in range(0, n, _CHUNK_ROWS):
            chunk = table[a : a + _CHUNK_ROWS]
            self._file.write((self._row * chunk.shape[0]) % tuple(chunk.ravel().tolist()))

    def close(self) -> None:
        """Flush, and rename the finished file onto `path` (atomic; durable once returned)."""
        if self._file.closed:
            return
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        os.replace(self._tmp, self.path)
        dfd = os.open(self.path.parent, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(dfd)  # the rename itself is durable only once the directory is
        finally:
            os.close(dfd)

    def abort(self) -> Path:
        """Stop, keeping the rows written so far as `<path>.partial`; returns that path."""
        partial = self.path.with_name(self.path.name + ".partial")
        if not self._file.closed:
            with contextlib.suppress(OSError):
                self._file.flush()
            self._file.close()
            os.replace(self._tmp, partial)
            self.partial_path = partial
        return self.partial_path or partial
