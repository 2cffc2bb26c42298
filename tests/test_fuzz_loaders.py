"""Every loader fed garbage, with hypothesis (issue 10): the config file (as the daemon and the
CLI load it), the calibration file, the CSV recording and the BNO055 offsets file. Whatever
the file holds, loading returns a valid result or raises the loader's own error with a message
(`ConfigError`, `CalibrationError`, `CsvError`, `OffsetsError`); what imud writes reads back
exactly. See tests/test_fuzz_decoders.py for the settings (and bench/fuzz_long.py)."""

from __future__ import annotations

import atexit
import copy
import json
import math
import shutil
import tempfile
import tomllib
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from imud.calib import csvio
from imud.calib.csvio import CsvError, CsvWriter, read_csv
from imud.calib.file import (
    CalibrationError,
    CalibrationFile,
    FitTable,
    SensorTable,
    TempTable,
    load_calibration,
    parse_calibration,
    to_toml,
)
from imud.calib.recording import Recording
from imud.calib.watch import calibration_problems
from imud.channels import Channel
from imud.config import ImudConfig, load_config, parse_config
from imud.errors import ConfigError
from tests.test_fuzz_decoders import fuzz

REPO = Path(__file__).resolve().parent.parent
_scratch: Path | None = None


def scratch() -> Path:
    """One directory for the whole run (pytest's tmp_path is per test, not per example)."""
    global _scratch
    if _scratch is None:
        _scratch = Path(tempfile.mkdtemp(prefix="imud-fuzz-"))
        atexit.register(shutil.rmtree, _scratch, True)
    return _scratch


def put(name: str, content: str | bytes) -> Path:
    p = scratch() / name
    p.write_bytes(content.encode() if isinstance(content, str) else content)
    return p


# --- TOML text from values (tomllib reads; nothing in the venv writes) -----------------------


def toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if v != v else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # JSON's escapes are TOML's
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        items = (f"{json.dumps(str(k))} = {toml_value(x)}" for k, x in v.items())
        return "{" + ", ".join(items) + "}"
    raise TypeError(type(v))


def toml_text(d: dict[str, Any]) -> str:
    return "".join(f"{json.dumps(str(k))} = {toml_value(v)}\n" for k, v in d.items())


# Values of every TOML type, keys mostly the config's own names, so the fuzz goes deep
KEYS = st.sampled_from([
    "daemon", "zenoh", "device", "name", "chip", "bus", "gyro_bus", "kind", "bus", "address",
    "transport", "cs", "speed_hz", "path", "port", "baud", "odr_hz", "accel_odr_hz", "sim",
    "motion", "rate_dps", "seed", "truth", "calibration", "gyro_range_dps", "accel_range_g",
    "mode", "listen", "connect", "prefix", "options", "realtime_priority", "bus_processes",
    "dlpf_hz", "hires", "datagram", "model", "deltas", "gyro_bias_tracking", "enabled",
    "faults", "offsets_file", "accel", "gyro", "mag", "bias", "matrix", "format", "version",
]) | st.text(max_size=8)  # fmt: skip
SCALARS = (
    st.integers(-(2**63), 2**63 - 1)
    | st.floats()
    | st.booleans()
    | st.text(max_size=12)
    | st.sampled_from(["sim", "i2c", "spi", "serial", "mpu6050", "bmi088", "icm42688p",
                       "bno055", "stim300", "adis16465", "tcp/127.0.0.1:7450", "ndof", "still"])
)  # fmt: skip
VALUES = st.recursive(
    SCALARS,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(KEYS, inner, max_size=5),
    max_leaves=20,
)


@st.composite
def mutated(draw: st.DrawFn, base: dict[str, Any]) -> dict[str, Any]:
    """`base` with a few of its keys replaced by any value, removed, or joined by another."""
    d = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        node: Any = d
        while True:  # walk down to a table or array
            keys = list(node) if isinstance(node, dict) else list(range(len(node)))
            if not keys:
                break
            k = draw(st.sampled_from(keys))
            if not isinstance(node[k], dict | list) or draw(st.booleans()):
                break
            node = node[k]
        if isinstance(node, dict):
            how = draw(st.sampled_from(["set", "set", "drop", "add"]))
            if how == "add" or not node:
                node[draw(KEYS)] = draw(VALUES)
            elif how == "drop":
                del node[draw(st.sampled_from(list(node)))]
            else:
                node[draw(st.sampled_from(list(node)))] = draw(VALUES)
        elif node:
            node[draw(st.integers(0, len(node) - 1))] = draw(VALUES)
    return d


# --- the config file -------------------------------------------------------------------------

CONFIGS = sorted((REPO / "configs").glob("*.toml"))
BASES = [tomllib.loads(p.read_text()) for p in CONFIGS]


def load_or_config_error(path: Path) -> ImudConfig | None:
    try:
        cfg = load_config(path)
    except ConfigError as e:
        assert e.messages and all(isinstance(m, str) and m.strip() for m in e.messages)
        return None
    errors, notes = calibration_problems(cfg)  # what check-config and the daemon do next
    assert all(isinstance(m, str) for m in errors + notes)
    return cfg


@fuzz(40)
@given(st.text(max_size=300) | st.binary(max_size=300))
def test_config_of_arbitrary_text(text: str | bytes) -> None:
    load_or_config_error(put("garbage.toml", text))


@fuzz(40)
@given(st.dictionaries(KEYS, VALUES, max_size=4))
def test_config_of_arbitrary_tables(raw: dict[str, Any]) -> None:
    load_or_config_error(put("tables.toml", toml_text(raw)))


@fuzz(60)
@given(st.sampled_from(range(len(BASES))).flatmap(lambda i: mutated(BASES[i])))
def test_config_of_a_damaged_real_config(raw: dict[str, Any]) -> None:
    """The shipped configs with a few values changed, removed or added: each problem is a
    message naming where it is."""
    try:
        parse_config(raw, scratch())
    except ConfigError as e:
        assert e.messages and all(isinstance(m, str) and m.strip() for m in e.messages)
    load_or_config_error(put("damaged.toml", toml_text(raw)))


@fuzz(30)
@given(st.sampled_from(range(len(BASES))).flatmap(lambda i: mutated(BASES[i])))
def test_config_errors_name_the_device(raw: dict[str, Any]) -> None:
    """A message about a device says which ("device[1] 'imu1'")."""
    try:
        parse_config(raw, scratch())
    except ConfigError as e:
        for m in e.messages:
            assert not m.startswith(("device.", "'device'", "0.", "1.")), m


# --- the calibration file --------------------------------------------------------------------

CAL_BASE: dict[str, Any] = {
    "format": "imud-calibration",
    "version": 2,
    "chip": "mpu6050",
    "device": "imu0",
    "written": "2026-11-23T10:12:00Z",
    "accel": {
        "bias": [0.112, -0.051, 0.298],
        "matrix": [[1.0201, 0.0172, -0.0121], [0.0, 0.9803, 0.0088], [0.0, 0.0, 1.0099]],
        "procedure": "accel-9",
        "temperature_c": 31.2,
        "gravity": 9.80953,
        "residuals": {"rms": 0.0021, "chi2": 4.1},
        "fit": {
            "names": ["bx", "by"],
            "values": [0.112, -0.051],
            "covariance": [[1e-8, 0.0], [0.0, 1e-8]],
        },
        "temperature": {
            "reference_c": 30.0,
            "span_c": [10.0, 50.0],
            "coefficients": [[0.0021, -0.0013, 0.0048]],
        },
        "notes": ["ok"],
    },
    "gyro": {"bias": [0.0121, -0.0073, 0.0042], "scale": [1.0, 1.01, 0.99]},
    "mag": {"bias": [1e-6, 2e-6, 3e-6]},
}
CHANNELS = st.sampled_from([
    Channel.ACCEL | Channel.GYRO | Channel.TEMPERATURE,
    Channel.ACCEL | Channel.GYRO | Channel.TEMPERATURE | Channel.MAG,
    Channel.GYRO,
])  # fmt: skip


def load_or_calibration_error(path: Path, chip: str | None, channels: Channel | None) -> None:
    try:
        model = load_calibration(path, chip, channels)
    except CalibrationError as e:
        assert str(e).strip()
        return
    for s in (model.accel, model.gyro, model.mag):
        if s is not None:
            assert np.isfinite(s.matrix).all() and np.isfinite(s.bias).all()


@fuzz(40)
@given(st.text(max_size=300) | st.binary(max_size=300), CHANNELS)
def test_calibration_of_arbitrary_text(text: str | bytes, channels: Channel) -> None:
    load_or_calibration_error(put("garbage.cal.toml", text), "mpu6050", channels)


@fuzz(60)
@given(mutated(CAL_BASE), st.sampled_from([None, "mpu6050", "bno055"]), CHANNELS)
def test_calibration_of_a_damaged_real_file(
    raw: dict[str, Any], chip: str | None, channels: Channel
) -> None:
    load_or_calibration_error(put("damaged.cal.toml", toml_text(raw)), chip, channels)


FINITE = st.floats(-1e6, 1e6, allow_nan=False)
TEXT = st.text(max_size=20)
VEC = st.tuples(FINITE, FINITE, FINITE)


@st.composite
def sensor_tables(draw: st.DrawFn) -> SensorTable:
    p = draw(st.integers(0, 3))
    var = draw(st.lists(st.floats(0, 1e3), min_size=p, max_size=p))
    fit = FitTable(
        names=draw(st.lists(TEXT, min_size=p, max_size=p)),
        values=draw(st.lists(FINITE, min_size=p, max_size=p)),
        covariance=[[var[i] if i == j else 0.0 for j in range(p)] for i in range(p)],
    )
    lo = draw(st.floats(-50, 100))
    temp = TempTable(
        reference_c=draw(st.floats(-50, 100)),
        span_c=(lo, lo + draw(st.floats(0.5, 100))),
        coefficients=draw(st.lists(VEC, min_size=1, max_size=3)),
        procedure=draw(st.none() | TEXT),
        notes=draw(st.lists(TEXT, max_size=2)),
    )
    off = draw(st.lists(st.floats(-0.05, 0.05), min_size=9, max_size=9))
    m = np.eye(3) + np.asarray(off).reshape(3, 3)
    return SensorTable(
        bias=draw(VEC),
        matrix=tuple(tuple(float(x) for x in row) for row in m) if draw(st.booleans()) else None,  # type: ignore[arg-type]
        procedure=draw(st.none() | TEXT),
        source=draw(st.none() | TEXT),
        temperature_c=draw(st.none() | st.floats(-50, 100)),
        residuals=draw(st.dictionaries(st.sampled_from(["rms", "chi2", "p_value"]), FINITE)),
        fit=fit if p else None,
        notes=draw(st.lists(TEXT, max_size=3)),
        temperature=temp if draw(st.booleans()) else None,
    )


@fuzz(30)
@given(
    st.builds(
        CalibrationFile,
        chip=st.none() | st.sampled_from(["mpu6050", "bno055"]),
        device=st.none() | TEXT,
        written=st.none() | TEXT,
        accel=st.none() | sensor_tables(),
        gyro=st.none() | sensor_tables(),
        mag=st.none() | sensor_tables(),
    )
)
def test_calibration_file_round_trips(cf: CalibrationFile) -> None:
    """What `imud calibrate` writes reads back exactly, whatever its strings and numbers
    (the text `write_calibration` checks and then writes, without its fsyncs)."""
    assert parse_calibration(tomllib.loads(to_toml(cf))) == cf


# --- CSV recordings --------------------------------------------------------------------------

COLUMN_NAMES = st.sampled_from([
    "timestamp_ns", "ax", "ay", "az", "gx", "gy", "gz", "temp", "mx", "my", "mz", "flags",
    "time", "time_s", "t", "Time (s)", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z",
    "w_RS_S_x [rad s^-1]", "a_RS_S_x [m s^-2]", "AccX", "GyroZ", "mag_x", "n_samples", "index",
    "millis", "micros", "", "x", '"ax"', "ax [g]", "gx [deg/s]", "temperature",
])  # fmt: skip
CELLS = (
    st.integers(-(2**70), 2**70).map(str)
    | st.floats().map(repr)
    | st.floats(-20, 20).map(lambda f: f"{f:.6g}")
    | st.sampled_from(["", " ", "nan", "inf", "-inf", "0x10", "1e400", "1,5", '"1"', "#", "é"])
    | st.text(max_size=5)
)


@st.composite
def csv_texts(draw: st.DrawFn) -> bytes:
    """CSV-like files: a header of real and foreign names, rows of numbers and junk, comments,
    blank lines, ragged rows, CRLF, a byte order mark."""
    names = draw(st.lists(COLUMN_NAMES, min_size=1, max_size=12))
    if draw(st.booleans()):
        names = ["timestamp_ns", "ax", "ay", "az", "gx", "gy", "gz", *names[:3]]
    lines = [
        draw(st.sampled_from(["", "# device: x", "#"])) for _ in range(draw(st.integers(0, 2)))
    ]
    lines.append(("#" if draw(st.integers(0, 5)) == 0 else "") + ",".join(names))
    t = draw(st.integers(0, 2**62))
    step = draw(st.sampled_from([1, 1000, 1_000_000, 10_000_000, 5e-3, 0.01]))
    for i in range(draw(st.integers(0, 8))):
        k = len(names) + draw(st.sampled_from([0, 0, 0, 0, -1, 1]))
        cells = [draw(CELLS) for _ in range(max(k, 0))]
        if cells and draw(st.booleans()):
            cells[0] = str(t + i * step)
        lines.append(",".join(cells) + draw(st.sampled_from(["", "", " # note"])))
    text = draw(st.sampled_from(["\n", "\r\n", "\r"])).join(lines)
    bom = "\ufeff" if draw(st.integers(0, 9)) == 0 else ""
    return (bom + text + draw(st.sampled_from(["", "\n"]))).encode("utf-8", "surrogatepass")


OPTIONS = st.fixed_dictionaries(
    {},
    optional={
        "accel_units": st.sampled_from(["m/s2", "g"]),
        "gyro_units": st.sampled_from(["rad/s", "dps"]),
        "time_units": st.sampled_from(["s", "ms", "us", "ns"]),
        "rate_hz": st.floats(1, 5000),
    },
)


def read_or_csv_error(path: Path, options: dict[str, Any]) -> None:
    try:
        rec = read_csv(path, **options)
    except CsvError as e:
        assert str(path) in str(e) and e.reason.strip()
        return
    n = rec.t_ns.shape[0]
    assert n >= 2 and bool(np.all(np.diff(rec.t_ns) > 0))
    assert rec.accel.shape == rec.gyro.shape == (n, 3)
    assert np.isfinite(rec.accel).all() and np.isfinite(rec.gyro).all()


@fuzz(40)
@given(st.binary(max_size=300), OPTIONS)
def test_csv_of_arbitrary_bytes(data: bytes, options: dict[str, Any]) -> None:
    read_or_csv_error(put("garbage.csv", data), options)


@fuzz(80)
@given(csv_texts(), OPTIONS)
def test_csv_of_csv_like_text(data: bytes, options: dict[str, Any]) -> None:
    read_or_csv_error(put("like.csv", data), options)


def outcome(path: Path, options: dict[str, Any]) -> tuple[str, ...] | Recording:
    try:
        return read_csv(path, **options)
    except CsvError as e:
        return (str(e),)


@st.composite
def readable_csv_texts(draw: Any) -> bytes:
    """Files read_csv accepts, with what a line scan must get right: comments above, between
    and after rows, blank lines, any line end."""
    n = draw(st.integers(2, 30))
    lines = ["# device: d", "timestamp_ns,ax,ay,az,gx,gy,gz"]
    for i in range(n):
        if draw(st.integers(0, 4)) == 0:
            lines.append(draw(st.sampled_from(["", "# a note, with commas,", "   "])))
        row = f"{1000 + i * 10_000_000},0.1,{i * 0.01:.3f},9.8,0.001,-0.002,{i * 1e-4:.5f}"
        lines.append(row + draw(st.sampled_from(["", "", " # note"])))
    end = draw(st.sampled_from(["\n", "\r\n", "\r"]))
    return (end.join(lines) + draw(st.sampled_from(["", end]))).encode()


@fuzz(60)
@given(st.one_of(csv_texts(), readable_csv_texts()), OPTIONS, st.integers(1, 64))
def test_csv_scanned_in_pieces_reads_as_whole(
    data: bytes, options: dict[str, Any], piece: int
) -> None:
    """A large file's lines are scanned a piece at a time; pieces of a few bytes (lines cut
    anywhere, comments and CR line ends) give what the whole file scanned at once gives."""
    path = put("pieces.csv", data)
    whole = outcome(path, options)
    with mock.patch.object(csvio, "_SCAN_BYTES", piece):
        cut = outcome(path, options)
    if isinstance(whole, tuple) or isinstance(cut, tuple):
        assert whole == cut
        return
    assert np.array_equal(whole.t_ns, cut.t_ns)
    assert np.array_equal(whole.accel, cut.accel) and np.array_equal(whole.gyro, cut.gyro)


@fuzz(20)
@given(st.data(), st.integers(2, 40), st.booleans(), st.booleans())
def test_csv_round_trips(data: st.DataObject, n: int, temp: bool, mag: bool) -> None:
    """What imud records reads back bit for bit (within the physical ranges read_csv checks)."""
    f32 = np.float32

    def arr(lo: float, hi: float, shape: tuple[int, ...]) -> np.ndarray:
        vals = data.draw(st.lists(st.floats(lo, hi, width=32), min_size=math.prod(shape),
                                  max_size=math.prod(shape)))  # fmt: skip
        return np.asarray(vals, dtype=f32).reshape(shape)

    t0 = data.draw(st.integers(0, 2**62))
    steps = data.draw(st.lists(st.integers(900_000, 1_100_000), min_size=n - 1, max_size=n - 1))
    t = t0 + np.concatenate([[0], np.cumsum(steps)]).astype(np.int64)
    accel = arr(-1, 1, (n, 3)) + np.asarray([0, 0, 9.8], f32)
    gyro = arr(-30, 30, (n, 3))
    tc = arr(-40, 120, (n,)) if temp else None
    mc = (arr(-1, 1, (n, 3)) * f32(1e-5) + f32(4e-5)) if mag else None
    path = scratch() / "rt.csv"
    with CsvWriter(path, has_temp=temp, has_mag=mag, comments={"device": "x\ny:z"}) as w:
        w.write(t, accel, gyro, tc, mc)
    rec = read_csv(path)
    assert rec.t_ns.tolist() == t.tolist()
    assert np.array_equal(rec.accel.astype(f32), accel) and np.array_equal(
        rec.gyro.astype(f32), gyro
    )
    if tc is not None:
        assert rec.temp is not None and np.array_equal(rec.temp.astype(f32), tc)
    if mc is not None:
        assert rec.mag is not None and np.array_equal(rec.mag.astype(f32), mc)


# --- BNO055 offsets file ---------------------------------------------------------------------

INT16 = st.integers(-32768, 32767)


@fuzz(40)
@given(st.binary(max_size=30))
def test_bno055_profile_bytes(data: bytes) -> None:
    from imud.chips.bno055.offsets import Offsets, OffsetsError

    try:
        o = Offsets.from_bytes(data)
    except OffsetsError:
        assert len(data) != 22
        return
    assert o.to_bytes() == data


@fuzz(30)
@given(
    st.lists(INT16, min_size=11, max_size=11),
    st.from_regex(r"[A-Za-z0-9_-]{1,64}", fullmatch=True),  # a device name the config allows
    st.binary(min_size=16, max_size=16),
)
def test_bno055_offsets_file_round_trips(words: list[int], device: str, uid: bytes) -> None:
    from imud.chips.bno055.offsets import Offsets, load_offsets

    o = Offsets.from_bytes(np.asarray(words, dtype="<i2").tobytes())
    path = put("p.bno055-offsets.toml", o.to_toml(device, uid, 0x01, "2026-01-01T00:00:00Z"))
    assert load_offsets(path, 0x01, uid) == o


@fuzz(40)
@given(
    st.text(max_size=200)
    | st.binary(max_size=200)
    | st.dictionaries(KEYS | st.sampled_from(["uid", "unit_sel", "radius", "accel_offset"]),
                      VALUES, max_size=6).map(toml_text)
)  # fmt: skip
def test_bno055_offsets_of_arbitrary_files(content: str | bytes) -> None:
    from imud.chips.bno055.offsets import OffsetsError, load_offsets

    path = put("g.bno055-offsets.toml", content)
    try:
        load_offsets(path, 0x01, None)
    except OffsetsError as e:
        assert str(path) in str(e)
