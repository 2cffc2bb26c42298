"""Recordings of many millions of rows through the real CLI: read and calibrated, or, where the
machine's memory is short, refused with the sizes and the fix, never a traceback (a process the
kernel kills half-way says nothing at all).

The files are written a byte matrix at a time: fixed-width rows whose noise repeats every
BLOCK rows, so the mean of the whole file is the mean of one block, known here exactly from
the text written."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

BLOCK = 1000
BIAS = np.array([1e-3, -2e-3, 5e-4])  # rad/s, the gyro's
HEADER = b"timestamp_ns,ax,ay,az,gx,gy,gz\n"


def write_still(path: Path, n: int, rate_hz: float = 1000.0) -> np.ndarray:
    """n rows still at one pose; returns the gyro's mean over the file, from the text itself."""
    rng = np.random.default_rng(7)
    accel = np.array([0.1, -0.2, 9.8]) + rng.standard_normal((BLOCK, 3)) * 0.02
    gyro = BIAS + rng.standard_normal((BLOCK, 3)) * 1e-3
    tails = [
        ("".join(f",{v:+.5f}" for v in (*a, *g)) + "\n").encode()
        for a, g in zip(accel, gyro, strict=True)
    ]
    width = len(tails[0])
    assert all(len(t) == width for t in tails)  # every value is +d.ddddd
    tail = np.frombuffer(b"".join(tails), np.uint8).reshape(BLOCK, width)
    written = np.array([[float(x) for x in t.decode().split(",")[4:7]] for t in tails])
    step = round(1e9 / rate_hz)
    powers = 10 ** np.arange(15, -1, -1, dtype=np.int64)  # 16 digits: 1e15 ns and on
    with open(path, "wb") as f:
        f.write(HEADER)
        for a in range(0, n, BLOCK * 100):
            k = np.arange(a, min(n, a + BLOCK * 100), dtype=np.int64)
            t = 10**15 + k * step
            digits = ((t[:, None] // powers) % 10 + ord("0")).astype(np.uint8)
            f.write(np.hstack([digits, tail[k % BLOCK]]).tobytes())
    mean: np.ndarray = written[np.arange(n) % BLOCK].mean(axis=0)
    return mean


def room(tmp_path: Path, need: int) -> Path:
    """A directory with `need` bytes free: the test's own, or memory-backed /dev/shm."""
    for d in (tmp_path, Path("/dev/shm")):
        if d.is_dir() and shutil.disk_usage(d).free > need:
            return d
    pytest.skip(f"no directory here has {need / 1e9:.1f} GB free for the recording")


def calibrate_gyro(path: Path, *prefix: str) -> subprocess.CompletedProcess[str]:
    argv = [sys.executable, *prefix, "calibrate", "gyro", "--from", str(path)]
    argv += ["--chip", "mpu6050", "--dry-run", "--json"]
    return subprocess.run(argv, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_ten_million_rows_are_read_and_calibrated(tmp_path: Path) -> None:
    """2.8 hours at 1 kHz (a 750 MB file): the gyro bias is the file's own mean."""
    n = 10_000_000
    path = room(tmp_path, 2 * 10**9) / "ten_million.csv"
    try:
        mean = write_still(path, n)
        r = calibrate_gyro(path, "-m", "imud")
    finally:
        path.unlink(missing_ok=True)
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 0, r.stdout + r.stderr
    out = json.loads(r.stdout)
    assert out["accepted"], out["reasons"]
    # the bias of a still recording is its mean rate (the text rounds to 1e-5 rad/s; the mean
    # of ten million of them is exact to far below that)
    assert np.allclose(out["bias"], mean, atol=1e-9, rtol=0), (out["bias"], mean)


# the CLI started under an address-space limit set after its imports, so the limit leaves a
# known margin for the recording whatever the interpreter and NumPy reserve for themselves
LIMITED = """
import resource, sys
from imud.cli.commands import main
import imud.cli.calibrate, imud.calib.csvio, imud.calib.procedure
status = open("/proc/self/status").read()
vm = int(next(l.split()[1] for l in status.splitlines() if l.startswith("VmSize:"))) * 1024
resource.setrlimit(resource.RLIMIT_AS, (vm + int(sys.argv.pop(1)), resource.RLIM_INFINITY))
sys.argv[0] = "imud"
main()
"""


def test_a_recording_larger_than_the_memory_left_is_refused_with_the_fix(tmp_path: Path) -> None:
    """A million rows (71 MB) with less memory to spare than the file or than reading it needs:
    refused, naming memory and how to cut the file; the same file with room to spare is
    calibrated (the refusal was the memory's)."""
    path = room(tmp_path, 200 * 10**6) / "million.csv"
    mean = write_still(path, 1_000_000)
    for margin in (60, 200):  # MB: short of the file itself; short of what reading needs
        short = calibrate_gyro(path, "-c", LIMITED, str(margin * 10**6))
        assert "Traceback" not in short.stderr, short.stderr
        assert short.returncode == 2, short.stdout + short.stderr
        error = json.loads(short.stdout)["error"]
        assert str(path) in error and "memory" in error and "head -n 1000001" in error, error
        if "rows need" in error:  # asked before spending: 7 columns, 16 bytes each and 16
            assert "its 1,000,000 rows need about 128 MB" in error, error
    enough = calibrate_gyro(path, "-c", LIMITED, str(4 * 10**9))
    assert enough.returncode == 0, enough.stdout + enough.stderr
    assert np.allclose(json.loads(enough.stdout)["bias"], mean, atol=1e-9, rtol=0)
