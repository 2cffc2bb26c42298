"""What both benchmarks share: a free loopback port and the calibration file they apply."""

from __future__ import annotations

import shutil
import socket
import subprocess
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


def tables_per_tree(child: str, trees: list[str], args: list[str], title: str, header: str) -> None:
    """Run `child` (a script's source) once per source tree, each in its own process (so each
    imports its own `imud`, the tree being its first argument and `args` the rest), and print
    its rows under `title` (with `{tree}` in it) and the Markdown table `header`."""
    columns = header.count("|") - 1
    for tree in trees:
        out = subprocess.run(
            [sys.executable, "-c", child, tree, *args], capture_output=True, text=True, check=True
        ).stdout.rstrip()
        print("\n" + title.format(tree=tree) + "\n")
        print(header)
        print("|" + "---|" * columns)
        print(out)


# The start of a child script (`tables_per_tree`) that averages the tilt NEES of ten draws: the
# tree's `imud` first on the path, the instants it is taken at, and its 95 % band for the mean
NEES_CHILD_PRELUDE = r"""
import sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from imud.orient import metrics as M
from imud.orient.ekf import NoiseModel, OrientationFilter
from imud.sim import scenarios as sc

runs = 10
times = np.arange(5000, 60000, 2500)
try:
    from scipy.stats import chi2
    lo, hi = chi2.ppf([0.025, 0.975], 2 * runs) / runs
except ImportError:  # chi2(20) quantiles
    lo, hi = 9.591 / runs, 34.170 / runs
"""
