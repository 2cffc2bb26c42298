"""`imud calibrate --from` on imu_tk's own file format, as a user of imu_tk would run it: its
Xsens test recording written back as its two text files (t x y z counts), the nominal scales on
the command line, the accelerometer and then the gyro calibrated into one file; and what a
wrong pair or a missing option is told."""

from __future__ import annotations

import gzip
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imud.calib.file import read_calibration

DATA = Path(__file__).parent / "data" / "xsens" / "xsens_imu_tk.csv.gz"
COUNTS = ["--accel-counts", "414,32768", "--gyro-counts", "4770,32768"]


def imud(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "imud", *args], capture_output=True, text=True, timeout=300
    )


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """imu_tk's two files, as its test data has them (%.7e, whitespace)."""
    with gzip.open(DATA, "rt") as f:
        rows = np.loadtxt(f, delimiter=",", skiprows=1)
    d = tmp_path_factory.mktemp("imu_tk")
    acc, gyr = d / "xsens_acc.mat", d / "xsens_gyro.mat"
    np.savetxt(acc, rows[:, [0, 1, 2, 3]], fmt="%15.7e")
    np.savetxt(gyr, rows[:, [0, 4, 5, 6]], fmt="%15.7e")
    return acc, gyr


def test_accel_then_gyro_from_imu_tks_files(pair: tuple[Path, Path], tmp_path: Path) -> None:
    acc, gyr = pair
    out = tmp_path / "xsens.cal.toml"
    src = ["--from", str(acc), "--gyro-from", str(gyr), *COUNTS, "--out", str(out)]
    r = imud("calibrate", "accel", *src, "--gravity", "9.81744")
    assert r.returncode == 0, r.stdout + r.stderr
    r = imud("calibrate", "gyro", *src)
    assert r.returncode == 0, r.stdout + r.stderr
    cf = read_calibration(out)
    assert cf.accel is not None and cf.gyro is not None and cf.accel.noise is not None
    # imu_tk's own result on this recording (tests/data/xsens/imu_tk_ref): 414.459, 412.010,
    # 414.649 counts per m/s^2, so against the nominal 414 the scale is 414 / theirs per axis
    scale = np.diag(np.array(cf.accel.matrix))
    np.testing.assert_allclose(scale, [414 / 414.459, 414 / 412.010, 414 / 414.649], atol=3e-4)


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ("no gyro file", "give --gyro-from GYRO_FILE"),
        ("no counts", "--accel-counts PER_UNIT,ZERO"),
        ("bad counts", "--accel-counts 'x': give counts per unit"),
        ("other instants", "do not hold the same instants (line 3"),
        ("five fields", ":2: 5 fields; imu_tk's files have four per line"),
    ],
)
def test_what_a_wrong_pair_is_told(
    change: str, says: str, pair: tuple[Path, Path], tmp_path: Path
) -> None:
    acc, gyr = pair
    args = ["--from", str(acc), "--gyro-from", str(gyr), *COUNTS]
    if change == "no gyro file":
        args = ["--from", str(acc), *COUNTS]
    elif change == "no counts":
        args = ["--from", str(acc), "--gyro-from", str(gyr)]
    elif change == "bad counts":
        args[args.index("414,32768")] = "x"
    else:
        lines = gyr.read_text().splitlines()[:100]
        if change == "other instants":  # a gyro file stamped 1 ms later from its third line
            for k in range(2, len(lines)):
                t = float(lines[k].split()[0]) + 1e-3
                lines[k] = f"{t:15.7e}" + lines[k][15:]
        else:
            lines[1] += " 1.0"
        bad = tmp_path / "gyro.mat"
        bad.write_text("\n".join(lines) + "\n")
        short = tmp_path / "acc.mat"
        short.write_text("\n".join(acc.read_text().splitlines()[:100]) + "\n")
        args = ["--from", str(short), "--gyro-from", str(bad), *COUNTS]
    r = imud("calibrate", "gyro", *args, "--out", str(tmp_path / "c.toml"))
    assert r.returncode == 2, r.stdout + r.stderr
    assert says in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_holdout_and_compare(pair: tuple[Path, Path], tmp_path: Path) -> None:
    """--holdout judges the fit on still windows it did not see; --compare judges a file on the
    same windows (here imud's own calibration of the whole recording, which did see them)."""
    acc, gyr = pair
    full = tmp_path / "full.cal.toml"
    src = ["--from", str(acc), "--gyro-from", str(gyr), *COUNTS, "--gravity", "9.81744"]
    assert imud("calibrate", "accel", *src, "--out", str(full)).returncode == 0
    r = imud("calibrate", "accel", *src, "--dry-run", "--holdout", "--compare", str(full), "--json")
    assert r.returncode == 0, r.stderr
    held = json.loads(r.stdout)["holdout"]
    rms = held["rms"]
    assert held["windows"] == 78  # 39 still poses, each judged in both halves
    assert rms["calibrated"] < rms["uncalibrated"] / 100  # the nominal scale is ~1 % off
    assert rms["seed"] is None and "six faces" in held["notes"][0]  # a hand-held session
    assert rms["compare"] <= rms["calibrated"]  # a fit that saw them does at least as well
    r = imud("calibrate", "accel", *src, "--dry-run", "--compare", str(acc))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr


def test_gyro_holdout_on_hand_turned_rotations(pair: tuple[Path, Path], tmp_path: Path) -> None:
    """Each half of the recording's rotations judges the other half's fit: the gravity direction
    each held-out rotation carries, against the uncalibrated gyro and a bias-only correction."""
    acc, gyr = pair
    out = tmp_path / "x.cal.toml"
    src = ["--from", str(acc), "--gyro-from", str(gyr), *COUNTS, "--out", str(out)]
    assert imud("calibrate", "accel", *src, "--gravity", "9.81744").returncode == 0
    r = imud("calibrate", "gyro", *src, "--holdout", "--json")
    assert r.returncode == 0, r.stderr
    held = json.loads(r.stdout)["holdout"]
    rms = held["rms"]
    # 39 poses in halves of 19 and 20: every rotation but the one between the halves, once
    assert held["unit"] == "deg" and held["windows"] == 37
    assert rms["calibrated"] < rms["seed"] < rms["uncalibrated"]
    assert rms["calibrated"] < 0.5  # degrees, on rotations the fit did not see
    rest = held["at_rest_deg_h"]  # the held-out poses' corrected rate: their bias left
    assert rest["calibrated"] < rest["seed"] < rest["uncalibrated"]
    r = imud("calibrate", "gyro", *src, "--dry-run", "--compare", str(out), "--json")
    assert r.returncode == 0, r.stderr
    rms = json.loads(r.stdout)["holdout"]["rms"]
    assert rms["compare"] < rms["calibrated"]  # the written file saw every rotation


def test_the_format_named_and_a_wrong_name_told(pair: tuple[Path, Path], tmp_path: Path) -> None:
    acc, gyr = pair
    src = ["--gyro-from", str(gyr), *COUNTS, "--dry-run"]
    r = imud("calibrate", "accel", "--from", str(acc), "--format", "imu_tk", *src)
    assert r.returncode == 0, r.stderr
    r = imud("calibrate", "accel", "--from", str(acc), "--format", "csv", *src)
    assert r.returncode == 2 and "give --format imu_tk" in r.stderr, r.stderr
    csv = tmp_path / "rec.csv"
    csv.write_text("timestamp_ns,ax,ay,az,gx,gy,gz\n1,0,0,9.8,0,0,0\n2,0,0,9.8,0,0,0\n")
    r = imud("calibrate", "accel", "--from", str(csv), "--format", "imu_tk", *src)
    assert r.returncode == 2 and "is not imu_tk's format" in r.stderr, r.stderr
    assert "give --format csv" in r.stderr
    assert "Traceback" not in r.stderr


REF = Path(__file__).parent / "data" / "xsens" / "imu_tk_ref"


def test_compare_takes_imu_tks_own_result(pair: tuple[Path, Path], tmp_path: Path) -> None:
    """--compare on imu_tk's calibration files as its program wrote them (T K B, of counts),
    applied to the nominal-scale readings through --accel-counts/--gyro-counts: the accel
    figure equals imu_tk's file applied to the counts by the test itself, on the same windows,
    and imud's held-out fit is no worse than imu_tk's (which saw them)."""
    from imud.calib.still import find_still
    from tests.test_calib_real import G, imu_tk_accel, recording

    acc, gyr = pair
    src = ["--from", str(acc), "--gyro-from", str(gyr), *COUNTS, "--gravity", str(G)]
    r = imud("calibrate", "accel", *src, "--dry-run", "--json",
             "--compare", str(REF / "test_imu_acc.calib"))  # fmt: skip
    assert r.returncode == 0, r.stderr
    rms = json.loads(r.stdout)["holdout"]["rms"]
    rec, counts = recording()
    tk, tk_b = imu_tk_accel()
    err = []
    for p in find_still(rec):
        mid = (p.start + p.end) // 2
        for a, b in ((p.start, mid), (mid, p.end)):
            err.append(np.linalg.norm(tk @ (counts[a:b].mean(axis=0) - tk_b)) - G)
    assert rms["compare"] == pytest.approx(float(np.sqrt(np.mean(np.square(err)))), rel=1e-6)
    assert rms["calibrated"] <= rms["compare"]
    out = tmp_path / "x.cal.toml"
    assert imud("calibrate", "accel", *src, "--out", str(out)).returncode == 0
    r = imud("calibrate", "gyro", "--from", str(acc), "--gyro-from", str(gyr), *COUNTS,
             "--out", str(out), "--dry-run", "--json",
             "--compare", str(REF / "test_imu_gyro.calib"))  # fmt: skip
    assert r.returncode == 0, r.stderr
    rms = json.loads(r.stdout)["holdout"]["rms"]
    assert rms["calibrated"] <= rms["compare"]  # imud's, held out, against imu_tk's
    # an SI recording has no counts to apply imu_tk's file through: told, not misread
    si = tmp_path / "si.csv"
    rows = [f"{rec.t_ns[k]},{','.join(f'{v:.6f}' for v in (*rec.accel[k], *rec.gyro[k]))}"
            for k in range(rec.n)]  # fmt: skip
    si.write_text("timestamp_ns,ax,ay,az,gx,gy,gz\n" + "\n".join(rows) + "\n")
    r = imud("calibrate", "accel", "--from", str(si), "--dry-run",
             "--compare", str(REF / "test_imu_acc.calib"))  # fmt: skip
    assert r.returncode == 2 and "give --accel-counts" in r.stderr, r.stderr
