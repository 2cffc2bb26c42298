"""BMI088 driver + two-die simulator at virtual time, over simulated SPI and I2C."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imud.chips.bmi088 import decode as d
from imud.chips.bmi088 import registers as R
from imud.chips.bmi088.registers import AccelRegister as A
from imud.chips.bmi088.registers import GyroRegister as G
from tests.helpers import Rig, concat, make_rig, match_truth

G = 9.80665
SPI = ({"kind": "sim", "bus": "spi1", "transport": "spi", "cs": 0},
       {"kind": "sim", "bus": "spi1", "transport": "spi", "cs": 1})  # fmt: skip
I2C = ({"kind": "sim", "address": 0x18}, {"kind": "sim", "address": 0x68})


Buses = tuple[dict[str, object], dict[str, object]]


def _rig(buses: Buses = SPI, sim: dict[str, object] | None = None, **device: object) -> Rig:
    return make_rig({"chip": "bmi088", "bus": buses[0], "gyro_bus": buses[1], **device},
                    {"errors": {"ideal": True}, **(sim or {})})  # fmt: skip


def _settled(rig: Rig, after_s: float = 1.0) -> tuple[dict[str, np.ndarray], ...]:
    """Published samples after the clock fits settled, and the truth sample each one is."""
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    keep = m["t_ns"] > m["t_ns"][0] + after_s * 1e9
    m = {k: v[keep] for k, v in m.items()}
    i = match_truth(m, t)
    return m, {k: v[i] for k, v in t.items()}


@pytest.mark.parametrize(
    ("gyro_odr", "accel_odr", "buses"),
    [(2000, 1600, SPI), (2000, 1600, I2C), (1000, 400, SPI), (400, 800, SPI), (100, 12.5, I2C)],
)
def test_rates_follow_the_gyro_die_clock(gyro_odr: int, accel_odr: float, buses: Buses) -> None:
    rig = _rig(buses, {"seed": 1, "errors": {}}, odr_hz=gyro_odr, accel_odr_hz=accel_odr)
    seconds = 4.0 if gyro_odr >= 1000 else 20.0
    rig.run(seconds, jitter_ns=200_000)
    m = concat(rig.batches())
    gyro_rate = rig.sim.gyro.rate_hz
    assert rig.runner.state == "running" and rig.runner.lost_samples == 0
    assert np.all(np.diff(m["seq"]) == 1) and np.all(np.diff(m["t_ns"]) > 0)
    # each die on its own oscillator, and the published stream runs on the gyro's
    assert abs(rig.sim.gyro.clock_error - rig.sim.accel.clock_error) > 1e-3
    assert rig.runner.status()["chip_rate_hz"] == pytest.approx(gyro_rate, rel=5e-4)
    assert rig.sim.accel.rate_hz == pytest.approx(accel_odr * (1 + rig.sim.accel.clock_error))
    # all but the ~50 ms start sequence (resets, power-up waits), gyro samples older than the
    # first accel sample and the newest, waiting for the accel sample after them
    slack = gyro_rate * (0.01 + 2 / accel_odr)
    assert len(m["seq"]) == pytest.approx(gyro_rate * (seconds - 0.05), abs=slack)


@pytest.mark.parametrize("gyro_range", [125, 250, 500, 1000, 2000])
def test_gyro_ranges_read_the_true_rate(gyro_range: int) -> None:
    rate = 0.8 * gyro_range
    rig = _rig(sim={"seed": 2, "motion": {"kind": "tumble", "rate_dps": [0.0, 0.0, rate]}},
               gyro_range_dps=gyro_range)  # fmt: skip
    rig.run(1.5)
    m = concat(rig.batches())
    lsb = math.radians(gyro_range) / 32768
    assert m["gyro"][:, 2].mean() == pytest.approx(math.radians(rate), abs=2 * lsb + 2e-3)
    assert rig.driver.gyro_scale == pytest.approx(lsb)


@pytest.mark.parametrize("accel_range", [3, 6, 12, 24])
def test_accel_ranges_read_gravity(accel_range: int) -> None:
    rig = _rig(sim={"seed": 3, "motion": {"kind": "still", "roll_deg": 30.0}},
               accel_range_g=accel_range)  # fmt: skip
    rig.run(1.5)
    m, t = _settled(rig, 0.5)
    assert rig.driver.accel_scale == pytest.approx(accel_range * G / 32768)
    np.testing.assert_allclose(m["accel"].mean(axis=0), t["accel"].mean(axis=0), atol=0.01)


def test_a_fast_tumble_is_interpolated_onto_gyro_times() -> None:
    """At 1000 deg/s about x, gravity turns through the y-z plane at 17 rad/s: taking the
    nearest accel sample instead of interpolating would be off by ~0.03 m/s^2 rms."""
    rig = _rig(
        sim={"seed": 4, "motion": {"kind": "tumble", "rate_dps": [1000.0, 0.0, 0.0]},
             "errors": {"ideal": True, "accel_noise_ug_rthz": 0, "gyro_noise_dps_rthz": 0},
             "clock_error": None},
        accel_range_g=3,
    )  # fmt: skip
    rig.run(3.0, jitter_ns=100_000)
    m, t = _settled(rig)
    err = m["accel"] - t["accel"]
    assert np.sqrt((err[:, 1:] ** 2).mean()) < 0.006
    assert np.abs(err).max() < 0.03
    swing = 9.80665 * math.radians(1000) * 1e9 / 1600 / 2  # nearest-sample error scale
    assert swing / 1e9 > 0.05  # the test would see it
    np.testing.assert_allclose(m["gyro"][:, 0], math.radians(1000), atol=2e-3)


def test_constant_rotation_about_z_reads_1_745_rad_s_with_noise() -> None:
    rig = _rig(sim={"seed": 5, "motion": {"kind": "tumble", "rate_dps": [0.0, 0.0, 100.0]}},
               gyro_range_dps=250)  # fmt: skip
    rig.run(3.0)
    m, t = _settled(rig)
    assert m["gyro"][:, 2].mean() == pytest.approx(1.745329, abs=1e-3)
    sigma_g = math.radians(0.014) * math.sqrt(2000)
    assert (m["gyro"] - t["gyro"]).std(axis=0) == pytest.approx([sigma_g] * 3, rel=0.1)
    # interpolation between two noisy accel samples averages them: less noise, never more
    sigma_a = 175e-6 * G * math.sqrt(1600)
    da = (m["accel"] - t["accel"]).std(axis=0)
    assert np.all(da < sigma_a * 1.05) and np.all(da > sigma_a * 0.6)


def test_overflow_of_both_fifos_is_counted_exactly() -> None:
    rig = _rig(sim={"seed": 6}, odr_hz=2000, accel_odr_hz=1600)
    rig.run(3.0, jitter_ns=100_000)
    # 70 ms overflows the gyro FIFO (50 ms) only; 200 ms both; 500 ms makes the accel skip
    # count saturate at 255 ("more than 255"), so its gap is judged from the clock
    for stall in (0.07, 0.2, 0.5):
        rig.clock.advance(int(stall * 1e9))
        rig.run(1.5, jitter_ns=100_000)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    i = match_truth(m, t)
    settled = m["t_ns"] > m["t_ns"][0] + 1e9
    assert rig.runner.state == "running" and rig.runner.restarts == 0
    # every sample published carries the seq of the true sample it is: gaps counted exactly
    assert len(np.unique((t["seq"][i] - m["seq"])[settled])) == 1
    assert rig.runner.lost_samples == (np.diff(m["seq"]) - 1).sum()
    # the gyro die dropped some; the accel die's gaps made more gyro samples holes
    assert rig.runner.lost_samples >= rig.sim.gyro.frames_dropped > 0
    assert rig.driver.accel_skipped >= 255 and rig.sim.accel.frames_dropped > 0
    assert rig.driver.counters.fifo_overflows >= 4


def test_gyro_die_glitch_reinitialises_both() -> None:
    rig = _rig(sim={"seed": 7})
    rig.run(1.0)
    rig.sim.gyro.regs[G.GYRO_RANGE] = 3  # 250 deg/s, set behind our back
    rig.run(1.0)
    assert rig.driver.counters.bad_registers >= 1 and rig.runner.restarts == 1
    assert rig.sim.gyro.regs[G.GYRO_RANGE] == 0 and rig.runner.state == "running"
    m = concat(rig.batches())
    assert np.all(np.diff(m["seq"]) >= 1)
    assert rig.runner.lost_samples == (np.diff(m["seq"]) - 1).sum() > 0


def test_accel_die_reset_behind_our_back_is_noticed() -> None:
    """A brown-out resets the accel die: suspended again, in I2C mode again."""
    rig = _rig(sim={"seed": 8})
    rig.run(1.0)
    rig.sim.accel.write(A.ACC_SOFTRESET, bytes([R.SOFTRESET_CMD]))
    rig.run(1.5)
    assert rig.runner.restarts == 1 and rig.runner.state == "running"
    assert rig.sim.accel.sampling and rig.sim.accel.spi_mode
    m = concat(rig.batches())
    assert m["t_ns"][-1] > rig.clock.now_ns() - 50_000_000  # streaming again


def test_a_die_at_the_wrong_address_is_named() -> None:
    rig = _rig(I2C, sim={"seed": 9})
    rig.bus.attach(0x68, rig.sim.accel)  # the accel die answers where the gyro should be
    rig.run(0.2)
    assert rig.runner.state == "error"
    assert "gyro die" in str(rig.runner.last_error) and "gyro_bus" in str(rig.runner.last_error)
    assert "0x1e" in str(rig.runner.last_error)


def test_i2c_faults_are_counted_and_never_become_data() -> None:
    rig = _rig(I2C, sim={"seed": 10, "nak_rate": 0.02})
    rig.run(4.0, jitter_ns=100_000)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    assert rig.runner.bus_errors > 5 and rig.runner.state == "running"
    i = match_truth(m, t)
    sigma = math.radians(0.014) * math.sqrt(2000)
    assert np.abs(m["gyro"] - t["gyro"][i]).max() < 6 * sigma
    assert rig.runner.lost_samples == (np.diff(m["seq"]) - 1).sum()


def test_temperature_follows_the_die_with_its_update_period() -> None:
    rig = _rig(sim={"seed": 11, "temperature_c": 30.0, "temperature_ramp_c_per_min": 60.0})
    rig.run(6.0)
    m, t = _settled(rig)
    # the register is 0.125 C steps refreshed every 1.28 s: at 1 C/s it lags by at most that
    lag = t["temp"] - m["temp"]
    assert np.all(lag > -0.13) and np.all(lag < 1.28 + 0.13)
    assert m["temp"][-1] > 34.0
