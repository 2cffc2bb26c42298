"""`imud noise` through the real CLI on a CSV recording with a gap: its deviations are
allantools' on the numbers in the file, pooled over the two stretches the gap leaves."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from imud.calib.csvio import CsvWriter


@pytest.fixture
def allantools() -> object:
    """allantools (the dev extra): an independent implementation, run on the same samples."""
    return pytest.importorskip("allantools")


@pytest.mark.extra
def test_the_allan_deviation_of_a_csv_with_a_gap(allantools: Any, tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    n, rate = 30_000, 400.0
    t = np.arange(n, dtype=np.int64) * 2_500_000 + 10**18
    keep = np.ones(n, dtype=bool)
    keep[12_000:12_040] = False  # 0.1 s missing: two stretches
    accel = rng.normal(0.0, 0.05, (n, 3)) + np.array([0.1, -0.2, 9.81])
    gyro = rng.normal(0.0, 0.004, (n, 3)) + np.array([0.01, 0.0, -0.02])
    path = tmp_path / "still.csv"
    with CsvWriter(path) as w:
        w.write(t[keep], accel[keep], gyro[keep])
    r = subprocess.run([sys.executable, "-m", "imud", "noise", str(path), "--json"],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["stretches"] == 2 and out["samples"] == keep.sum()
    assert out["rate_hz"] == pytest.approx(rate)
    rows = np.loadtxt(path, delimiter=",", comments="#", skiprows=2)  # as the file holds them
    cut = int(np.flatnonzero(np.diff(rows[:, 0]) > 3e6)[0]) + 1
    full = np.array(out["stride"]) == 1
    taus = np.array(out["tau_s"])[full]
    got = np.hstack((np.array(out["gyro_adev_rad_s"]), np.array(out["accel_adev_m_s2"])))[full]
    for col, column in enumerate((4, 5, 6, 1, 2, 3)):  # gx gy gz ax ay az
        for i, tau in enumerate(taus):
            s = terms = 0.0
            for part in (rows[:cut, column], rows[cut:, column]):
                _, dev, _, ns = allantools.oadev(part, rate=rate, data_type="freq", taus=[tau])
                if len(dev):
                    s += dev[0] ** 2 * ns[0]
                    terms += ns[0]
            assert got[i, col] == pytest.approx(np.sqrt(s / terms), rel=1e-9)


def test_bad_input_is_said(tmp_path: Path) -> None:
    empty = tmp_path / "e.csv"
    empty.write_text("")
    for argv, says in (
        ([str(tmp_path / "none.csv")], "cannot read"),
        ([str(empty)], ""),
    ):
        r = subprocess.run([sys.executable, "-m", "imud", "noise", *argv],
                           capture_output=True, text=True, timeout=60)  # fmt: skip
        assert r.returncode == 2, r.stdout + r.stderr
        assert says in r.stderr and "Traceback" not in r.stderr, r.stderr
