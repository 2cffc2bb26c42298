"""BMI088 driver + two-die simulator at virtual time, over simulated SPI and I2C."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imud.channels import SampleFlag
from imud.chips.bmi088 import registers as R
from imud.chips.bmi088.registers import AccelRegister as A
from imud.chips.bmi088.registers import GyroRegister as GR
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
    assert rig.runner.status().chip_rate_hz == pytest.approx(gyro_rate, rel=5e-4)
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
    # one-sided density over the 532 Hz filter's noise band, 1.22 x its bandwidth (Bosch)
    sigma_g = math.radians(0.014) * math.sqrt(1.22 * 532)
    assert (m["gyro"] - t["gyro"]).std(axis=0) == pytest.approx([sigma_g] * 3, rel=0.1)
    # interpolation between two noisy accel samples averages them: less noise, never more
    sigma_a = 175e-6 * G * math.sqrt(1600 / 2)
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
    # the published stream is the gyro's: it lost exactly the frames the gyro die dropped
    assert rig.runner.lost_samples == rig.sim.gyro.frames_dropped > 0
    assert rig.driver.accel_skipped >= 255 and rig.sim.accel.frames_dropped > 0
    assert rig.driver.counters.fifo_overflows >= 4
    # The stop-on-full gyro FIFO keeps the first 100 frames (50 ms) of a stall, the stream-mode
    # accel FIFO the last 146 (91 ms): after the 200 ms and 500 ms stalls no accel frame is left
    # around the 100 gyro frames kept, so they are published with the accel NaN and flagged.
    # The 70 ms stall (plus at most a 10.5 ms poll) fits in the accel FIFO: nothing there.
    accel_bad = (m["flags"] & SampleFlag.ACCEL_INVALID) != 0
    runs = _runs(accel_bad)
    # 100 frames, and the odd gyro sample newer than the last accel frame read before the stall
    assert len(runs) == 2 and all(100 <= n <= 102 for _, n in runs), runs
    assert np.isnan(m["accel"][accel_bad]).all() and np.isfinite(m["accel"][~accel_bad]).all()
    assert np.isfinite(m["gyro"]).all()  # the gyro measured every one of them
    # each run is the start of a stall: the gyro gap (the frames it dropped) comes right after
    gaps = np.diff(m["seq"]) - 1
    assert [int(gaps[start + n - 1]) > 0 for start, n in runs] == [True, True]


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, length) of each run of True."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    return [(int(a), int(b - a)) for a, b in zip(edges[0::2], edges[1::2], strict=True)]


def _fill_gyro_fifo(rig: Rig, frames: int) -> None:
    """Let the gyro die latch `frames` frames past the 100 its FIFO holds (0: exactly full),
    with no poll in between, then poll at once. Ideal clocks: frame k of the die's grid is
    latched at origin + k periods."""
    g = rig.sim.gyro
    g.advance()  # the frames due so far
    have = len(g.fifo) // R.GYRO_FRAME_BYTES
    period = 1e9 / g.rate_hz
    k_full = g.next_k - 1 + (R.GYRO_FIFO_FRAMES - have)  # the frame that fills it
    t = g.grid_origin_ns + (k_full + frames + 0.5) * period  # between two frames
    rig.clock.advance(int(t) - rig.clock.now_ns())
    status = g.read(GR.FIFO_STATUS, 1)[0]
    assert status == (0x80 if frames else 0x00) | 100  # what the driver will read
    assert g.frames_dropped == frames
    rig.runner.step()  # the poll, now


def test_gyro_fifo_at_exactly_100_frames_without_overrun_loses_nothing() -> None:
    """FIFO_STATUS 100 with bit 7 clear: the FIFO just filled and every frame is there; the
    newest is the newest sample (docs/chips/bmi088.md, open question b)."""
    rig = _rig(sim={"seed": 12}, odr_hz=2000, accel_odr_hz=1600)
    rig.run(2.0)
    _fill_gyro_fifo(rig, 0)
    rig.run(1.0)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    assert rig.driver.counters.fifo_overflows == 0 and rig.sim.gyro.frames_dropped == 0
    assert rig.runner.lost_samples == 0 and np.all(np.diff(m["seq"]) == 1)
    assert not (m["flags"] & SampleFlag.ACCEL_INVALID).any()  # 50 ms: the accel FIFO kept all
    # and the full FIFO's samples are stamped as well as the others: within a third of a period
    i = match_truth(m, t)
    settled = m["t_ns"] > m["t_ns"][0] + 1e9  # once the clock fits settled
    assert len(np.unique((t["seq"][i] - m["seq"])[settled])) == 1
    assert np.abs(m["t_ns"] - t["t_ns"][i])[settled].max() < 0.33 * 500_000


@pytest.mark.parametrize("dropped", [1, 12])
def test_gyro_fifo_overrun_counts_the_frames_the_die_dropped(dropped: int) -> None:
    """FIFO_STATUS with bit 7 set: frames came while the 100-frame FIFO was full and were
    dropped. The gap in seq is exactly what the die dropped."""
    rig = _rig(sim={"seed": 13}, odr_hz=2000, accel_odr_hz=1600)
    rig.run(2.0)
    _fill_gyro_fifo(rig, dropped)
    rig.run(1.0)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    assert rig.driver.counters.fifo_overflows == 1 and rig.sim.gyro.frames_dropped == dropped
    gaps = np.diff(m["seq"]) - 1
    assert gaps.max() == dropped and (gaps > 0).sum() == 1
    assert rig.runner.lost_samples == dropped
    i = match_truth(m, t)
    settled = m["t_ns"] > m["t_ns"][0] + 1e9  # once the clock fits settled
    assert len(np.unique((t["seq"][i] - m["seq"])[settled])) == 1  # each seq the true one's


def test_invalid_temperature_is_nan_and_flagged_not_a_hole() -> None:
    """TEMP_MSB 0x80 means no valid temperature (DS 5.3.7): the samples carry NaN and the
    temperature flag, their accel and gyro published as usual; status keeps the last reading."""
    rig = _rig(sim={"seed": 14, "temperature_c": 30.0})
    rig.run(1.0)
    assert rig.runner.temperature_c == pytest.approx(30.0, abs=0.125)
    before = len(rig.out)
    rig.sim.accel.temp_reg = (0x80, 0x00)
    rig.sim.accel.temp_next_ns = rig.clock.now_ns() + 10**12  # no update meanwhile
    rig.run(0.5)
    late = concat(rig.batches()[before + 2 :])  # after the register changed
    bad = (late["flags"] & SampleFlag.TEMPERATURE_INVALID) != 0
    assert bad.all() and np.isnan(late["temp"]).all()
    assert np.isfinite(late["accel"]).all() and np.isfinite(late["gyro"]).all()
    assert not (late["flags"] & (SampleFlag.ACCEL_INVALID | SampleFlag.GYRO_INVALID)).any()
    assert rig.runner.lost_samples == 0
    assert rig.runner.temperature_c == pytest.approx(30.0, abs=0.125)


# The re-initialisation: both dies soft-reset, which empties their FIFOs (the gyro frames since
# the last poll: a poll interval, plus at most a phase step); the gyro die then restarts 30 ms
# later (its reset time), the accel power-up takes 2 x 5 ms and the settling 10 ms, after which
# both FIFOs are flushed: 50 ms without samples. At 2 kHz, give or take a sample of grid phase
# at either end.
START_S = 0.030 + 2 * 0.005 + 0.010
POLL_S = 0.010  # the BMI088 poll interval: its 10 ms cap (a quarter of either FIFO is longer)
PHASE_S = 0.0005  # the poll's phase step: at most a gyro period
LOST_MIN = 2000 * (START_S + POLL_S) - 1
LOST_MAX = 2000 * (START_S + POLL_S + PHASE_S) + 2


def _gaps(m: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    gaps = np.diff(m["seq"]) - 1
    return gaps, (m["flags"] & SampleFlag.ACCEL_INVALID) != 0


def test_gyro_die_glitch_reinitialises_both() -> None:
    rig = _rig(sim={"seed": 7})
    rig.run(1.0)
    rig.sim.gyro.regs[GR.GYRO_RANGE] = 3  # 250 deg/s, set behind our back
    rig.run(1.0)
    assert rig.driver.counters.bad_registers >= 1 and rig.runner.restarts == 1
    assert rig.sim.gyro.regs[GR.GYRO_RANGE] == 0 and rig.runner.state == "running"
    m = concat(rig.batches())
    gaps, accel_bad = _gaps(m)
    assert np.all(gaps >= 0)
    # one gap, the re-initialisation: what the reset emptied from the gyro FIFO and the 50 ms
    assert (gaps > 0).sum() == 1
    assert rig.runner.lost_samples == gaps.sum()
    assert LOST_MIN <= gaps.sum() <= LOST_MAX
    # the accel die never stopped: the accel is missing only for the gyro samples newer than its
    # last frame before the reset, and older than its first frame after it (an accel period,
    # 0.625 ms, each side: at most two gyro samples each)
    assert accel_bad.sum() <= 4
    assert np.isfinite(m["gyro"]).all()


def test_accel_die_reset_behind_our_back_is_noticed() -> None:
    """A brown-out resets the accel die: suspended again, in I2C mode again, its FIFO emptied.
    The gyro die goes on measuring: its samples are published, with the accel NaN and flagged,
    until the periodic check notices and both dies are reinitialised; only what the
    re-initialisation itself empties and takes is lost."""
    rig = _rig(sim={"seed": 8})
    rig.run(1.0)
    t_reset = rig.clock.now_ns()
    rig.sim.accel.write(A.ACC_SOFTRESET, bytes([R.SOFTRESET_CMD]))
    rig.run(1.5)
    assert rig.runner.restarts == 1 and rig.runner.state == "running"
    assert rig.sim.accel.sampling and rig.sim.accel.spi_mode
    m = concat(rig.batches())
    assert m["t_ns"][-1] > rig.clock.now_ns() - 50_000_000  # streaming again
    gaps, accel_bad = _gaps(m)
    assert (gaps > 0).sum() == 1 and rig.runner.lost_samples == gaps.sum()
    assert LOST_MIN <= gaps.sum() <= LOST_MAX
    last = int(np.flatnonzero(gaps)[0])  # the last sample before the re-initialisation
    idx = np.arange(len(m["seq"]))
    outage = (m["t_ns"] > t_reset) & (idx <= last)
    # the gyro samples of the outage (from the reset to the re-initialisation) are all there
    # (one gap only, above), every one with the accel NaN and flagged
    assert outage.any()
    assert accel_bad[outage].all() and np.isfinite(m["gyro"][outage]).all()
    assert np.isnan(m["accel"][outage]).all()
    # before the reset, only those newer than the last accel frame read (the frames the accel
    # die latched since that poll were lost to its reset)
    assert (accel_bad & (m["t_ns"] <= t_reset)).sum() <= 2000 * (POLL_S + PHASE_S + 1 / 1600) + 1
    # after the re-initialisation, only those older than the accel's first frame
    assert accel_bad[last + 1 :].sum() <= 2
    assert rig.runner.invalid_samples == accel_bad.sum()


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
