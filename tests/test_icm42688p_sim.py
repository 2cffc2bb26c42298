"""ICM-42688-P driver + simulator at virtual time, over simulated SPI and I2C."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imud.channels import SampleFlag
from imud.chips.icm42688p.registers import Bank0 as reg
from imud.chips.icm42688p.registers import Bank1, Bank2
from imud.chips.icm42688p.sim import ACCEL_STARTUP_NS, GYRO_STARTUP_NS
from imud.sim.spi import SimSpiDev
from tests.helpers import Rig, concat, make_rig, match_truth

G = 9.80665
SPI = {"kind": "sim", "transport": "spi", "speed_hz": 20_000_000}


def _ideal(**sim: object) -> dict[str, object]:
    return {"errors": {"ideal": True}, **sim}


@pytest.mark.parametrize("odr", [32000.0, 16000.0, 8000.0, 1000.0, 200.0, 12.5])
def test_every_rate_streams_continuously_on_the_chips_clock(odr: float) -> None:
    rig = make_rig({"chip": "icm42688p", "odr_hz": odr, "bus": SPI},
                   _ideal(clock_error=-0.008, seed=1))  # fmt: skip
    seconds = 3.0 if odr >= 1000 else 40.0
    rig.run(seconds, jitter_ns=int(min(100_000, 2e9 / odr)))
    m = concat(rig.batches())
    true_rate = odr * (1 - 0.008)
    assert rig.runner.state == "running" and rig.runner.lost_samples == 0
    assert rig.driver.counters.fifo_overflows == 0 and rig.driver.invalid_packets == 0
    assert np.all(np.diff(m["seq"]) == 1) and np.all(np.diff(m["t_ns"]) > 0)
    assert rig.runner.pipeline.clock.rate_hz == pytest.approx(true_rate, rel=3e-4)
    # the FIFO never passes half full: poll interval against its capacity in time
    assert rig.driver.poll_interval_ns * odr / 1e9 <= rig.driver.fifo_capacity / 2


def test_constant_rotation_about_z_at_32khz_reads_1_745_rad_s() -> None:
    rig = make_rig(
        {"chip": "icm42688p", "odr_hz": 32000, "gyro_range_dps": 250, "bus": SPI},
        _ideal(seed=2, motion={"kind": "tumble", "rate_dps": [0.0, 0.0, 100.0]}),
    )
    rig.run(2.0)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    assert m["gyro"][:, 2].mean() == pytest.approx(1.745329, abs=2e-4)
    i = match_truth(m, t)
    settled = m["t_ns"] > m["t_ns"][0] + 1e9
    err = np.abs(m["t_ns"] - t["t_ns"][i])[settled]
    assert err.max() < 0.3 * 31_250  # stamps within a third of a 31 us period
    # the accel turns with the body: compare sample by sample with the truth
    da = m["accel"][settled] - t["accel"][i][settled]
    sigma = 70e-6 * G * math.sqrt(32000)
    assert np.abs(da.mean(axis=0)).max() < 0.01 and da.std() < 1.3 * sigma


def test_noise_matches_datasheet_density() -> None:
    rig = make_rig({"chip": "icm42688p", "odr_hz": 1000, "accel_range_g": 2,
                    "gyro_range_dps": 125, "bus": SPI}, _ideal(seed=3))  # fmt: skip
    rig.run(5.0)
    m = concat(rig.batches())
    # one-sided densities over the UI filter's band, ODR/4 = 250 Hz (docs/chips/icm42688p.md)
    assert m["accel"].std(axis=0) == pytest.approx([70e-6 * G * math.sqrt(250)] * 3, rel=0.1)
    sg = math.radians(0.0028) * math.sqrt(250)
    assert m["gyro"].std(axis=0) == pytest.approx([sg] * 3, rel=0.1)
    assert m["accel"].mean(axis=0)[2] == pytest.approx(G, abs=0.005)
    assert m["temp"].mean() == pytest.approx(25.0, abs=0.5)  # int8 FIFO temperature


def test_hires_packets_carry_20_bit_data() -> None:
    rig = make_rig(
        {"chip": "icm42688p", "odr_hz": 8000, "hires": True, "bus": SPI},
        _ideal(seed=4, motion={"kind": "tumble", "rate_dps": [0.0, 0.0, 100.0]},
               errors={"ideal": True, "gyro_noise_dps_rthz": 0.0, "accel_noise_ug_rthz": 0.0}),
    )  # fmt: skip
    rig.run(1.0)
    m = concat(rig.batches())
    gz = m["gyro"][:, 2]
    # with noise off the 20-bit value is 100 deg/s to within one 20-bit LSB (2000/2^19 deg/s)
    assert np.abs(np.degrees(gz) - 100.0).max() <= 2000 / 2**19 * 1.01
    assert m["temp"].std() < 0.01  # int16 temperature at 132.48 LSB/C


def test_stop_on_full_overflow_keeps_the_fifo_and_counts_the_rest() -> None:
    rig = make_rig({"chip": "icm42688p", "odr_hz": 8000, "bus": SPI},
                   _ideal(seed=5, clock_error=0.004))  # fmt: skip
    rig.run(4.0, jitter_ns=50_000)
    for _ in range(3):
        rig.clock.advance(60_000_000)  # a 60 ms stall: 480 samples, the FIFO holds 128
        rig.run(1.0, jitter_ns=50_000)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    assert rig.driver.counters.fifo_overflows == 3 and rig.runner.state == "running"
    i = match_truth(m, t)
    # nothing discarded: the full FIFO's 128 samples were read, the chip dropped the rest. (From
    # the second on: one read pins the chip's phase only to within a period, so the very first
    # batch may be stamped nearer a neighbour's true instant than its own until the fit has a
    # few reads; the stalls come at 4 s.)
    settled = m["t_ns"] > m["t_ns"][0] + 1e9
    assert len(np.unique((t["seq"][i] - m["seq"])[settled])) == 1
    gaps = np.diff(m["seq"]) - 1
    assert (gaps > 0).sum() == 3 and rig.runner.lost_samples == gaps.sum()
    # 60 ms of samples (plus up to a poll interval and jitter either side) minus the 128 kept
    most_ms = 60 + 2 * rig.driver.poll_interval_ns / 1e6
    assert 480 * 1.004 - 128 - 2 <= gaps.max() <= most_ms * 8.032 - 128


def test_spi_faults_are_bus_errors_not_data() -> None:
    rig = make_rig({"chip": "icm42688p", "odr_hz": 4000, "bus": SPI},
                   _ideal(seed=6, nak_rate=0.03))  # fmt: skip
    rig.run(5.0, jitter_ns=50_000)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    assert rig.runner.bus_errors + rig.driver.counters.bad_transfers > 5
    assert rig.runner.state == "running"
    i = match_truth(m, t)
    # a garbled burst never becomes data: every published sample matches the truth within noise
    sigma = 70e-6 * G * math.sqrt(4000)
    assert np.abs(m["accel"] - t["accel"][i]).max() < 6 * sigma
    assert np.all(np.diff(m["seq"]) >= 1)
    assert rig.runner.lost_samples == (np.diff(m["seq"]) - 1).sum()


def test_start_up_packets_without_any_data_are_holes_and_half_valid_ones_are_published() -> None:
    """Sensors restarting deliver the invalid marker until their start-up time is over, the
    accel sooner than the gyro. Packets with neither are holes (not published, counted lost);
    packets with accel data but no gyro data are published with the gyro NaN and flagged."""
    rig = make_rig({"chip": "icm42688p", "odr_hz": 1000, "bus": SPI}, _ideal(seed=7))
    rig.run(1.0)
    published_before = rig.runner.samples
    rig.sim.advance()  # samples due so far were latched before the restart
    rig.sim.on_since_ns = rig.clock.now_ns()  # both sensors restart (as after a glitch)
    rig.sim._discard_staged()  # (as a register write does: samples computed ahead are redone)
    rig.run(1.0)
    holes = round(ACCEL_STARTUP_NS * 1000 / 1e9)  # 1 kHz, ideal clock
    half = round((GYRO_STARTUP_NS - ACCEL_STARTUP_NS) * 1000 / 1e9)
    assert abs(rig.driver.invalid_packets - holes) <= 1
    m = concat(rig.batches())
    gyro_bad = (m["flags"] & SampleFlag.GYRO_INVALID) != 0
    accel_bad = (m["flags"] & SampleFlag.ACCEL_INVALID) != 0
    # the holes: one gap in seq, exactly as long as the packets with no data, counted as lost
    gaps = np.diff(m["seq"]) - 1
    assert (gaps > 0).sum() == 1 and gaps.sum() == rig.driver.invalid_packets
    assert rig.runner.lost_samples == rig.driver.invalid_packets
    # right after the gap: the packets with accel data only, gyro NaN and flagged
    after = int(np.flatnonzero(gaps)[0]) + 1
    assert abs(int(gyro_bad.sum()) - half) <= 1
    assert gyro_bad[after : after + int(gyro_bad.sum())].all()
    assert not accel_bad.any()  # an invalid accel alone made a hole, never a NaN sample
    assert np.isnan(m["gyro"][gyro_bad]).all()
    assert np.isfinite(m["gyro"][~gyro_bad]).all()
    assert np.abs(m["gyro"][~gyro_bad]).max() < 0.05  # still: no -32768 marker as data
    sigma = 70e-6 * G * math.sqrt(1000)  # datasheet accel noise density at 1 kHz
    assert np.abs(m["accel"][gyro_bad, 2] - G).max() < 5 * sigma  # their accel is data
    assert np.isfinite(m["temp"]).all()  # the temperature never stopped
    assert rig.runner.invalid_samples == gyro_bad.sum()
    assert rig.runner.samples == len(m["seq"]) > published_before


def test_i2c_at_its_top_rate() -> None:
    rig = make_rig({"chip": "icm42688p", "odr_hz": 2000,
                    "bus": {"kind": "sim", "address": 0x69}}, _ideal(seed=8))  # fmt: skip
    rig.run(2.0)
    assert rig.runner.samples > 3800 and rig.runner.lost_samples == 0


def test_register_glitch_reinitialises() -> None:
    rig = make_rig({"chip": "icm42688p", "odr_hz": 1000, "bus": SPI}, _ideal(seed=9))
    rig.run(1.0)
    rig.sim.banks[0][reg.GYRO_CONFIG0] = 0x46  # +-500 deg/s, set behind our back
    rig.run(2.0)
    assert rig.driver.counters.bad_registers >= 1 and rig.runner.restarts >= 1
    assert rig.sim.banks[0][reg.GYRO_CONFIG0] == 0x06  # FS_SEL 0 (2000 deg/s), ODR code 6 (1 kHz)
    assert rig.runner.state == "running"


@pytest.mark.parametrize(
    ("bank", "register", "configured", "corrupt"),
    [
        (1, Bank1.GYRO_CONFIG_STATIC3, 13, 6),  # gyro AAF DELT: the 585 Hz row, set to 258 Hz's
        (1, Bank1.GYRO_CONFIG_STATIC2, 0xA0, 0xA2),  # GYRO_AAF_DIS set: the gyro AAF off
        (2, Bank2.ACCEL_CONFIG_STATIC3, 0x40, 0x90),  # accel DELTSQR[7:0] of 1163 Hz -> 943 Hz
    ],
)
def test_anti_alias_register_glitch_reinitialises(
    bank: int, register: int, configured: int, corrupt: int
) -> None:
    """The periodic check covers the anti-alias filter registers of banks 1 and 2 too: a
    glitch there is found within one round (one register per 100 ms) and the chip reset and
    reconfigured, with the loss counted."""
    rig = make_rig({"chip": "icm42688p", "odr_hz": 1000, "bus": SPI}, _ideal(seed=11))
    rig.run(0.5)
    assert rig.sim.banks[bank][register] == configured
    rig.sim.banks[bank][register] = corrupt
    rig.run(0.1 * 16 + 0.5)  # 16 configured registers at the default settings, one a 100 ms
    assert rig.driver.counters.bad_registers == 1 and rig.runner.restarts == 1
    assert rig.sim.banks[bank][register] == configured  # reset and configured again
    assert rig.runner.state == "running"
    m = concat(rig.batches())
    assert np.all(np.diff(m["seq"]) >= 1) and np.all(np.diff(m["t_ns"]) > 0)
    assert rig.runner.lost_samples == (np.diff(m["seq"]) - 1).sum() > 0


@pytest.fixture(scope="module")
def stalls_at_32khz_with_slow_transfers() -> tuple[Rig, dict[str, np.ndarray], np.ndarray]:
    """Each SPI transfer takes 60 us + 0.8 us a byte (10 MHz): a status read brackets the FIFO
    count by ~65 us, two 31 us periods at 32 kHz, so host time alone cannot tell a gap's sample
    count to the sample. The FIFO timestamp, on the chip's own clock, does. Five stalls overflow
    the 4 ms FIFO. Returns the rig, the published samples, and each one's stamp error against
    the true instant of the sample its seq names."""
    rig = make_rig({"chip": "icm42688p", "odr_hz": 32000, "bus": SPI},
                   _ideal(seed=10, clock_error=0.007))  # fmt: skip
    rig.driver.dev.spi = SimSpiDev(rig.sim, transfer_time=(rig.clock, 60_000, 800))
    rig.run(2.0, jitter_ns=30_000)
    for stall in (7_000_000, 12_000_000, 23_000_000, 9_000_000, 15_000_000):
        rig.clock.advance(stall)  # the FIFO (4 ms) overflows each time
        rig.run(0.5, jitter_ns=30_000)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    # the offset between seq and the chip's own index, fixed by the first samples: from then on
    # every sample's true instant follows from its seq
    i = match_truth(m, t)
    offset = int(np.median((t["seq"][i] - m["seq"])[:1000]))
    err = np.abs(m["t_ns"] - t["t_ns"][m["seq"] + offset - t["seq"][0]])
    return rig, m, err


def test_fifo_timestamp_counts_gaps_exactly_when_host_bounds_are_wider_than_a_period(
    stalls_at_32khz_with_slow_transfers: tuple[Rig, dict[str, np.ndarray], np.ndarray],
) -> None:
    rig, m, err = stalls_at_32khz_with_slow_transfers
    assert rig.driver.counters.fifo_overflows >= 5  # a 2 kB burst at 10 MHz itself takes 1.7 ms
    # A gap miscounted by one would put the typical stamp after it a whole period (31 us) off;
    # counted exactly, the stamps after every gap settle within a few us of the truth
    gaps = np.flatnonzero(np.diff(m["seq"]) > 1) + 1
    assert len(gaps) >= 5
    for seg in np.split(err, gaps):
        assert np.median(seg) < 0.25 * 31_250
    assert rig.runner.lost_samples == (np.diff(m["seq"]) - 1).sum()
    # the FIFO timestamp's step: 31.25 us a sample in ticks of 32/30 us (docs/chips/icm42688p.md
    # 3.3), on the chip's clock whatever its error
    assert rig.runner.pipeline.clock._tps == pytest.approx(
        1e9 / 32000 / (1e6 * 32 / 30 / 1e3), rel=1e-3
    )


def test_stamps_after_a_gap_never_stray_a_whole_period(
    stalls_at_32khz_with_slow_transfers: tuple[Rig, dict[str, np.ndarray], np.ndarray],
) -> None:
    # a stamp a period or more off is nearer a neighbour's true instant than its own sample's
    _, _, err = stalls_at_32khz_with_slow_transfers
    assert err.max() < 31_250
