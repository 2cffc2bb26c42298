"""Recordings as CSV (imud/calib/csvio.py, docs/recording-csv.md): what imud writes reads back
bit for bit, other tools' files read with the unit options, and every bad file is refused with
its line (as an editor numbers it) and column named."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from imud.calib.csvio import CsvError, CsvWriter, read_comments, read_csv

HEADER = "timestamp_ns,ax,ay,az,gx,gy,gz"
T0 = 1_700_000_000_123_456_789  # needs all 19 digits of an int64: a float64 would round it
DT = 10_000_000  # 100 Hz


def row(i: int, a: str = "0.1,-0.2,9.8", g: str = "0.01,0.02,-0.03") -> str:
    return f"{T0 + i * DT},{a},{g}"


def put(tmp_path: Path, text: str | bytes, name: str = "rec.csv") -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return path


def good(n: int = 5) -> list[str]:
    return [HEADER] + [row(i) for i in range(n)]


def refused(path: Path, **kw: str | float) -> CsvError:
    with pytest.raises(CsvError) as info:
        read_csv(path, **kw)  # type: ignore[arg-type]
    assert isinstance(info.value, ValueError)
    assert str(path) in str(info.value)
    return info.value


# --- round trip ------------------------------------------------------------------------------


def physical(n: int, seed: int) -> dict[str, np.ndarray]:
    """A still IMU tilted about x, float32 as on the wire: gravity 9.81 m/s^2 plus noise,
    gyro noise around a small bias, 25 degC, the Earth's field (48 uT)."""
    rng = np.random.default_rng(seed)
    tilt = 0.3
    g = 9.81 * np.array([0.0, math.sin(tilt), math.cos(tilt)])
    accel = (g + rng.normal(0, 0.02, (n, 3))).astype(np.float32)
    gyro = (np.array([0.002, -0.001, 0.003]) + rng.normal(0, 0.004, (n, 3))).astype(np.float32)
    temp = (25 + rng.normal(0, 0.05, n)).astype(np.float32)
    mag = (np.array([20e-6, 1e-6, -44e-6]) + rng.normal(0, 2e-7, (n, 3))).astype(np.float32)
    flags = np.zeros(n, np.uint32)
    t = T0 + np.arange(n, dtype=np.int64) * DT + rng.integers(0, 1000, n)
    return {"t": t, "accel": accel, "gyro": gyro, "temp": temp, "mag": mag, "flags": flags}


def same_bits(read: np.ndarray, written: np.ndarray) -> bool:
    return bool(np.array_equal(read.astype(np.float32).view(np.uint32), written.view(np.uint32)))


def test_round_trip_is_bit_exact_for_float32(tmp_path: Path) -> None:
    d = physical(3000, seed=1)
    d["flags"][[3, 7]] = 1 << 16  # accel at full scale
    d["flags"][11] = 1 << 18  # mag at full scale
    d["flags"][12] = 1 << 24  # a chip alarm: not saturation
    # values that stress the decimal form: extremes, a subnormal, negative zero (in few rows,
    # so the medians the unit checks look at stay physical)
    d["accel"][20] = [np.finfo(np.float32).max, np.finfo(np.float32).tiny, -0.0]
    d["gyro"][21] = [np.float32(1.4e-45), np.nextafter(np.float32(1), np.float32(2)), -1e-30]
    path = tmp_path / "rec.csv"
    comments = {"device": "m0", "samples": "raw", "date": "2026-01-02T03:04:05Z"}
    with CsvWriter(path, has_temp=True, has_mag=True, has_flags=True, comments=comments) as w:
        for a, b in ((0, 1), (1, 1000), (1000, 1000), (1000, 3000)):  # batches of 1, 999, 0, 2000
            w.write(
                d["t"][a:b], d["accel"][a:b], d["gyro"][a:b], d["temp"][a:b], d["mag"][a:b],
                d["flags"][a:b],
            )  # fmt: skip
    assert w.rows == 3000
    rec = read_csv(path)
    assert rec.source == str(path) and rec.n == 3000
    assert rec.t_ns.dtype == np.int64 and np.array_equal(rec.t_ns, d["t"])
    assert rec.temp is not None and rec.mag is not None and rec.saturated is not None
    for got, want in ((rec.accel, d["accel"]), (rec.gyro, d["gyro"]), (rec.temp, d["temp"])):
        assert same_bits(got, want)
    assert same_bits(rec.mag, d["mag"])
    assert rec.saturated.tolist() == [i in (3, 7, 11) for i in range(3000)]
    assert read_comments(path) == {**read_comments(path), **comments}
    assert "format" in read_comments(path)


def test_round_trip_of_the_required_columns_alone(tmp_path: Path) -> None:
    d = physical(50, seed=2)
    path = tmp_path / "six.csv"
    with CsvWriter(path) as w:
        w.write(d["t"], d["accel"], d["gyro"])
    assert path.read_text().splitlines()[1] == HEADER
    rec = read_csv(path)
    assert rec.temp is None and rec.mag is None and rec.saturated is None
    assert same_bits(rec.accel, d["accel"]) and same_bits(rec.gyro, d["gyro"])


def test_the_file_appears_only_when_closed(tmp_path: Path) -> None:
    d = physical(10, seed=3)
    path = tmp_path / "rec.csv"
    with CsvWriter(path) as w:
        w.write(d["t"], d["accel"], d["gyro"])
        assert not path.exists()  # a reader cannot see half a file
    assert path.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.csv"]  # no temporary left


def test_an_exception_keeps_the_partial_file_and_says_where(tmp_path: Path) -> None:
    d = physical(10, seed=4)
    path = tmp_path / "rec.csv"
    with pytest.raises(RuntimeError) as info, CsvWriter(path) as w:
        w.write(d["t"], d["accel"], d["gyro"])
        raise RuntimeError("the device went away")
    partial = tmp_path / "rec.csv.partial"
    assert not path.exists() and partial.exists()
    assert any(str(partial) in note for note in info.value.__notes__)
    assert w.partial_path == partial
    assert read_csv(partial).n == 10  # what was written is whole rows


def test_the_writer_refuses_what_the_reader_would(tmp_path: Path) -> None:
    d = physical(10, seed=5)
    t, a, g = d["t"], d["accel"], d["gyro"]
    b, c = tmp_path / "b.csv", tmp_path / "c.csv"
    with pytest.raises(ValueError, match="not finite in sample 4"), CsvWriter(tmp_path / "a") as w:
        bad = a.copy()
        bad[4, 1] = np.nan
        w.write(t, bad, g)
    with pytest.raises(ValueError, match="does not increase at sample 0"), CsvWriter(b) as w:
        w.write(t[:5], a[:5], g[:5])
        w.write(t[4:], a[4:], g[4:])  # the last stamp again
    with (
        pytest.raises(ValueError, match="temp missing: the writer was opened with"),
        CsvWriter(c, has_temp=True) as w,
    ):
        w.write(t, a, g)
    with pytest.raises(ValueError, match="mag given: no"), CsvWriter(c) as w:
        w.write(t, a, g, mag=d["mag"])
    with pytest.raises(ValueError, match=r"accel has shape \(10, 2\)"), CsvWriter(c) as w:
        w.write(t, a[:, :2], g)
    with pytest.raises(ValueError, match="flags must be 32-bit"), CsvWriter(c, has_flags=True) as w:
        w.write(t, a, g, flags=np.full(10, -1))
    assert not c.exists() and (tmp_path / "c.csv.partial").exists()


# --- units -----------------------------------------------------------------------------------


def test_unit_options_convert_to_si(tmp_path: Path) -> None:
    lines = ["timestamp_ns,ax,ay,az,gx,gy,gz,mx,my,mz"] + [
        f"{T0 + i * DT},0,0.6,0.8,90,-45,180,30,-20,40" for i in range(4)
    ]
    path = put(tmp_path, "\n".join(lines) + "\n")
    rec = read_csv(path, accel_units="g", gyro_units="dps", mag_units="uT", gravity=9.81)
    np.testing.assert_allclose(rec.accel[0], [0.0, 5.886, 7.848], rtol=1e-15)  # 0.6 g, 0.8 g
    np.testing.assert_allclose(rec.gyro[0], [math.pi / 2, -math.pi / 4, math.pi], rtol=1e-15)
    assert rec.mag is not None
    np.testing.assert_allclose(rec.mag[0], [30e-6, -20e-6, 40e-6], rtol=1e-15)
    other_g = read_csv(path, accel_units="g", gyro_units="dps", mag_units="uT", gravity=9.78)
    assert other_g.accel[0, 2] == pytest.approx(0.8 * 9.78, rel=1e-15)


def test_unit_options_are_checked(tmp_path: Path) -> None:
    path = put(tmp_path, "\n".join(good()))
    with pytest.raises(ValueError, match="accel_units"):
        read_csv(path, accel_units="mg")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="gravity"):
        read_csv(path, gravity=0.0)


def table(a: str, g: str = "0.01,0.02,-0.03", extra: str = "", n: int = 6) -> str:
    head = HEADER + (",mx,my,mz" if extra.count(",") == 3 else ",temp" if extra else "")
    return "\n".join([head] + [row(i, a, g) + extra for i in range(n)]) + "\n"


@pytest.mark.parametrize(
    ("text", "units", "column", "hint"),
    [
        (table("0,0.6,0.8"), {}, "ax, ay, az", "looks like g: pass --accel-units g"),
        (table("0,5.9,7.8"), {"accel_units": "g"}, "ax, ay, az", "--accel-units m/s2"),
        (table("0,0,0.05"), {}, "ax, ay, az", "gravity removed"),
        (table("0,0,9.8", "100,-200,50"), {}, "gx, gy, gz", "looks like dps: pass --gyro-units"),
        (table("0,0,9.8", extra=",30,-20,40"), {}, "mx, my, mz", "looks like uT: pass --mag-units"),
        (table("0,0,9.8", extra=",3e-5,-2e-5,4e-5"), {"mag_units": "uT"}, "mx, my, mz",
         "looks like tesla: pass --mag-units T"),
        (table("0,0,9.8", extra=",298.15"), {}, "temp", "looks like kelvin"),
    ],
)  # fmt: skip
def test_units_wrong_by_orders_of_magnitude_are_named(
    tmp_path: Path, text: str, units: dict[str, str], column: str, hint: str
) -> None:
    err = refused(put(tmp_path, text), **units)
    assert err.column == column and f"column {column}" in str(err)
    assert hint in str(err)


def test_plausible_units_pass(tmp_path: Path) -> None:
    rec = read_csv(put(tmp_path, table("0,0,9.8", "3,-2,1", ",2e-5,0,-4.4e-5")))
    assert rec.mag is not None and rec.gyro[0, 0] == 3.0


# --- what is tolerated -----------------------------------------------------------------------


def test_bom_crlf_comments_blank_lines_and_extra_columns(tmp_path: Path) -> None:
    text = (
        "\ufeff# device: m0\r\n"
        "# chip: test\r\n"
        "\r\n"
        " Timestamp_NS , frame , ax,ay,az,gx,gy,gz, note\r\n"
        f"{T0},a,0.1,-0.2,9.8,0.01,0.02,-0.03,hello\r\n"
        "# a comment between rows\r\n"
        "   \r\n"
        f"{T0 + DT},b,0.2,-0.1,9.7,0.01,0.02,-0.03,x # and one after a row\r\n"
        f"{T0 + 2 * DT},c, 0.3 ,-0.1,9.9,0.01,0.02,-0.04,\r\n"
    )
    path = put(tmp_path, text)
    rec = read_csv(path)
    assert rec.t_ns.tolist() == [T0, T0 + DT, T0 + 2 * DT]
    assert rec.accel[:, 0].tolist() == [0.1, 0.2, 0.3]
    assert rec.gyro[2].tolist() == [0.01, 0.02, -0.04]
    assert read_comments(path) == {"device": "m0", "chip": "test"}
    # line numbers still count what an editor shows: the BOM, CR and comments change nothing
    bad = text.replace("c, 0.3 ,", "c, x ,")
    err = refused(put(tmp_path, bad, "bad.csv"))
    assert (err.line, err.column) == (9, "ax") and ":9: column ax: 'x' is not a number" in str(err)


def test_columns_in_any_order(tmp_path: Path) -> None:
    text = "gz,gy,gx,az,ay,ax,timestamp_ns,temp\n" + "".join(
        f"-0.03,0.02,0.01,9.8,-0.2,0.1,{T0 + i * DT},{20 + i}\n" for i in range(3)
    )
    rec = read_csv(put(tmp_path, text))
    assert rec.accel[0].tolist() == [0.1, -0.2, 9.8] and rec.gyro[0].tolist() == [0.01, 0.02, -0.03]
    assert rec.temp is not None and rec.temp.tolist() == [20.0, 21.0, 22.0]


# --- what is refused -------------------------------------------------------------------------


def test_missing_required_columns(tmp_path: Path) -> None:
    text = "# one\n# two\ntimestamp_ns,ax,ay,az,gx,gy,extra\n" + f"{row(0)}\n{row(1)}\n"
    err = refused(put(tmp_path, text))
    assert err.line == 3 and ":3: missing required columns gz;" in str(err)
    assert "the header has: timestamp_ns, ax, ay, az, gx, gy, extra" in str(err)


@pytest.mark.parametrize(
    ("header", "says"),
    [
        # names outside the table of other tools' names (docs/recording-csv.md) get renames
        ("timestamp_ns,imu_acc_x,imu_acc_y,imu_acc_z,gyro_x_dps,gyro_y_dps,gyro_z_dps",
         ["another tool's names", "imu_acc_x -> ax", "imu_acc_z -> az", "gyro_x_dps -> gx",
          "gyro_z_dps -> gz"]),
        # names in the table are read; a time that states no unit needs --time-units
        ("time,acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z",
         ["column time: its name does not say its unit", "pass --time-units ms"]),
        # ROS's %time is when the bag got the message, not the sample's time: not read
        ("%time,field.linear_acceleration.x,field.linear_acceleration.y,"
         "field.linear_acceleration.z,field.angular_velocity.x,field.angular_velocity.y,"
         "field.angular_velocity.z",
         ["missing required columns timestamp_ns", "%time -> timestamp_ns"]),
    ],
)  # fmt: skip
def test_another_tools_header_is_read_or_gets_the_renames(
    tmp_path: Path, header: str, says: list[str]
) -> None:
    n = header.count(",") + 1
    # times 1, 2, 3: in ms a 1 kHz recording, the unit the hint names
    text = header + "\n" + "\n".join(",".join([str(i + 1)] * n) for i in range(3)) + "\n"
    err = refused(put(tmp_path, text))
    assert err.line == 1
    for s in says:
        assert s in str(err)


@pytest.mark.parametrize(
    ("lines", "line", "column", "says"),
    [
        ([HEADER, row(0), row(1, "0.1,abc,9.8")], 3, "ay", "'abc' is not a number"),
        ([HEADER, row(0), row(1), row(2, "0.1,,9.8")], 4, "ay", "empty value"),
        ([HEADER, row(0), "1.7e18,0.1,-0.2,9.8,0.01,0.02,-0.03"], 3, "timestamp_ns",
         "'1.7e18' is not an integer (timestamp_ns counts nanoseconds)"),
        ([HEADER, row(0), row(1, g="0.01,nan,-0.03")], 3, "gy", "nan is not a finite number"),
        ([HEADER, row(0), row(1), row(2, "0.1,-0.2,inf")], 4, "az", "inf is not a finite"),
        ([HEADER + ",flags", row(0) + ",0", row(1) + ",-1"], 3, "flags", "not a 32-bit flag"),
        ([HEADER + ",flags", row(0) + ",0", row(1) + ",65536.5"], 3, "flags", "not an integer"),
    ],
)  # fmt: skip
def test_bad_values_are_named_by_line_and_column(
    tmp_path: Path, lines: list[str], line: int, column: str, says: str
) -> None:
    err = refused(put(tmp_path, "\n".join(lines) + "\n"))
    assert (err.line, err.column) == (line, column)
    assert f":{line}: column {column}: " in str(err) and says in str(err)


def test_a_bad_value_deep_in_a_long_file_is_found(tmp_path: Path) -> None:
    lines = [HEADER] + [row(i) for i in range(5000)]
    lines[3777] = row(3776, g="0.01,0.02,0x1f")  # file line 3778
    err = refused(put(tmp_path, "# c\n" + "\n".join(lines)))  # the comment makes it line 3779
    assert (err.line, err.column) == (3779, "gz") and "'0x1f' is not a number" in str(err)


def test_wrong_number_of_fields(tmp_path: Path) -> None:
    short = [HEADER, row(0), row(1), f"{T0 + 2 * DT},0.1,-0.2,9.8,0.01", row(3)]
    err = refused(put(tmp_path, "\n".join(short)))
    assert err.line == 4 and err.column == "gy"
    assert "5 fields where the header (line 1) names 7" in str(err)
    long = [HEADER, row(0), row(1) + ",7", row(2)]
    err = refused(put(tmp_path, "\n".join(long), "long.csv"))
    assert err.line == 3 and "8 fields where the header (line 1) names 7" in str(err)


def test_too_short(tmp_path: Path) -> None:
    err = refused(put(tmp_path, "# c\n" + "\n".join(good(1)) + "\n"))
    assert "1 sample: at least 2 are needed" in str(err)
    err = refused(put(tmp_path, HEADER + "\n", "empty.csv"))
    assert "0 samples: at least 2 are needed" in str(err)
    err = refused(put(tmp_path, "# only a comment\n\n", "nothing.csv"))
    assert "no header row" in str(err)


def test_timestamps_must_strictly_increase(tmp_path: Path) -> None:
    lines = [HEADER, row(0), row(1), row(2), row(2), row(3)]
    err = refused(put(tmp_path, "\n".join(lines)))
    assert (err.line, err.column) == (5, "timestamp_ns")
    t2 = T0 + 2 * DT
    assert f"{t2} is not after {t2} on line 4" in str(err)
    lines = [HEADER, row(0), row(2), row(1)]
    err = refused(put(tmp_path, "\n".join(lines), "back.csv"))
    assert err.line == 4 and f"{T0 + DT} is not after {T0 + 2 * DT} on line 3" in str(err)


def test_header_problems(tmp_path: Path) -> None:
    err = refused(put(tmp_path, "\n".join(good()[1:])))
    assert err.line == 1 and "the first row is data, not a header" in str(err)
    err = refused(put(tmp_path, HEADER + ",ax\n" + row(0) + ",1\n" + row(1) + ",1\n", "dup.csv"))
    assert err.column == "ax" and "appears twice (fields 2 and 8)" in str(err)
    text = HEADER + ",mx,my\n" + row(0) + ",1,2\n" + row(1) + ",1,2\n"
    err = refused(put(tmp_path, text, "mag.csv"))
    assert "has mx, my but not mz" in str(err)
    err = refused(put(tmp_path, HEADER.replace(",", ";") + "\n1;2\n", "semi.csv"))
    assert "imud reads comma-separated files" in str(err)


def test_the_example_in_the_docs_reads(tmp_path: Path) -> None:
    doc = (Path(__file__).resolve().parent.parent / "docs" / "recording-csv.md").read_text()
    example = doc.split("```csv\n", 1)[1].split("```", 1)[0]
    path = put(tmp_path, example)
    rec = read_csv(path)
    assert rec.n == 3 and rec.rate_hz == pytest.approx(100.0)
    assert rec.saturated is not None and rec.saturated.tolist() == [False, False, True]
    assert read_comments(path)["samples"] == "raw"


def test_a_magnetometer_session_holds_only_the_magnetometer(tmp_path: Path) -> None:
    """A tool's preamble (`Fs,50.00`) above `mx,my,mz` and no time: 50 Hz rows; no accelerometer
    or gyro is needed for it, and theirs read as NaN, never as values."""
    path = tmp_path / "mag.csv"
    rows = "\n".join(f"{20 + k},{-5 - k},{40 + 2 * k}" for k in range(10))
    path.write_text(f"Fs,50.00\nInitialization time,60\nmx,my,mz\n{rows}\n")
    rec = read_csv(path, mag_units="uT", need=("mag",))
    assert rec.n == 10 and rec.rate_hz == pytest.approx(50.0)
    assert rec.t_ns[1] - rec.t_ns[0] == 20_000_000
    assert rec.mag is not None and rec.mag[0].tolist() == pytest.approx([20e-6, -5e-6, 40e-6])
    assert np.isnan(rec.accel).all() and np.isnan(rec.gyro).all()
    counts = read_csv(path, need=("mag",), mag_per_ut=0.5)  # 0.5 counts a uT
    assert counts.mag is not None and counts.mag[0, 0] == pytest.approx(40e-6)
    with pytest.raises(CsvError, match="missing required columns ax, ay, az, gx, gy, gz"):
        read_csv(path, mag_units="uT")  # an accel/gyro calibration needs theirs
    path.write_text(f"mx,my,mz\n{rows}\n")
    with pytest.raises(CsvError, match="missing required columns timestamp_ns"):
        read_csv(path, mag_units="uT", need=("mag",))  # no time and no rate: said
    assert read_csv(path, mag_units="uT", need=("mag",), rate_hz=10.0).rate_hz == 10.0


@pytest.mark.parametrize("rate", ["0", "-50", "nan"])
def test_a_preamble_rate_that_is_no_rate_is_named(rate: str, tmp_path: Path) -> None:
    path = tmp_path / "mag.csv"
    path.write_text(f"Fs,{rate}\nmx,my,mz\n20,-5,40\n21,-6,41\n")
    with pytest.raises(CsvError, match=r"mag.csv:1: the preamble's rate .* is not a positive"):
        read_csv(path, mag_units="uT", need=("mag",))
