"""The calibration file: one human-readable TOML file per device.

It says what the pipeline applies (per sensor: bias, matrix, temperature polynomial) and where it
came from (chip and device, date, procedure, source, temperature, local g, the parameters'
covariance and the residual statistics), so a person can judge a calibration months later and a
tool can propagate its uncertainty. See docs/calibration.md for the format.

Loading validates everything the pipeline will rely on: shapes, finite numbers, a matrix that is
neither singular nor ill-conditioned, a covariance that is symmetric and positive semi-definite,
the chip it was made for, sensors the chip has. A bad file raises `CalibrationError` naming the
key and the fix; the device then runs uncalibrated and says why in status (never garbage).
"""

from __future__ import annotations

import datetime as dt
import math
import tomllib
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from imud.atomicfile import write_atomic
from imud.calib.estimate import AffineEstimate, TempEstimate
from imud.calib.model import CalibrationModel, SensorModel, TempPoly
from imud.calib.noise import MeasuredNoise
from imud.channels import Channel

Vec3 = tuple[float, float, float]
FORMAT = "imud-calibration"
VERSION = 2
MAX_CONDITION = 1e3  # a calibration undoes percent-level scale and misalignment errors
_SENSOR_CHANNEL = {"accel": Channel.ACCEL, "gyro": Channel.GYRO, "mag": Channel.MAG}
_UNITS = {"accel": "m/s^2", "gyro": "rad/s", "mag": "T"}


class CalibrationError(ValueError):
    pass


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class FitTable(_Strict):
    """The estimated parameters by name, and their covariance (same order)."""

    names: list[str]
    values: list[float]
    covariance: list[list[float]]

    @model_validator(mode="after")
    def _shapes(self) -> FitTable:
        p = len(self.names)
        if len(self.values) != p:
            raise ValueError(f"values has {len(self.values)} entries for {p} names")
        if len(self.covariance) != p or any(len(r) != p for r in self.covariance):
            raise ValueError(f"covariance must be {p}x{p} (one row and column per name)")
        c = np.asarray(self.covariance, dtype=np.float64)
        # symmetric to rounding, judged on the correlation scale sqrt(c_ii c_jj): an
        # element-wise relative test fails on cross terms that are zero but for rounding
        scale = np.sqrt(np.outer(np.abs(np.diag(c)), np.abs(np.diag(c))))
        if p and not np.all(np.abs(c - c.T) <= 1e-6 * scale + 1e-300):
            raise ValueError("covariance is not symmetric")
        if p and float(np.linalg.eigvalsh(c).min()) < -1e-9 * max(float(np.abs(c).max()), 1e-300):
            raise ValueError("covariance is not positive semi-definite (a negative variance)")
        return self


class TempTable(_Strict):
    """bias(T) - bias(reference_c) = sum_k coefficients[k-1] * (T - reference_c)^k, per axis."""

    reference_c: float
    span_c: tuple[float, float]
    coefficients: list[Vec3] = Field(min_length=1, max_length=3)
    procedure: str | None = None
    date: str | None = None
    source: str | None = None
    residuals: dict[str, float] = Field(default_factory=dict)
    fit: FitTable | None = None
    notes: list[str] = Field(default_factory=list)

    @model_validator(mode="after")
    def _span(self) -> TempTable:
        lo, hi = self.span_c
        if not lo < hi:
            raise ValueError(f"span_c = [{lo}, {hi}]: the low edge must be below the high one")
        return self


class NoiseTable(_Strict):
    """The white noise measured in a calibration's still data (imud/calib/noise.py): one-sided
    density per axis of the corrected output (the two-sample variance at tau_s is
    density^2 / (2 tau_s)). The ROS 2 output's covariances use it in place of the datasheet's."""

    density: Vec3
    tau_s: float = Field(gt=0)
    differences: int = Field(ge=1)
    still_s: float = Field(gt=0)
    date: str | None = None

    @model_validator(mode="after")
    def _positive(self) -> NoiseTable:
        if not all(math.isfinite(d) and d > 0 for d in self.density):
            raise ValueError(f"density = {list(self.density)}: every axis must be above zero")
        return self


class SensorTable(_Strict):
    """corrected = matrix @ (raw - bias - temperature term)."""

    bias: Vec3 = (0.0, 0.0, 0.0)
    matrix: tuple[Vec3, Vec3, Vec3] | None = None
    scale: Vec3 | None = None
    procedure: str | None = None
    date: str | None = None
    source: str | None = None
    temperature_c: float | None = None
    gravity: float | None = None
    field_t: float | None = None
    residuals: dict[str, float] = Field(default_factory=dict)
    fit: FitTable | None = None
    notes: list[str] = Field(default_factory=list)
    temperature: TempTable | None = None
    noise: NoiseTable | None = None
    # the gyro's bias per m/s^2 of specific force (imud/calib/gsens.py), rad/s per m/s^2
    g_sensitivity: tuple[Vec3, Vec3, Vec3] | None = None

    @model_validator(mode="after")
    def _one_of(self) -> SensorTable:
        if self.scale is not None and self.matrix is not None:
            raise ValueError("give either 'scale' or 'matrix', not both (matrix includes scale)")
        m = self.transform()
        if not np.isfinite(m).all():
            raise ValueError("matrix has a value that is not finite")
        cond = float(np.linalg.cond(m))
        if not math.isfinite(cond) or abs(float(np.linalg.det(m))) < 1e-12:
            raise ValueError("matrix is singular: it would map different readings to one value")
        if cond > MAX_CONDITION:
            raise ValueError(
                f"matrix is ill-conditioned (condition number {cond:.3g} > {MAX_CONDITION:g}): a "
                "calibration undoes scale and misalignment errors of a few percent; recalibrate"
            )
        if float(np.linalg.det(m)) < 0:
            raise ValueError(
                "matrix has a negative determinant (it mirrors the axes): a calibration only "
                "corrects scale and misalignment; fix the axis signs instead"
            )
        return self

    def transform(self) -> np.ndarray[Any, np.dtype[np.float64]]:
        if self.matrix is not None:
            return np.asarray(self.matrix, dtype=np.float64)
        return np.diag(np.asarray(self.scale if self.scale is not None else (1.0, 1.0, 1.0)))


class CalibrationFile(_Strict):
    format: Literal["imud-calibration"] = "imud-calibration"
    version: Literal[1, 2] = 2
    chip: str | None = None
    device: str | None = None
    written: str | None = None
    accel: SensorTable | None = None
    gyro: SensorTable | None = None
    mag: SensorTable | None = None

    def sensor(self, name: str) -> SensorTable | None:
        return {"accel": self.accel, "gyro": self.gyro, "mag": self.mag}[name]

    @model_validator(mode="after")
    def _g_sensitivity_is_the_gyros(self) -> CalibrationFile:
        for name in ("accel", "mag"):
            t = self.sensor(name)
            if t is not None and t.g_sensitivity is not None:
                raise ValueError(
                    f"[{name}] g_sensitivity: only the gyro's bias follows the specific force; "
                    "move it to [gyro] or delete it"
                )
        return self


def _where(loc: tuple[int | str, ...]) -> str:
    return ".".join(str(p) for p in loc) or "(top level)"


def parse_calibration(raw: dict[str, Any], where: str = "calibration file") -> CalibrationFile:
    try:
        return CalibrationFile.model_validate(raw)
    except ValidationError as e:
        msgs = "; ".join(f"{_where(err['loc'])}: {err['msg']}" for err in e.errors())
        raise CalibrationError(f"{where}: {msgs}") from None


def read_calibration(path: Path) -> CalibrationFile:
    """Parse and validate a file (without checking it against a device)."""
    try:
        with open(path, "rb") as f:
            raw = tomllib.load(f)
    except FileNotFoundError as e:
        raise CalibrationError(
            f"calibration file {path} does not exist: write one with `imud calibrate`"
        ) from e
    except tomllib.TOMLDecodeError as e:
        raise CalibrationError(f"calibration file {path}: TOML syntax error: {e}") from e
    except UnicodeDecodeError as e:
        raise CalibrationError(f"calibration file {path}: not UTF-8 text (byte {e.start})") from e
    except OSError as e:  # a directory, no permission, ...
        raise CalibrationError(f"calibration file {path}: cannot read: {e.strerror}") from e
    return parse_calibration(raw, f"calibration file {path}")


def sensor_model(t: SensorTable) -> SensorModel:
    """What the pipeline applies for one sensor's table."""
    temp = None
    if t.temperature is not None:
        tt = t.temperature
        temp = TempPoly(tt.reference_c, np.asarray(tt.coefficients, dtype=np.float64),
                        (float(tt.span_c[0]), float(tt.span_c[1])))  # fmt: skip
    g = None if t.g_sensitivity is None else np.asarray(t.g_sensitivity, dtype=np.float64)
    return SensorModel(np.asarray(t.bias, dtype=np.float64), t.transform(), temp, g)


def to_model(cf: CalibrationFile, path: Path) -> CalibrationModel:
    return CalibrationModel(
        path,
        *(None if (t := cf.sensor(s)) is None else sensor_model(t) for s in _SENSOR_CHANNEL),
    )


def check_for_device(cf: CalibrationFile, path: Path, chip: str, channels: Channel) -> list[str]:
    """Why this file cannot serve a device of `chip` producing `channels` (empty: it can)."""
    problems = []
    if cf.chip is not None and cf.chip != chip:
        problems.append(
            f"calibration file {path} was made for a {cf.chip}, this device is a {chip}: "
            "calibrate this device, or point `calibration` at its own file"
        )
    for name, ch in _SENSOR_CHANNEL.items():
        t = cf.sensor(name)
        if t is None:
            continue
        if not channels & ch:
            problems.append(f"calibration file {path}: [{name}]: a {chip} has no {name} channel")
        if t.temperature is not None and not channels & Channel.TEMPERATURE:
            problems.append(
                f"calibration file {path}: [{name}.temperature]: a {chip} reports no temperature"
            )
    return problems


def load_calibration(
    path: Path, chip: str | None = None, channels: Channel | None = None
) -> CalibrationModel:
    """Read, validate and (given the device's chip and channels) check a file, ready to apply."""
    cf = read_calibration(path)
    if chip is not None and channels is not None:
        problems = check_for_device(cf, path, chip, channels)
        if problems:
            raise CalibrationError("; ".join(problems))
    return to_model(cf, path)


# --- writing -------------------------------------------------------------------------------------


def now_iso() -> str:
    return dt.datetime.now(dt.UTC).replace(microsecond=0).isoformat().replace("+00:00", "Z")


_ESCAPES = {
    '"': '\\"',
    "\\": "\\\\",
    "\b": "\\b",
    "\t": "\\t",
    "\n": "\\n",
    "\f": "\\f",
    "\r": "\\r",
}


def _char(c: str) -> str:
    """One character of a TOML basic string: quote and backslash escaped, and every control
    character (TOML allows none in a string but tab), so any note or source path reads back. A
    lone surrogate (a file name's undecodable byte) has no escape in TOML: U+FFFD stands in."""
    if c in _ESCAPES:
        return _ESCAPES[c]
    o = ord(c)
    if o < 0x20 or o == 0x7F:
        return f"\\u{o:04x}"
    if 0xD800 <= o <= 0xDFFF:
        return "\ufffd"
    return c


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float | np.floating | np.integer):
        f = float(v)
        if isinstance(v, int | np.integer) and not isinstance(v, bool):
            return str(int(v))
        return repr(f) if math.isfinite(f) else ("nan" if f != f else ("inf" if f > 0 else "-inf"))
    if isinstance(v, str):
        return '"' + "".join(map(_char, v)) + '"'
    if isinstance(v, list | tuple):
        items = [_value(x) for x in v]
        if any(isinstance(x, list | tuple) for x in v):
            return "[\n  " + ",\n  ".join(items) + ",\n]"
        return "[" + ", ".join(items) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


_COMMENTS = {
    "accel": "accelerometer: corrected = matrix @ (raw - bias - temperature term), m/s^2",
    "gyro": "gyroscope: corrected = matrix @ (raw - bias - temperature term), rad/s",
    "mag": "magnetometer: corrected = matrix @ (raw - bias); bias is the hard iron, tesla",
}


def _emit(table: dict[str, Any], name: str, out: list[str], comment: str | None = None) -> None:
    scalars = {k: v for k, v in table.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in table.items() if isinstance(v, dict)}
    if name:
        out.append("")
        if comment:
            out.append(f"# {comment}")
        out.append(f"[{name}]")
    for k, v in scalars.items():
        out.append(f"{k} = {_value(v)}")
    for k, v in tables.items():
        _emit(v, f"{name}.{k}" if name else k, out, _COMMENTS.get(k) if not name else None)


def to_toml(cf: CalibrationFile) -> str:
    """The file's text. Floats are written with repr, which reads back bit-exactly."""
    data = cf.model_dump(exclude_none=True)
    for s in _SENSOR_CHANNEL:
        t = data.get(s)
        if t is not None:
            for key in ("residuals", "notes"):
                if not t.get(key):
                    t.pop(key, None)
            temp = t.get("temperature")
            if temp is not None:
                for key in ("residuals", "notes"):
                    if not temp.get(key):
                        temp.pop(key, None)
    out = [
        "# imud calibration file (docs/calibration.md). Written by `imud calibrate`; the daemon",
        "# picks up a changed file without a restart.",
    ]
    _emit(data, "", out)
    return "\n".join(out) + "\n"


def write_calibration(path: Path, cf: CalibrationFile) -> None:
    """Atomically replace `path` (validated first: nothing unreadable is ever written)."""
    text = to_toml(cf)
    parse_calibration(tomllib.loads(text), f"calibration to write to {path}")
    write_atomic(path, text)


def load_or_new(path: Path, chip: str | None, device: str | None) -> CalibrationFile:
    """The file a procedure updates: the existing one (its other sensors are kept), or a new one.
    `chip`/`device` None: not known (an offline recording that does not say); the file's own
    are kept."""
    if path.exists():
        cf = read_calibration(path)
        if chip is not None and cf.chip is not None and cf.chip != chip:
            raise CalibrationError(
                f"{path} holds a calibration for a {cf.chip}, not a {chip}: give another --out"
            )
        update = {"chip": chip or cf.chip, "device": device or cf.device, "version": VERSION}
        return cf.model_copy(update=update)
    return CalibrationFile(chip=chip, device=device)


# --- from an estimate to the file ----------------------------------------------------------------


def _fit_table(names: tuple[str, ...], values: Any, cov: Any) -> FitTable:
    c = np.asarray(cov, dtype=np.float64)
    c = 0.5 * (c + c.T)  # an estimator's rounding: the covariance is symmetric by definition
    try:
        return FitTable(
            names=list(names),
            values=[float(v) for v in np.asarray(values).ravel()],
            covariance=[[float(x) for x in row] for row in c],
        )
    except ValidationError as e:  # a fit whose numbers cannot be a covariance: say so
        msgs = "; ".join(f"{_where(err['loc'])}: {err['msg']}" for err in e.errors())
        raise CalibrationError(
            f"the fit's parameter covariance cannot be written ({msgs}): the data did not "
            "determine the parameters; capture more, or over a wider span"
        ) from None


def _finite(d: dict[str, float]) -> dict[str, float]:
    return {k: float(v) for k, v in d.items() if isinstance(v, int | float) and math.isfinite(v)}


def with_affine(
    cf: CalibrationFile, est: AffineEstimate, source: str, g_sensitivity: Any = None
) -> CalibrationFile:
    """`cf` with one sensor's bias and matrix replaced by an estimate (its temperature
    polynomial, if any, is kept: the estimate was made on temperature-compensated data)."""
    old = cf.sensor(est.sensor)
    try:
        table = _affine_table(est, source, old, g_sensitivity)
    except ValidationError as e:  # a fit no file can hold (singular, mirrored, ill-conditioned)
        msgs = "; ".join(f"{_where(err['loc'])}: {err['msg']}" for err in e.errors())
        raise CalibrationError(f"[{est.sensor}] cannot be written: {msgs}") from None
    return cf.model_copy(update={est.sensor: table, "written": now_iso()})


def _affine_table(
    est: AffineEstimate, source: str, old: SensorTable | None, g_sensitivity: Any = None
) -> SensorTable:
    g = None
    if g_sensitivity is not None:
        g = tuple(tuple(float(x) for x in row) for row in np.asarray(g_sensitivity))
    return SensorTable(
        bias=tuple(float(x) for x in est.bias),
        matrix=tuple(tuple(float(x) for x in row) for row in est.matrix),
        procedure=est.procedure,
        date=now_iso(),
        source=source,
        temperature_c=est.temperature_c,
        gravity=est.gravity,
        field_t=est.field_t,
        residuals=_finite(est.fit.residuals),
        fit=_fit_table(est.fit.names, est.fit.values, est.fit.covariance),
        notes=list(est.verdict.reasons),
        temperature=None if old is None else old.temperature,
        noise=None if old is None else old.noise,  # until this procedure measures it anew
        g_sensitivity=g,  # what this calibration found (None: none, or not tested)
    )


def with_noise(cf: CalibrationFile, sensor: str, measured: MeasuredNoise) -> CalibrationFile:
    """`cf` with `sensor`'s measured noise replaced (its table must exist)."""
    old = cf.sensor(sensor)
    if old is None:
        raise ValueError(f"no [{sensor}] table to add noise to")
    noise = NoiseTable(
        density=tuple(float(x) for x in measured.density),
        tau_s=measured.tau_s,
        differences=measured.differences,
        still_s=measured.still_s,
        date=now_iso(),
    )
    return cf.model_copy(update={sensor: old.model_copy(update={"noise": noise})})


def with_temperature(cf: CalibrationFile, est: TempEstimate, source: str) -> CalibrationFile:
    """`cf` with one sensor's temperature polynomial replaced. A bias already in the file was
    estimated at its capture temperature without compensation; it is moved to the polynomial's
    reference temperature so the corrected output at that temperature stays what it was."""
    temp = TempTable(
        reference_c=est.reference_c,
        span_c=est.span_c,
        coefficients=[tuple(float(x) for x in row) for row in est.coefficients],
        procedure="temp",
        date=now_iso(),
        source=source,
        residuals=_finite(est.fit.residuals),
        fit=_fit_table(est.fit.names, est.fit.values, est.fit.covariance),
        notes=list(est.verdict.reasons),
    )
    old = cf.sensor(est.sensor)
    if old is None:
        table = SensorTable(temperature=temp)
    else:
        bias = np.asarray(old.bias, dtype=np.float64)
        if old.temperature_c is not None and old.temperature is None:
            poly = TempPoly(est.reference_c, est.coefficients, est.span_c)
            p, _ = poly.offset(np.array([old.temperature_c]))
            bias = bias - p[0]
        table = old.model_copy(update={"temperature": temp, "bias": tuple(float(x) for x in bias)})
    return cf.model_copy(update={est.sensor: table, "written": now_iso()})
