"""`imud calibrate` on what users actually hand it: raw counts in a CSV (imucal's sessions, a
sample counter and a stated rate), a scale or zero count given wrong, a gyro column of zeros,
a magnetometer in counts, a --plot path that cannot be written. Each either works or exits
with a message naming the option to fix, never a traceback, and nothing half-written.

The counts are imu_tk's real Xsens recording (tests/data/xsens), converted here by the test's
own arithmetic for the expected results."""

from __future__ import annotations

import gzip
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imud.calib.procedure import run_accel
from tests.test_calib_real import DATA, G, recording

COUNTS = ("--accel-counts", "414,32768", "--gyro-counts", "4770,32768")


def imud(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "imud", "calibrate", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.fixture(scope="module")
def counts_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The Xsens recording as its counts (t_s, acc_*, gyr_*), as a logger writes them."""
    path = tmp_path_factory.mktemp("counts") / "xsens_counts.csv"
    with gzip.open(DATA / "xsens_imu_tk.csv.gz", "rb") as f:
        path.write_bytes(f.read())
    return path


@pytest.fixture(scope="module")
def imucal_csv(counts_csv: Path) -> Path:
    """The same counts as imucal's sessions hold them: a sample counter, no time."""
    rows = counts_csv.read_text().splitlines()[1:]
    out = ["n_samples,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z"]
    out += [f"{k}," + r.split(",", 1)[1] for k, r in enumerate(rows)]
    path = counts_csv.parent / "imucal_session.csv"
    path.write_text("\n".join(out) + "\n")
    return path


def test_a_csv_of_counts_with_the_counts_options_calibrates_as_si(
    counts_csv: Path, imucal_csv: Path
) -> None:
    """--accel-counts/--gyro-counts read a CSV's counts as imu_tk's files are read: the fit is
    the one of the same data converted to SI here, whether time or a counter at --rate."""
    rec, _ = recording()  # the test's own (counts - 32768) / 414
    want = run_accel(rec, G, "full").report
    for path, extra in ((counts_csv, ()), (imucal_csv, ("--rate", "100"))):
        r = imud("accel", "--from", str(path), *COUNTS, *extra, "--gravity", str(G),
                 "--dry-run", "--json")  # fmt: skip
        assert r.returncode == 0, r.stdout + r.stderr
        got = json.loads(r.stdout)
        assert got["accepted"] is True
        # the counter's times are k / 100 s, the file's are the logger's (within a few us of
        # those): the poses and so the fit agree to far below the fit's own sigma
        assert np.allclose(got["bias"], want["bias"], atol=2e-5), (got["bias"], want["bias"])
        assert np.allclose(got["matrix"], want["matrix"], atol=2e-6)


@pytest.mark.parametrize(
    ("option", "value", "units", "says"),
    [
        ("--gyro-counts", "4770", (), "is the zero count right"),  # zero left out
        ("--accel-counts", "4060,32768", (), "counts per g? add --accel-units g"),
        ("--accel-counts", "41.4,32768", (), "check the counts per m/s2"),
    ],
)
def test_counts_given_wrong_name_the_option(
    counts_csv: Path, option: str, value: str, units: tuple[str, ...], says: str
) -> None:
    args = dict(zip(COUNTS[::2], COUNTS[1::2], strict=True))
    args[option] = value
    flat = [x for kv in args.items() for x in kv]
    r = imud("accel", "--from", str(counts_csv), *flat, *units, "--dry-run")
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    assert option in r.stderr and says in r.stderr, r.stderr


def test_counts_per_g_with_accel_units_g(counts_csv: Path) -> None:
    """Counts per unit of --accel-units: 414 counts per m/s^2 are 4060 per g."""
    per_g = f"{414 * 9.80665},32768"
    r = imud("accel", "--from", str(counts_csv), "--accel-counts", per_g, "--accel-units", "g",
             "--gyro-counts", "4770,32768", "--dry-run", "--json")  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    assert json.loads(r.stdout)["accepted"] is True


def test_si_values_read_as_counts_are_refused(tmp_path: Path) -> None:
    rec, _ = recording()
    path = tmp_path / "si.csv"
    t = rec.t_ns
    rows = [f"{t[k]},{','.join(f'{v:.6f}' for v in (*rec.accel[k], *rec.gyro[k]))}"
            for k in range(0, rec.n, 5)]  # fmt: skip
    path.write_text("timestamp_ns,ax,ay,az,gx,gy,gz\n" + "\n".join(rows) + "\n")
    r = imud("accel", "--from", str(path), *COUNTS, "--dry-run")
    assert r.returncode == 2 and "--accel-counts" in r.stderr, r.stderr


def test_a_gyro_column_of_zeros_is_not_saturation(tmp_path: Path) -> None:
    """A logger that wrote zeros for a gyro it did not have: the accelerometer's poses stand."""
    rec, _ = recording()
    path = tmp_path / "zero_gyro.csv"
    rows = [f"{rec.t_ns[k]},{','.join(f'{v:.6f}' for v in rec.accel[k])},0,0,0"
            for k in range(rec.n)]  # fmt: skip
    path.write_text("timestamp_ns,ax,ay,az,gx,gy,gz\n" + "\n".join(rows) + "\n")
    r = imud("accel", "--from", str(path), "--gravity", str(G), "--dry-run", "--json")
    assert r.returncode == 0, r.stdout + r.stderr
    out = json.loads(r.stdout)
    assert out["accepted"] is True
    assert not any("full scale" in n for n in out["notes"]), out["notes"]


def test_magnetometer_counts_without_mag_counts_say_which_option(tmp_path: Path) -> None:
    path = tmp_path / "qmc.csv"
    with gzip.open(Path(__file__).parent / "data" / "qmc5883l" / "noisy_raw_data.csv.gz") as f:
        path.write_bytes(f.read())
    r = imud("mag", "--from", str(path), "--dry-run")
    assert r.returncode == 2 and "--mag-counts" in r.stderr, r.stderr


@pytest.mark.parametrize(
    ("plot", "says"), [("nodir/fit.png", "no directory nodir"), ("fit.txt", "picture file")]
)
def test_a_plot_that_cannot_be_drawn_stops_before_anything_is_written(
    counts_csv: Path, tmp_path: Path, plot: str, says: str
) -> None:
    out = tmp_path / "cal.toml"
    r = subprocess.run(
        [sys.executable, "-m", "imud", "calibrate", "accel", "--from", str(counts_csv),
         *COUNTS, "--out", str(out), "--plot", plot],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    assert r.returncode == 2 and says in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "says"),
    [
        ((), "5 mg (the consumer-grade default; --tolerance-mg)"),
        (("--chip", "adis16465"), "2 mg (the industrial-grade default; --tolerance-mg)"),
        (("--chip", "stim300"), "1 mg (the tactical-grade default; --tolerance-mg)"),
        (("--chip", "stim300", "--grade", "consumer"), "5 mg (the consumer-grade default"),
        (("--tolerance-mg", "3"), "3 mg (--tolerance-mg)"),
    ],
)
def test_the_tolerance_is_the_grades_and_named(
    counts_csv: Path, args: tuple[str, ...], says: str
) -> None:
    """The chip says its grade (an ADIS16465 is industrial, a STIM300 tactical), --grade
    overrides it, and the output names which tolerance judged the fit."""
    r = imud("accel", "--from", str(counts_csv), *COUNTS, "--gravity", str(G), "--dry-run",
             *args)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    assert says in " ".join(r.stdout.split()), r.stdout


def test_a_gyro_only_still_file_gives_the_bias(tmp_path: Path) -> None:
    """timestamp and gyro columns alone (the Xsens's first 50 s, still): the bias is their
    mean; the whole recording, which moves, needs the accelerometer and says so."""
    rec, _ = recording()
    head = tmp_path / "gyro_still.csv"
    rows = [f"{rec.t_ns[k]},{','.join(f'{v:.7f}' for v in rec.gyro[k])}" for k in range(5000)]
    head.write_text("timestamp_ns,gx,gy,gz\n" + "\n".join(rows) + "\n")
    r = imud("gyro", "--from", str(head), "--dry-run", "--json")
    assert r.returncode == 0, r.stdout + r.stderr
    out = json.loads(r.stdout)
    assert out["accepted"] is True
    want = np.array([[float(v) for v in row.split(",")[1:]] for row in rows]).mean(axis=0)
    assert np.allclose(out["bias"], want, atol=1e-9)
    whole = tmp_path / "gyro_all.csv"
    rows = [f"{rec.t_ns[k]},{','.join(f'{v:.7f}' for v in rec.gyro[k])}" for k in range(rec.n)]
    whole.write_text("timestamp_ns,gx,gy,gz\n" + "\n".join(rows) + "\n")
    r = imud("gyro", "--from", str(whole), "--dry-run")
    assert r.returncode == 3 and "no accelerometer columns" in r.stderr, r.stderr


def test_one_corrupt_sample_is_named_not_fitted(tmp_path: Path) -> None:
    """A single 1e30 in the accelerometer (a corrupt line: the median-based unit checks pass
    it) would enter the gyro's g-sensitivity term; it is refused, with its time."""
    rec, _ = recording()
    path = tmp_path / "corrupt.csv"
    rows = [f"{rec.t_ns[k]},{','.join(f'{v:.6f}' for v in (*rec.accel[k], *rec.gyro[k]))}"
            for k in range(rec.n)]  # fmt: skip
    rows[20_000] = rows[20_000].split(",", 1)[0] + ",1e30,0,9.8,0,0,0"
    path.write_text("timestamp_ns,ax,ay,az,gx,gy,gz\n" + "\n".join(rows) + "\n")
    r = imud("gyro", "--from", str(path), "--dry-run")
    assert r.returncode == 3 and "Traceback" not in r.stderr
    assert "sample 20001 at" in r.stderr and "a corrupt line" in r.stderr, r.stderr


def test_a_rate_the_preamble_contradicts_is_said(tmp_path: Path) -> None:
    path = tmp_path / "qmc.csv"
    with gzip.open(Path(__file__).parent / "data" / "qmc5883l" / "noisy_raw_data.csv.gz") as f:
        path.write_bytes(f.read())  # its preamble: Fs,50.00
    r = imud("mag", "--from", str(path), "--mag-counts", "30", "--rate", "100", "--dry-run")
    assert r.returncode == 2 and "preamble says 50 Hz" in r.stderr, r.stderr
    r = imud("mag", "--from", str(path), "--mag-counts", "30", "--rate", "50", "--dry-run")
    assert r.returncode == 0, r.stderr
