"""The config a daemon ran, rebuilt with private copies of its calibration files
(`imud.recording.daemoncfg`): the copies go with `close()`, and those of a process killed before
it could close are removed by the next one to make copies."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from imud.recording.daemoncfg import PREFIX, DaemonConfig

CAL = "version = 1\n\n[gyro]\nbias = [0.01, 0.0, 0.0]\nscale = [1.0, 1.0, 1.0]\n"
RAW = {
    "device": [
        {
            "name": "imu0",
            "chip": "mpu6050",
            "bus": {"kind": "sim", "bus": "sim0", "address": 0x68},
            "calibration": "/somewhere/on/the/daemons/machine.cal.toml",
        }
    ]
}


@pytest.fixture
def tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    return tmp_path


def copies(tmp: Path) -> list[Path]:
    return sorted(tmp.glob(f"{PREFIX}*"))


def test_the_calibration_is_copied_and_the_copy_goes_with_close(tmp: Path) -> None:
    cfg = DaemonConfig(RAW, {"imu0": CAL})
    assert cfg.config is not None and cfg.error is None
    path = cfg.config.device[0].calibration
    assert path is not None and Path(path).read_text() == CAL
    assert Path(path).parent in copies(tmp)
    cfg.close()
    assert copies(tmp) == []


def test_a_killed_processs_copies_are_removed_by_the_next_and_a_live_ones_are_kept(
    tmp: Path,
) -> None:
    killed = subprocess.run(
        [
            sys.executable,
            "-c",
            "import os, signal\n"
            "from imud.recording.daemoncfg import DaemonConfig\n"
            f"kept = DaemonConfig({RAW!r}, {{'imu0': {CAL!r}}})\n"
            "os.kill(os.getpid(), signal.SIGKILL)\n",
        ],
        env={**os.environ, "TMPDIR": str(tmp)},
        check=False,
    )
    assert killed.returncode == -signal.SIGKILL
    left = copies(tmp)
    assert len(left) == 1 and not left[0].name.startswith(f"{PREFIX}{os.getpid()}-")
    live = DaemonConfig(RAW, {"imu0": CAL})  # this process: alive
    ours = [p for p in copies(tmp) if p.name.startswith(f"{PREFIX}{os.getpid()}-")]
    assert len(ours) == 1
    assert copies(tmp) == ours  # the killed one's went
    other = DaemonConfig(RAW, {"imu0": CAL})
    assert len(copies(tmp)) == 2  # a live process's copies stay
    live.close()
    other.close()
    assert copies(tmp) == []
