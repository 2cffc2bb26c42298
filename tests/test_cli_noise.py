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


def _still_csv(
    path: Path, n: int, rate: float, temp: bool, seed: int = 7, step: float = 2e-6
) -> dict[str, float]:
    """A still recording with white noise of known N and a gyro random walk of known K (and a
    temperature ramp with a bias that follows it, when `temp`): N = sigma / sqrt(rate),
    K = step sigma * sqrt(rate)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=np.int64) * round(1e9 / rate) + 10**18
    sg, sa = 0.002, 0.02
    gyro = rng.normal(0.0, sg, (n, 3)) + np.cumsum(rng.normal(0.0, step, (n, 3)), axis=0)
    accel = rng.normal(0.0, sa, (n, 3)) + np.array([0.0, 0.0, 9.81])
    kw: dict[str, Any] = {}
    if temp:
        tc = np.linspace(10.0, 30.0, n)
        gyro[:, 0] += 1e-4 * (tc - 20.0)  # 0.1 mrad/s per degree on x
        kw["temp"] = tc
    with CsvWriter(path, has_temp=temp, comments={"device": "imu7", "chip": "mpu6050"}) as w:
        w.write(t, accel, gyro, **kw)
    return {"gyro_n": sg / np.sqrt(rate), "accel_n": sa / np.sqrt(rate),
            "gyro_k": step * np.sqrt(rate)}  # fmt: skip


def _run(*argv: str) -> Any:
    from click.testing import CliRunner

    from imud.cli.noise import noise

    return CliRunner().invoke(noise, list(argv), catch_exceptions=False)


def test_fits_and_kalibr_yaml_carry_the_known_figures(tmp_path: Path) -> None:
    """N and K of a synthetic still recording come back inside their intervals; the Kalibr file
    has the five keys Kalibr's imu.yaml needs (kalibr wiki "YAML formats"), the worst axis."""
    truth = _still_csv(tmp_path / "s.csv", 120_000, 200.0, temp=False)
    yaml_path = tmp_path / "imu.yaml"
    r = _run(str(tmp_path / "s.csv"), "--json", "--kalibr", str(yaml_path))
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    fit = out["fit"]
    for a in "xyz":
        n = fit["gyro"][a]["N"]
        assert n["lo95"] <= truth["gyro_n"] <= n["hi95"] and n["unit"] == "rad/s/sqrt(Hz)"
        assert fit["accel"][a]["N"]["lo95"] <= truth["accel_n"] <= fit["accel"][a]["N"]["hi95"]
        k = fit["gyro"][a]["K"]
        assert k["lo95"] <= truth["gyro_k"] <= k["hi95"]
        # discrete: N sqrt(f) is the per-sample sigma of the white noise
        assert fit["gyro"][a]["N_discrete"] == pytest.approx(0.002, rel=0.02)
    # imud's own (one-sided) density is sqrt(2) N
    n = [fit["gyro"][a]["N"]["value"] for a in "xyz"]
    np.testing.assert_allclose(fit["imud"]["gyro"]["one_sided_density"], np.sqrt(2) * np.array(n))
    lines = [x.split("#")[0].strip() for x in yaml_path.read_text().splitlines()]
    kv = dict(x.split(":", 1) for x in lines if x)
    assert set(kv) == {"accelerometer_noise_density", "accelerometer_random_walk",
                       "gyroscope_noise_density", "gyroscope_random_walk", "rostopic",
                       "update_rate"}  # fmt: skip
    assert float(kv["gyroscope_noise_density"]) == pytest.approx(
        max(fit["gyro"][a]["N"]["value"] for a in "xyz")
    )
    assert float(kv["update_rate"]) == pytest.approx(200.0)
    assert kv["rostopic"].strip() == "/imu7/imu/data_raw"
    assert out["chip"] == "mpu6050" and out["device"] == "imu7"
    # nothing is overwritten
    r = _run(str(tmp_path / "s.csv"), "--kalibr", str(yaml_path))
    assert r.exit_code == 2 and "exists" in r.output


def test_by_temperature_bins_the_bias_and_the_noise(tmp_path: Path) -> None:
    """A gyro bias of 0.1 mrad/s per degree on x: each 5-degree bin's mean is the bias at its
    centre (the ramp is linear); N inside its interval in (almost) every bin and axis."""
    truth = _still_csv(tmp_path / "t.csv", 100_000, 200.0, temp=True, step=0.0)
    r = _run(str(tmp_path / "t.csv"), "--json", "--by-temperature", "5")
    assert r.exit_code == 0, r.output
    bins = json.loads(r.output)["by_temperature"]
    assert [(b["lo_c"], b["hi_c"]) for b in bins] == [(10, 15), (15, 20), (20, 25), (25, 30),
                                                      (30, 35)]  # fmt: skip
    inside = 0
    for b in bins[:4]:
        centre = (b["lo_c"] + b["hi_c"]) / 2
        # the x bias at the bin's centre, within the mean's white noise (0.002 / sqrt(25,000))
        assert b["gyro_mean_rad_s"][0] == pytest.approx(1e-4 * (centre - 20.0), abs=5e-5)
        assert b["gyro_mean_rad_s"][1] == pytest.approx(0.0, abs=5e-5)
        inside += sum(x["lo95"] <= truth["gyro_n"] <= x["hi95"] for x in b["gyro_n"])
    assert inside >= 10  # of 12 95 % intervals (P(fewer) = 2 %)
    r = _run(str(_still_csv_path(tmp_path)), "--by-temperature")
    assert r.exit_code == 2 and "no temperature recorded" in r.output


def _still_csv_path(tmp_path: Path) -> Path:
    p = tmp_path / "nt.csv"
    _still_csv(p, 2_000, 100.0, temp=False)
    return p


@pytest.mark.extra  # matplotlib (the plot extra)
def test_plot_writes_a_png(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    _still_csv(tmp_path / "s.csv", 40_000, 200.0, temp=False)
    r = _run(str(tmp_path / "s.csv"), "--plot", str(tmp_path / "a.png"))
    assert r.exit_code == 0, r.output
    data = (tmp_path / "a.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and 10_000 < len(data) < 150_000


def test_plot_without_matplotlib_says_how_to_install(tmp_path: Path, monkeypatch: Any) -> None:
    import builtins

    real = builtins.__import__

    def no_mpl(name: str, *a: Any, **k: Any) -> Any:
        if name.startswith("matplotlib"):
            raise ImportError("No module named 'matplotlib'")
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_mpl)
    p = _still_csv_path(tmp_path)
    r = _run(str(p), "--plot", str(tmp_path / "a.png"))
    assert r.exit_code == 2 and "pip install 'imud[plot]'" in r.output
