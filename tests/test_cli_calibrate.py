"""`imud calibrate` offline, as a user runs it: a CSV recording in, a calibration file out, then
`imud calibrate apply` on the same recording.

The recording is made here from physics: the simulator's pose profile gives the true specific
force and rate (still poses joined by rotations), and the sensor errors are applied in this file:
m = A (f + b0) + n with A = (I + misalignment) diag(1 + scale error). The 9-parameter calibration
ties the frame to the chip's axes, so the matrix it must find is the upper-triangular factor R of
A^-1 = Q R (positive diagonal), and its bias is A b0.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imud.calib.csvio import CsvWriter, read_csv
from imud.sim.motion import MotionModel
from imud.sim.settings import DEFAULT_POSES, PosesMotion

RATE = 200.0
ACCEL_NOISE = 400e-6 * 9.80665 * math.sqrt(RATE)  # MPU6050 400 ug/sqrt(Hz), per sample
GYRO_NOISE = math.radians(0.005) * math.sqrt(RATE)
B0 = np.array([0.3, -0.25, 0.2])  # m/s^2
GB = np.radians([0.8, -0.5, 0.3])  # rad/s


def normal_gravity(lat_deg: float, h: float) -> float:
    """WGS84 Somigliana with the free-air term (NIMA TR8350.2 eqs. 4-1, 4-3), written out here."""
    ge, k, e2 = 9.7803253359, 0.00193185265241, 0.00669437999013
    a, f, m = 6378137.0, 1 / 298.257223563, 0.00344978650684
    s2 = math.sin(math.radians(lat_deg)) ** 2
    g0 = ge * (1 + k * s2) / math.sqrt(1 - e2 * s2)
    return g0 * (1 - 2 / a * (1 + f + m - 2 * f * s2) * h + 3 * h * h / (a * a))


def sensor_matrix() -> np.ndarray:
    mis = np.radians(1.0) * np.array([[0, 0.8, -0.6], [-0.5, 0, 1.0], [0.7, -0.9, 0]])
    return (np.eye(3) + mis) @ np.diag([1.02, 0.98, 1.015])


def truth_calibration(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    _q, r = np.linalg.qr(np.linalg.inv(a))
    d = np.sign(np.diag(r))
    return np.diag(d) @ r, a @ B0


def make_recording(path: Path, poses: int = 12, hold_s: float = 8.0, seed: int = 1) -> float:
    g = normal_gravity(45.0, 100.0)
    motion = PosesMotion(
        poses=list(DEFAULT_POSES[:poses]), hold_s=hold_s, move_s=1.5, sweep_s=0.0, repeat=False
    )
    model = MotionModel(motion)
    t = np.arange(0, poses * (hold_s + 1.5), 1 / RATE)
    f, w = model.sample(t)
    f = f * (g / 9.80665)  # the profile uses standard gravity; this bench sits at 45 N, 100 m
    rng = np.random.default_rng(seed)
    a = sensor_matrix()
    acc = (f + B0) @ a.T + rng.normal(0, ACCEL_NOISE, f.shape)
    gyr = w + GB + rng.normal(0, GYRO_NOISE, w.shape)
    temp = np.full(len(t), 30.0)
    with CsvWriter(
        path,
        has_temp=True,
        comments={"chip": "mpu6050", "device": "bench", "samples": "raw (uncorrected)"},
    ) as wr:
        wr.write((t * 1e9).astype(np.int64) + 1_000_000_000, acc, gyr, temp)
    return g


def imud(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "imud", *args], capture_output=True, text=True, timeout=120
    )


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, float]:
    p = tmp_path_factory.mktemp("rec") / "twelve.csv"
    return p, make_recording(p)


def test_accel_from_a_recording_recovers_the_sensor_and_writes_the_file(
    recording: tuple[Path, float], tmp_path: Path
) -> None:
    rec, g = recording
    out = tmp_path / "cal.toml"
    r = imud(
        "calibrate",
        "accel",
        "--from",
        str(rec),
        "--out",
        str(out),
        "--json",
        "--latitude",
        "45",
        "--height",
        "100",
    )
    assert r.returncode == 0, r.stdout + r.stderr
    rep = json.loads(r.stdout)
    assert rep["accepted"] is True and rep["written"] == str(out)
    assert rep["gravity"] == pytest.approx(g, abs=1e-9)
    assert rep["orientations"] == 12
    c_true, b_true = truth_calibration(sensor_matrix())
    c = np.array(rep["matrix"])
    b = np.array(rep["bias"])
    p = rep["parameters"]
    for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)):
        sig = p[f"C_{'xyz'[i]}{'xyz'[j]}"]["sigma"]
        assert abs(c[i, j] - c_true[i, j]) < 4 * sig + 1e-12, (i, j, c[i, j], c_true[i, j], sig)
    for k in range(3):
        assert abs(b[k] - b_true[k]) < 4 * p[f"b_{'xyz'[k]}"]["sigma"]
    assert np.allclose(np.tril(c, -1), 0.0)  # upper-triangular: the frame is the chip's
    # the file holds it, with its provenance
    text = out.read_text()
    assert 'chip = "mpu6050"' in text and 'procedure = "accel-9"' in text
    assert "covariance" in text and "[accel.residuals]" in text
    # the seed's up/down formula is printed beside it (all six faces are in the recording)
    assert "seed_up_down" in rep


def test_apply_corrects_the_recording_with_the_daemon_code(
    recording: tuple[Path, float], tmp_path: Path
) -> None:
    rec, g = recording
    cal, out = tmp_path / "cal.toml", tmp_path / "corrected.csv"
    assert (
        imud(
            "calibrate", "accel", "--from", str(rec), "--out", str(cal), "--gravity", repr(g)
        ).returncode
        == 0
    )
    r = imud("calibrate", "apply", "--calibration", str(cal), "--from", str(rec), "--out", str(out))
    assert r.returncode == 0, r.stderr
    raw, cor = read_csv(rec), read_csv(out)
    np.testing.assert_array_equal(raw.t_ns, cor.t_ns)
    # every still sample now reads local g in magnitude (noise only: 0.055 m/s^2 per sample)
    motion = MotionModel(
        PosesMotion(poses=list(DEFAULT_POSES), hold_s=8.0, move_s=1.5, sweep_s=0.0, repeat=False)
    )
    t_s = (raw.t_ns - raw.t_ns[0]) / 1e9
    still = np.zeros(raw.n, dtype=bool)
    for span in motion.still_spans(float(t_s[-1])):
        still |= (t_s > span.start_s + 0.5) & (t_s < span.end_s - 0.5)
    err_before = np.linalg.norm(raw.accel[still], axis=1).mean() - g
    err_after = np.linalg.norm(cor.accel[still], axis=1).mean() - g
    assert abs(err_after) < 0.005 < abs(err_before)


def test_too_few_orientations_refused_saying_how_many_more(tmp_path: Path) -> None:
    rec = tmp_path / "seven.csv"
    make_recording(rec, poses=7, hold_s=5.0)
    r = imud("calibrate", "accel", "--from", str(rec), "--out", str(tmp_path / "c.toml"))
    assert r.returncode == 3, r.stdout + r.stderr
    msg = r.stdout + r.stderr
    assert "7" in msg and "2 more" in msg
    assert not (tmp_path / "c.toml").exists()


def test_a_bad_csv_is_a_usage_error_naming_the_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("timestamp_ns,ax,ay,az,gx,gy,gz\n1,0,0,9.8,0,0,0\n2,0,x,9.8,0,0,0\n")
    r = imud("calibrate", "accel", "--from", str(bad), "--out", str(tmp_path / "c.toml"))
    assert r.returncode == 2
    assert "bad.csv:3" in r.stderr and "ay" in r.stderr and "Traceback" not in r.stderr


def test_gyro_bias_from_a_still_recording(tmp_path: Path) -> None:
    rec = tmp_path / "still.csv"
    n = int(60 * RATE)
    rng = np.random.default_rng(5)
    acc = np.array([0.0, 0.0, 9.80665]) + rng.normal(0, ACCEL_NOISE, (n, 3))
    gyr = GB + rng.normal(0, GYRO_NOISE, (n, 3))
    with CsvWriter(rec, has_temp=True) as w:
        w.write(np.arange(n, dtype=np.int64) * 5_000_000 + 1, acc, gyr, np.full(n, 25.0))
    out = tmp_path / "g.toml"
    r = imud(
        "calibrate", "gyro", "--from", str(rec), "--out", str(out), "--json", "--chip", "mpu6050"
    )
    assert r.returncode == 0, r.stdout + r.stderr
    rep = json.loads(r.stdout)
    b, p = np.array(rep["bias"]), rep["parameters"]
    # N / sqrt(T): 0.005 deg/s/sqrt(Hz) over 60 s
    expect_sigma = math.radians(0.005) / math.sqrt(60.0)
    for k in range(3):
        s = p[f"b_{'xyz'[k]}"]["sigma"]
        assert 0.7 * expect_sigma < s < 1.3 * expect_sigma
        assert abs(b[k] - GB[k]) < 4 * s
    assert "[gyro]" in out.read_text()


@pytest.mark.extra  # matplotlib
def test_plot_draws_a_png(recording: tuple[Path, float], tmp_path: Path) -> None:
    png = tmp_path / "fit.png"
    r = imud("calibrate", "accel", "--from", str(recording[0]), "--dry-run", "--plot", str(png))
    assert r.returncode == 0, r.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "not written (--dry-run)" in r.stdout


@pytest.mark.extra  # matplotlib
def test_gyro_plot_shows_each_rotation(recording: tuple[Path, float], tmp_path: Path) -> None:
    png = tmp_path / "gyro.png"
    r = imud("calibrate", "gyro", "--from", str(recording[0]), "--dry-run", "--plot", str(png))
    assert r.returncode in (0, 3), r.stderr  # the plot is drawn whatever the verdict
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the twelve poses' eleven rotations, each with the angle it turned and its gravity miss
    assert "per rotation: poses, duration s, angle deg, gravity miss deg" in r.stdout
    assert " 1 ->  2" in r.stdout and "11 -> 12" in r.stdout


def _csv(path: Path, accel: np.ndarray, gyro: np.ndarray, rate: float = 100.0) -> Path:
    rows = [f"{int(i * 1e9 / rate)}," + ",".join(f"{float(v)!r}" for v in (*a, *g))
            for i, (a, g) in enumerate(zip(accel, gyro, strict=True))]  # fmt: skip
    path.write_text("timestamp_ns,ax,ay,az,gx,gy,gz\n" + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize(
    ("case", "code", "says"),
    [  # the reader's checks are usage errors (2), the procedures' refusals 3
        ("one sample", 2, "1 sample: at least 2 are needed"),
        ("dead axis", 3, "accelerometer's y axis reads 0 in every one of its 2000 samples"),
        ("counts", 2, "median |accel| is 4096 m/s2, not near gravity"),  # 4096 LSB/g as m/s^2
        ("deg/s", 2, "looks like dps: pass --gyro-units dps"),
    ],
)
def test_garbage_is_refused_naming_the_column_and_the_fix(
    case: str, code: int, says: str, tmp_path: Path
) -> None:
    rng = np.random.default_rng(5)
    n = 1 if case == "one sample" else 2000
    accel = np.array([0.0, 0.0, 9.81]) + rng.standard_normal((n, 3)) * 0.02
    gyro = rng.standard_normal((n, 3)) * 1e-3
    if case == "dead axis":
        accel[:, 1] = 0.0
    if case == "counts":
        accel *= 4096 / 9.81
    if case == "deg/s":
        gyro = gyro + np.degrees([0.0, 0.0, 1.0])  # turning at 57 "rad/s": deg/s as rad/s
    path = _csv(tmp_path / "garbage.csv", accel, gyro)
    for kind in ("accel", "gyro"):
        r = imud("calibrate", kind, "--from", str(path), "--out", str(tmp_path / "c.toml"))
        msg = r.stdout + r.stderr
        assert "Traceback" not in msg, msg
        if case == "deg/s" and kind == "accel":
            continue  # the accelerometer's columns are fine
        assert r.returncode == code and says in msg, (kind, msg)
    assert not (tmp_path / "c.toml").exists()


def test_holdout_beside_the_seed(tmp_path: Path) -> None:
    """Twelve poses with the six faces, a sensor with misalignment: on held-out windows the
    9-parameter calibration beats the seed's per-axis six-face method, which cannot undo it."""
    rec = tmp_path / "poses.csv"
    make_recording(rec)
    r = imud("calibrate", "accel", "--from", str(rec), "--dry-run", "--holdout", "--json")
    assert r.returncode == 0, r.stderr
    rms = json.loads(r.stdout)["holdout"]["rms"]
    assert rms["seed"] is not None
    assert rms["calibrated"] < rms["seed"] < rms["uncalibrated"]


def test_an_accelerometer_only_recording(tmp_path: Path) -> None:
    """A recording without gyro columns (an accelerometer alone): the still poses are found
    from the accelerometer's own noise floor and the calibration is the same."""
    full = tmp_path / "poses.csv"
    make_recording(full)
    lines = full.read_text().splitlines()
    comments = [ln for ln in lines if ln.startswith("#")]
    table = [ln.split(",") for ln in lines if not ln.startswith("#")]
    keep = [i for i, h in enumerate(table[0]) if h not in ("gx", "gy", "gz")]
    accel_only = tmp_path / "accel.csv"
    rows = [",".join(f for i, f in enumerate(row) if i in keep) for row in table]
    accel_only.write_text("\n".join(comments + rows) + "\n")
    outs = []
    for path in (full, accel_only):
        r = imud("calibrate", "accel", "--from", str(path), "--dry-run", "--json")
        assert r.returncode == 0, r.stderr
        outs.append(json.loads(r.stdout))
    assert len(outs[1]["poses"]) == len(outs[0]["poses"])
    np.testing.assert_allclose(outs[1]["matrix"], outs[0]["matrix"], atol=2e-4)
    r = imud("calibrate", "gyro", "--from", str(accel_only), "--dry-run")
    assert r.returncode == 2 and "gx" in r.stderr and "Traceback" not in r.stderr


def test_a_shot_list_one_reading_a_pose(tmp_path: Path) -> None:
    """ax, ay, az (and mx, my, mz) and no time: each row a still pose's reading, as a tool that
    logs one reading a button press writes. The fit takes its noise from the residuals."""
    rng = np.random.default_rng(12)
    a = sensor_matrix()
    g = normal_gravity(45.0, 100.0)
    faces = np.vstack([np.eye(3), -np.eye(3)])
    corners = np.array([[1, 1, 1], [-1, 1, 1], [1, -1, 1], [1, 1, -1], [-1, -1, 1], [1, -1, -1]])
    dirs = np.vstack([faces, corners / np.sqrt(3.0)])
    readings = (dirs * g + B0) @ a.T + rng.standard_normal(dirs.shape) * 2e-3
    path = tmp_path / "shots.csv"
    mag = rng.standard_normal(dirs.shape) * 40.0
    rows = [",".join(f"{float(v)!r}" for v in (*r, *m)) for r, m in zip(readings, mag, strict=True)]
    path.write_text("ax,ay,az,mx,my,mz\n" + "\n".join(rows) + "\n")
    src = ["--from", str(path), "--shots", "--mag-units", "uT"]
    r = imud(
        "calibrate", "accel", *src, "--dry-run", "--json", "--latitude", "45", "--height", "100"
    )
    assert r.returncode == 0, r.stdout + r.stderr
    out = json.loads(r.stdout)
    want_c, want_b = truth_calibration(a)
    np.testing.assert_allclose(out["matrix"], want_c, atol=2e-3)
    np.testing.assert_allclose(out["bias"], want_b, atol=5e-3)
    assert any("shot list" in x for x in out["reasons"])
    r = imud("calibrate", "accel", "--from", str(path), "--dry-run")  # not said: a stream
    assert r.returncode in (2, 3) and "Traceback" not in r.stderr
    assert "needs --shots" in r.stderr, r.stderr
    for extra, says in (
        (("--strict",), "drop --strict"),
        (("--holdout",), "drop them"),
    ):
        r = imud("calibrate", "accel", *src, "--dry-run", *extra)
        assert r.returncode == 2 and says in r.stderr, r.stderr
    r = imud("calibrate", "gyro", *src, "--dry-run")
    assert r.returncode == 2 and "gyro needs a stream" in r.stderr, r.stderr
    r = imud("calibrate", "accel", *src, "--dry-run")
    assert "reading (data row)" in r.stdout and " at " not in r.stdout.split("per pose")[1]
