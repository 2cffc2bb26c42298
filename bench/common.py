"""What both benchmarks share: a free loopback port and the calibration file they apply."""

from __future__ import annotations

import shutil
import socket
import sys
from pathlib import Path

CALIBRATION_TOML = """\
version = 1

[accel]  # m/s^2, dimensionless scale
bias = [0.12, -0.08, 0.21]
scale = [1.004, 0.997, 1.002]

[gyro]  # rad/s
bias = [0.011, -0.007, 0.004]
scale = [1.001, 0.999, 1.003]
"""


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def imud_executable() -> str:
    """The `imud` console script of the Python running the bench (its venv), else on PATH."""
    beside = Path(sys.executable).with_name("imud")
    if beside.exists():
        return str(beside)
    found = shutil.which("imud")
    if found is None:
        raise SystemExit("cannot find the `imud` console script (is the package installed?)")
    return found
