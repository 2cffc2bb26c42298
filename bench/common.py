"""What both benchmarks share: a free loopback port and the calibration file they apply."""

from __future__ import annotations

import socket

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
