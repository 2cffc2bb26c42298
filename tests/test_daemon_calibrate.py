"""`imud calibrate accel` live against the running daemon, with no human: the simulated device
sits on a calibration bench (still poses, rotations between), the procedure reads its raw
stream, finds the poses, fits, writes the device's file, and the daemon applies it at once.
Then `imud calibrate apply` on a raw recording gives what the daemon published for the same
samples.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from imud.calib.csvio import read_csv
from tests.daemon_fixture import DaemonProc

CONFIG = """
[[device]]
name = "bench"
chip = "mpu6050"
bus = { kind = "sim", bus = "simA", address = 0x68 }
odr_hz = 200
dlpf_hz = 42
accel_range_g = 4
gyro_range_dps = 500
calibration = "bench.cal.toml"
[device.sim]
seed = 7
motion = { kind = "poses", hold_s = 2.6, move_s = 0.8, sweep_s = 0.0 }
[device.sim.errors]
accel_bias_mg = [30.0, -20.0, 25.0]
accel_scale_error = [0.02, -0.015, 0.01]
misalignment_deg = 0.5
accel_temp_drift_mg_per_c = [0.0, 0.0, 0.0]
accel_bias_instability_ug = 0.0
"""


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProc]:
    d = DaemonProc(tmp_path_factory.mktemp("bench"), CONFIG)
    d.wait_started()
    yield d
    code, _ = d.stop()
    assert code == 0, d.log.read_text()


def _bench(d: DaemonProc) -> dict[str, object]:
    return next(x for x in d.status()["devices"] if x["name"] == "bench")


def test_accel_calibration_completes_live_and_is_applied(daemon: DaemonProc) -> None:
    assert "does not exist" in str(_bench(daemon)["calibration_error"])
    r = daemon.cli(
        "calibrate",
        "accel",
        "--device",
        "bench",
        "--config",
        str(daemon.config),
        "--poses",
        "9",
        "--min-still",
        "1.5",
        "--duration",
        "120",
        "--json",
        # the residual test refuses a right calibration 1 % of the time by design (the
        # estimator tests check that rate); this test is about the live procedure completing
        "--significance",
        "1e-6",
        timeout=180,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    rep = json.loads(r.stdout)
    assert rep["accepted"] and rep["orientations"] >= 9
    cal = daemon.config.parent / "bench.cal.toml"
    assert rep["written"] == str(cal) and cal.exists()
    assert 'chip = "mpu6050"' in cal.read_text() and 'source = "live bench"' in cal.read_text()
    # the bias it found is the simulated one (times the scale): x 30 mg * 1.02, within 4 sigma
    bx = rep["parameters"]["b_x"]
    assert abs(bx["value"] - 0.030 * 9.80665 * 1.02) < 4 * bx["sigma"] + 0.003
    end = time.monotonic() + 10
    while time.monotonic() < end and _bench(daemon)["calibration"] is None:
        time.sleep(0.2)
    st = _bench(daemon)
    assert st["calibration"] == str(cal) and st["calibration_error"] is None


def test_apply_equals_the_daemons_output(daemon: DaemonProc, tmp_path: Path) -> None:
    cal = daemon.config.parent / "bench.cal.toml"
    if not cal.exists():
        pytest.skip("needs the live calibration above")
    raw, cor, applied = tmp_path / "raw.csv", tmp_path / "cor.csv", tmp_path / "applied.csv"
    base = [
        sys.executable,
        "-m",
        "imud",
        "record",
        "bench",
        "--duration",
        "2",
        "--connect",
        daemon.endpoint,
    ]
    procs = [
        subprocess.Popen([*base, "--raw", "--csv", str(raw)]),
        subprocess.Popen([*base, "--csv", str(cor)]),
    ]
    assert [p.wait(60) for p in procs] == [0, 0]
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "imud",
            "calibrate",
            "apply",
            "--calibration",
            str(cal),
            "--from",
            str(raw),
            "--out",
            str(applied),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    a, c = read_csv(applied), read_csv(cor)
    common, ia, ic = np.intersect1d(a.t_ns, c.t_ns, return_indices=True)
    assert len(common) > 100  # the two recordings overlap on most of their samples
    # the same samples, the same code: equal up to the float32 rounding of the raw stream
    np.testing.assert_allclose(a.accel[ia], c.accel[ic], rtol=0, atol=2e-5)
    np.testing.assert_allclose(a.gyro[ia], c.gyro[ic], rtol=0, atol=2e-6)
