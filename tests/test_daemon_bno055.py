"""The daemon with simulated BNO055s, to a real Zenoh subscriber: one on I2C and one on its UART
behind a real pseudo-terminal, both at ~100 Hz with every fusion channel in SI units and every gap
counted; and calibration offsets that survive a daemon restart.

Nothing here depends on the scheduler: no loss rate is asserted, only that every gap the
subscriber sees is one the daemon counted, and what the samples say about the motion."""

from __future__ import annotations

import itertools
import math
import time
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import imud.client as ic
from imud.channels import Channel
from tests.daemon_fixture import DaemonProc

STREAMS = """
[[device]]
name = "bi2c"
chip = "bno055"
bus = { kind = "sim", bus = "i2c0", transport = "i2c", address = 0x28 }
offsets_file = "bi2c.toml"
save_offsets = false
[device.sim]
seed = 21
clock_error = 0.004
motion = { kind = "tumble", rate_dps = [0.0, 0.0, 45.0] }

[[device]]
name = "buart"
chip = "bno055"
bus = { kind = "sim", bus = "uart0", transport = "serial", baud = 115200 }
offsets_file = "buart.toml"
save_offsets = false
[device.sim]
seed = 22
clock_error = -0.003
motion = { kind = "tumble", rate_dps = [0.0, 0.0, 45.0] }
"""
ALL = {
    Channel.ACCEL,
    Channel.GYRO,
    Channel.TEMPERATURE,
    Channel.MAG,
    Channel.ORIENTATION,
    Channel.LINEAR_ACCEL,
    Channel.GRAVITY,
}


def cat(batches: list[Any], ch: Channel) -> np.ndarray:
    return np.concatenate([b.channels[ch] for b in batches]).astype(np.float64)


def valid(batches: list[Any], ch: Channel) -> np.ndarray:
    """The channel's values its samples do not flag invalid; those it flags read NaN."""
    values, bad = cat(batches, ch), np.concatenate([b.invalid(ch) for b in batches])
    assert np.isnan(values[bad]).all()
    return values[~bad]


def wait_streaming(d: DaemonProc, names: tuple[str, ...], samples: int = 200) -> None:
    """Until every named device has delivered `samples`: over its UART the BNO055 first spends
    a second or two finding its sample grid's phase with probes (imud/chips/bno055/uartpoll.py)."""
    end = time.monotonic() + 30.0
    while time.monotonic() < end:
        st = {s["name"]: s for s in d.status()["devices"]}
        if all(st[n]["samples"] >= samples for n in names):
            return
        time.sleep(0.2)
    raise AssertionError(f"no {samples} samples from {names} within 30 s: {st}")


def test_i2c_and_uart_stream_the_fusion_channels_with_every_gap_counted(tmp_path: Path) -> None:
    d = DaemonProc(tmp_path, STREAMS)
    try:
        d.wait_started()
        wait_streaming(d, ("bi2c", "buart"))
        raw = d.collect("imud/*/imu", 3.0)
        status = {s["name"]: s for s in d.status()["devices"]}
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    batches = [ic.decode(x) for x in raw]
    for name, clock_error in (("bi2c", 0.004), ("buart", -0.003)):
        bs = [b for b in batches if b.device == name]
        assert all(set(b.channels) == ALL for b in bs), name
        for prev, b in itertools.pairwise(bs):  # every gap on the wire was counted
            assert b.first_seq - (prev.first_seq + prev.count) == b.lost_before, name
        seq = np.concatenate([b.seq for b in bs])
        t = np.concatenate([b.t_ns for b in bs])
        # enough samples for the medians below, however many a loaded machine cost (a UART
        # read the scheduler delays skips a sample, counted: see imud/chips/bno055/uartpoll.py)
        assert len(seq) > 30 and np.all(np.diff(t) > 0) and np.all(np.diff(seq) > 0), name
        rate = (seq[-1] - seq[0]) / ((t[-1] - t[0]) / 1e9)  # the chip's, gaps included
        assert rate == pytest.approx(100.0 * (1 + clock_error), rel=0.03), name
        gyro = cat(bs, Channel.GYRO)
        assert np.median(gyro[:, 2]) == pytest.approx(math.radians(45.0), abs=0.02), name
        # the motion sensors in every sample; the fusion outputs and temperature in all but
        # those a probe alone read while the phase was sought (flagged invalid, NaN)
        for ch in (Channel.ACCEL, Channel.GYRO, Channel.MAG):
            assert not np.isnan(cat(bs, ch)).any(), (name, ch)
        grav = np.linalg.norm(valid(bs, Channel.GRAVITY), axis=1)
        assert len(grav) > 30, name
        np.testing.assert_allclose(grav, 9.80665, atol=0.03)
        quat = np.linalg.norm(valid(bs, Channel.ORIENTATION), axis=1)
        np.testing.assert_allclose(quat, 1.0, atol=0.002)
        mag = np.linalg.norm(cat(bs, Channel.MAG), axis=1)  # tesla: the 50 uT Earth field
        assert np.median(mag) == pytest.approx(50e-6, rel=0.1), name
        assert np.median(valid(bs, Channel.TEMPERATURE)) == 25.0
        st = status[name]
        assert st["state"] == "running" and st["chip_status"]["calibration"] is not None
        assert st["channels"] == [
            "accel", "gyro", "temperature_c", "mag", "orientation", "linear_accel", "gravity"
        ]  # fmt: skip
    assert status["buart"]["chip_status"]["uart"]["requests"] > 100


TUMBLE = """
[[device]]
name = "imu"
chip = "bno055"
bus = {{ kind = "sim", bus = "i2c0", address = 0x28 }}
offsets_file = "{path}"
save_offsets = {save}
[device.sim]
seed = 31
motion = {motion}
magnetic = {{ hard_iron_ut = [12.0, -7.0, 4.0] }}
"""


def wait_for(d: DaemonProc, ok: Any, timeout: float = 15.0) -> dict[str, Any]:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        st: dict[str, Any] = d.status()["devices"][0]["chip_status"]
        if ok(st):
            return st
        time.sleep(0.3)
    raise AssertionError(f"not reached within {timeout} s: {st}\n{d.log.read_text()}")


@pytest.mark.slow  # two daemons, one after the other, each calibrating the chip in real time
def test_bno055_offsets_survive_a_daemon_restart(tmp_path: Path) -> None:
    offsets = tmp_path / "imu.bno055-offsets.toml"
    (tmp_path / "run1").mkdir()
    (tmp_path / "run2").mkdir()
    tumble = '{ kind = "tumble", rate_dps = [90.0, 150.0, 60.0] }'
    d = DaemonProc(tmp_path / "run1", TUMBLE.format(path=offsets, save="true", motion=tumble))
    try:
        d.wait_started()
        first = wait_for(d, lambda s: s["offsets_saved_at"] is not None)
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    assert first["offsets_restored"] == "no file" and first["fully_calibrated"]
    saved = tomllib.loads(offsets.read_text())
    assert saved["chip"] == "bno055" and saved["device"] == "imu"
    assert [saved["mag_offset"][k] for k in "xyz"] == [192, -112, 64]  # 12, -7, 4 uT * 16
    # a fresh daemon, a chip fresh from power-on (offsets zero), a body that stays still: it
    # could never calibrate its accelerometer or magnetometer by itself
    still = '{ kind = "still" }'
    d = DaemonProc(tmp_path / "run2", TUMBLE.format(path=offsets, save="false", motion=still))
    try:
        d.wait_started()
        second = wait_for(d, lambda s: s["calibration"] is not None and s["fully_calibrated"])
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    assert second["offsets_restored"] == "ok"  # written in CONFIG mode, read back equal
    restored = second["offsets"]
    assert restored["accel"] == [saved["accel_offset"][k] for k in "xyz"]
    assert restored["mag"] == [192, -112, 64]
    assert restored["gyro"] == [saved["gyro_offset"][k] for k in "xyz"]
    assert [restored["accel_radius"], restored["mag_radius"]] == [1000, 800]
    assert second["calibration"] == {"sys": 3, "gyro": 3, "accel": 3, "mag": 3}
