"""`imud orient` on recordings, run as the real CLI in a subprocess: an MCAP file written the way
`imud record` writes one (native batches, the devices' descriptions, the daemon's config
attached) from a scenario with known truth, and imud's CSV of the same samples."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imud.calib.csvio import CsvWriter
from imud.channels import Channel
from imud.orient import metrics as M
from imud.recording.mcapfile import Attachment, McapOut
from imud.recording.reader import open_recording
from imud.recording.recorder import native_topic
from imud.recording.schemas import BATCH, batch_cdr
from imud.sim import scenarios as sc
from imud.wire import decode, encode

T0 = 1_764_000_000_000_000_000
CONFIG = """
[ros2]
enabled = true
rate_hz = 100

[[device]]
name = "imu0"
chip = "mpu6050"
bus = { kind = "sim" }
odr_hz = 1000
dlpf_hz = 188
"""


def imud(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "imud", *args], capture_output=True, text=True, timeout=120
    )


@pytest.fixture(scope="module")
def scenario() -> sc.Scenario:
    return sc.reference(seed=7, seconds=20)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory, scenario: sc.Scenario) -> Path:
    """The scenario's samples as 32-sample batches, 64 samples lost after the 8th second."""
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    info = {"name": "imu0", "chip": "mpu6050", "odr_hz": 1000.0,
            "channels": ["accel", "gyro"]}  # fmt: skip
    meta = {"imud": {"devices": "imu0"}, "imud.devices": {"imu0": json.dumps(info)}}
    att = [Attachment("imud.toml", "application/toml", CONFIG.encode())]
    s = scenario
    t = T0 + (s.t_s * 1e9).astype(np.int64)
    with McapOut(path, att, meta) as out:
        lost = 0
        for i in range(0, len(t), 32):
            if 8000 <= i < 8064:  # a loss the daemon announced
                lost += 32
                continue
            j = min(i + 32, len(t))
            chans = {Channel.ACCEL: s.accel[i:j], Channel.GYRO: s.gyro[i:j]}
            w = encode("imu0", i, t[i:j], chans, lost_before=lost)
            lost = 0
            out.add(native_topic("imud", "imu0"), BATCH, int(t[j - 1]), batch_cdr(w))
    return path


def read_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    rows = [r for r in path.read_text().splitlines() if r and not r.startswith("#")]
    assert rows[0].split(",")[:5] == ["t_ns", "qw", "qx", "qy", "qz"]
    t = np.array([int(r.split(",")[0]) for r in rows[1:]])
    vals = np.array([[float(v) if v else np.nan for v in r.split(",")[1:]] for r in rows[1:]])
    return t, vals


def test_orient_an_mcap_recording_to_csv(
    recording: Path, scenario: sc.Scenario, tmp_path: Path
) -> None:
    out = tmp_path / "o.csv"
    r = imud("orient", str(recording), "--out", str(out), "--json")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["device"] == "imu0" and summary["chip"] == "mpu6050"
    assert summary["lost"] == 64 and summary["samples"] == 20000 - 64
    t, vals = read_csv(out)
    assert len(t) == 20000 - 64
    truth = scenario.truth[((t - T0) // 1_000_000 - 1).astype(int)]
    q = vals[:, :4]
    ok = ~np.isnan(q[:, 0])
    assert not ok[:900].any() and ok[1100:].all()  # the filter's 1-s start
    tilt = M.tilt_error_deg(q[ok], truth[ok])
    # the MPU6050's datasheet noise is above the scenario's: the filter trusts the accelerometer
    # less than it could, and still holds the tilt to a tenth of a degree, the gap included
    assert np.sqrt(np.mean(tilt[4000:] ** 2)) < 0.1
    # the learned bias is the scenario's
    bias = np.array(summary["filter"]["bias_rad_s"])
    assert np.abs(bias - scenario.gyro_bias).max() < np.radians(0.05)


def test_orient_to_mcap_keeps_the_batches_and_adds_imu_data(
    recording: Path, tmp_path: Path
) -> None:
    out = tmp_path / "o.mcap"
    r = imud("orient", str(recording), "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "written:" in r.stdout
    rec = open_recording(out)
    assert list(rec.devices) == ["imu0"]
    batches = [decode(w) for _, _, w in rec.batches(["imu0"])]
    assert sum(b.count for b in batches) == 20000 - 64
    assert batches[-1].get(Channel.ORIENTATION) is not None
    assert batches[-1].get(Channel.ORIENTATION_COVARIANCE) is not None
    assert sum(b.lost_before for b in batches) == 64
    # imu/data, the ROS 2 messages the recorded config asks for (100 Hz)
    from mcap.reader import make_reader

    with open(out, "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert "/imu0/imu/data" in topics and "/imu0/imu/data_raw" in topics


def test_orient_a_csv(recording: Path, scenario: sc.Scenario, tmp_path: Path) -> None:
    s = scenario
    path = tmp_path / "in.csv"
    t = T0 + (s.t_s * 1e9).astype(np.int64)
    with CsvWriter(path, has_temp=False, has_mag=False, comments={"chip": "mpu6050"}) as w:
        w.write(t, s.accel, s.gyro, None, None)
    r = imud("orient", str(path), "--json")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["samples"] == 20000 and summary["lost"] == 0
    q = np.array(summary["last"]["quaternion_wxyz"])
    assert M.tilt_error_deg(q[None], s.truth[-1:])[0] < 0.2


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["nowhere.mcap"], ["nowhere.mcap", "no such file"]),
        (["{rec}", "--out", "{tmp}/x.txt"], ["--out", ".csv", ".mcap"]),
        (["{rec}", "--out", "{rec}"], ["exists", "nothing is overwritten"]),
        (["{rec}", "--device", "imu9"], ["no device 'imu9'", "imu0"]),
        (["{rec}", "--update-hz", "0"], ["--update-hz"]),
    ],
)
def test_bad_arguments_are_named(
    recording: Path, tmp_path: Path, args: list[str], words: list[str]
) -> None:
    r = imud("orient", *[a.format(rec=recording, tmp=tmp_path) for a in args])
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr
    for w in words:
        assert w in r.stderr, r.stderr
