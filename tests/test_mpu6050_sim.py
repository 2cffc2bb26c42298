"""Driver + simulator at virtual time: rates, timestamps against truth, gaps, recovery."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imud.channels import SampleFlag
from imud.chips.mpu6050.registers import Register as reg
from tests.helpers import concat, make_rig, match_truth

G = 9.80665


def _ideal(**sim: object) -> dict[str, object]:
    return {"errors": {"ideal": True}, **sim}


@pytest.mark.parametrize("clock_error", [0.013, -0.02, 0.0])
def test_rate_continuity_and_chip_clock(clock_error: float) -> None:
    rig = make_rig({"odr_hz": 1000}, _ideal(clock_error=clock_error, seed=4))
    rig.run(10.0, jitter_ns=300_000)
    m = concat(rig.batches())
    assert rig.runner.state == "running"
    assert rig.runner.lost_samples == 0 and rig.driver.counters.fifo_overflows == 0
    assert np.all(np.diff(m["seq"]) == 1) and m["seq"][0] == 0
    assert np.all(np.diff(m["t_ns"]) > 0)
    true_rate = 1000.0 * (1 + clock_error)
    assert rig.runner.pipeline is not None
    assert rig.runner.pipeline.clock.rate_hz == pytest.approx(true_rate, rel=2e-4)
    # every sample the chip produced after the first read is delivered
    assert len(m["seq"]) == pytest.approx(10.0 * true_rate, abs=0.15 * true_rate)


@pytest.mark.parametrize(
    ("odr", "dlpf"), [(1000.0, 188), (500.0, 98), (200.0, 42), (50.0, 5), (8000 / 9, 256)]
)
def test_each_rate_timestamped_against_truth(odr: float, dlpf: int) -> None:
    rig = make_rig({"odr_hz": odr, "dlpf_hz": dlpf}, _ideal(clock_error=0.011, seed=5))
    rig.run(12.0, jitter_ns=200_000)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    i = match_truth(m, t)
    settled = m["t_ns"] > m["t_ns"][0] + 3e9
    err = (m["t_ns"] - t["t_ns"][i])[settled]
    period = 1e9 / (odr * 1.011)
    assert np.abs(err).max() < 0.15 * period + 60_000, f"max error {np.abs(err).max()} ns"
    # the sequence number is the chip's sample index: constant offset to the truth index
    assert len(np.unique(t["seq"][i] - m["seq"])) == 1


def test_still_level_reads_gravity_and_zero_rate_within_noise() -> None:
    rig = make_rig({"odr_hz": 1000, "accel_range_g": 4}, _ideal(seed=6))
    rig.run(5.0)
    m = concat(rig.batches())
    n = len(m["seq"])
    # one-sided datasheet densities over the DLPF's band (dlpf_hz 188: accel 184 Hz, gyro 188 Hz)
    sigma_a = 400e-6 * G * math.sqrt(184.0)
    sigma_g = math.radians(0.005) * math.sqrt(188.0)
    mean_a = m["accel"].mean(axis=0)
    assert np.abs(mean_a - [0, 0, G]).max() < 5 * sigma_a / math.sqrt(n) + 0.0012  # + LSB/2
    assert np.abs(m["gyro"].mean(axis=0)).max() < 5 * sigma_g / math.sqrt(n) + 3e-5
    assert np.linalg.norm(m["accel"], axis=1).mean() == pytest.approx(G, abs=0.01)
    assert m["accel"].std(axis=0) == pytest.approx([sigma_a] * 3, rel=0.1)
    assert m["gyro"].std(axis=0) == pytest.approx([sigma_g] * 3, rel=0.1)


def test_tumble_follows_truth_sample_by_sample() -> None:
    rig = make_rig(
        {"odr_hz": 500, "dlpf_hz": 98, "gyro_range_dps": 250, "accel_range_g": 2},
        _ideal(seed=7, motion={"kind": "tumble", "rate_dps": [20.0, 35.0, 10.0]}),
    )
    rig.run(6.0, jitter_ns=100_000)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    i = match_truth(m, t)
    da = m["accel"] - t["accel"][i]
    dg = m["gyro"] - t["gyro"][i]
    sigma_a = 400e-6 * G * math.sqrt(500.0)
    sigma_g = math.radians(0.005) * math.sqrt(500.0)
    assert np.abs(da.mean(axis=0)).max() < 0.01 and da.std() < 1.2 * sigma_a
    assert np.abs(dg.mean(axis=0)).max() < 1e-3 and dg.std() < 1.2 * sigma_g
    assert np.degrees(m["gyro"].mean(axis=0)) == pytest.approx([20, 35, 10], abs=0.05)


def test_fifo_overflow_is_recovered_and_every_lost_sample_counted() -> None:
    rig = make_rig({"odr_hz": 1000}, _ideal(seed=8, clock_error=0.007))
    rig.run(3.0, jitter_ns=100_000)
    for _ in range(3):
        rig.clock.advance(250_000_000)  # a stalled bus: 250 samples arrive, the FIFO holds 85
        rig.run(2.0, jitter_ns=100_000)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    assert rig.driver.counters.fifo_overflows == 3
    assert rig.runner.state == "running"
    i = match_truth(m, t)
    # exact accounting: seq and truth index differ by one constant across every gap
    assert len(np.unique(t["seq"][i] - m["seq"])) == 1
    gaps = np.diff(m["seq"]) - 1
    assert rig.runner.lost_samples == gaps.sum() > 3 * 160
    produced = t["seq"][i[-1]] - t["seq"][i[0]] + 1
    assert produced == len(m["seq"]) + rig.runner.lost_samples
    flagged = [b for b in rig.batches() if b.lost_before]
    assert len(flagged) == 3 and all(b.flags & 2 for b in flagged)


def test_nak_faults_are_counted_and_samples_still_accounted() -> None:
    rig = make_rig({"odr_hz": 1000}, _ideal(seed=9, clock_error=-0.004))
    rig.run(0.5)
    assert rig.runner.state == "running"
    faults = rig.bus.faults(0x68)
    assert faults is not None
    faults.nak_rate = 0.01  # from now on, while streaming
    rig.run(8.0, jitter_ns=100_000)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    assert rig.runner.bus_errors > 10
    assert rig.runner.state == "running"
    # a NAK comes before the chip sends a byte: the FIFO is left as it was, never reset, and
    # the next poll reads what it holds (tests/test_nak_no_loss.py)
    assert rig.driver.counters.fifo_resets == 1  # the start's only
    i = match_truth(m, t)
    offsets = t["seq"][i] - m["seq"]
    assert offsets.max() == offsets.min()  # every published sample is the next truth sample
    assert rig.runner.lost_samples == (np.diff(m["seq"]) - 1).sum() == 0


def test_register_glitch_triggers_reinit_with_right_scale_after() -> None:
    rig = make_rig({"odr_hz": 1000, "gyro_range_dps": 500}, _ideal(seed=10))
    rig.run(2.0)
    rig.sim.regs[reg.ACCEL_CONFIG] = 0x18  # a glitch flips the chip to +-16 g behind our back
    rig.run(3.0)
    assert rig.driver.counters.bad_registers >= 1 and rig.runner.restarts >= 1
    assert rig.sim.regs[reg.ACCEL_CONFIG] == 0x08  # reconfigured
    late = concat(rig.batches()[-20:])
    assert late["accel"][:, 2].mean() == pytest.approx(G, abs=0.02)
    m = concat(rig.batches())
    assert np.all(np.diff(m["seq"]) >= 1) and np.all(np.diff(m["t_ns"]) > 0)


def test_chip_power_loss_is_detected_and_gap_counted() -> None:
    rig = make_rig({"odr_hz": 1000}, _ideal(seed=11))
    rig.run(2.0)
    before = rig.runner.samples
    rig.sim._power_on_reset()  # brown-out: registers back to defaults, chip asleep
    rig.run(4.0)
    assert rig.runner.restarts >= 1 and rig.runner.state == "running"
    assert rig.runner.samples > before + 2000
    m = concat(rig.batches())
    gap = int((np.diff(m["seq"]) - 1).max())
    # the outage (register check + reset) costs between 0.1 s and 1.2 s of samples
    assert 100 <= gap <= 1200 and rig.runner.lost_samples >= gap


def test_gyro_saturates_at_full_scale() -> None:
    rig = make_rig(
        {"odr_hz": 200, "dlpf_hz": 42, "gyro_range_dps": 250},
        _ideal(seed=12, motion={"kind": "tumble", "rate_dps": [0.0, 0.0, 400.0]}),
    )
    rig.run(1.0)
    m = concat(rig.batches())
    assert m["gyro"][:, 2].max() == pytest.approx(math.radians(250) * 32767 / 32768, rel=1e-6)
    # every sample's z rate (400 deg/s) is past the range: each one says so; the accel is not
    flags = m["flags"].astype(np.int64)
    assert np.all(flags & SampleFlag.GYRO_SATURATED)
    assert not np.any(flags & SampleFlag.ACCEL_SATURATED)
    assert not np.any(flags & 0xFFFF)  # saturated is not invalid: the values are published


def test_temperature_ramp_is_reported() -> None:
    rig = make_rig({"odr_hz": 100, "dlpf_hz": 42}, _ideal(seed=13, temperature_ramp_c_per_min=30))
    rig.run(10.0)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    i = match_truth(m, t)
    # one register read per batch: stale by at most a poll interval (0.2 s -> 0.1 C at 30 C/min)
    assert np.abs(m["temp"] - t["temp"][i]).max() < 0.11
    assert m["temp"][-1] - m["temp"][0] == pytest.approx(5.0, abs=0.2)


def test_same_seed_same_bytes() -> None:
    a = make_rig({"odr_hz": 500, "dlpf_hz": 98}, {"seed": 21})
    b = make_rig({"odr_hz": 500, "dlpf_hz": 98}, {"seed": 21})
    a.run(2.0)
    b.run(2.0)
    assert a.out == b.out and len(a.out) > 30


def test_default_error_model_draws_realistic_errors() -> None:
    rig = make_rig({"odr_hz": 1000}, {"seed": 14})
    rig.run(3.0)
    m = concat(rig.batches())
    assert abs(rig.sim.clock_error) <= 0.02  # default oscillator error within +-2 %
    bias = np.degrees(m["gyro"].mean(axis=0))
    assert 0.01 < np.abs(bias).max() < 5.0  # a turn-on gyro bias exists, of MPU6050 size
    assert abs(np.linalg.norm(m["accel"].mean(axis=0)) - G) < 0.5


def test_absent_chip_reports_error_and_keeps_retrying() -> None:
    rig = make_rig({"odr_hz": 1000}, _ideal())
    rig.bus._devices.clear()  # nothing answers at 0x68
    rig.run(5.0)
    assert rig.runner.state == "error"
    assert rig.runner.last_error is not None and "0x68" in rig.runner.last_error
    assert rig.bus.transfers >= 4  # it retried with backoff rather than giving up


def test_sustained_overflow_counts_losses_as_they_happen(caplog: pytest.LogCaptureFixture) -> None:
    rig = make_rig({"odr_hz": 1000}, _ideal(seed=15, clock_error=0.005))
    rig.run(10.0)  # long enough for the chip-clock fit to extrapolate 3 s blind to < 1 sample
    delivered_before = rig.runner.samples
    rig.driver.poll_interval_ns = 100_000_000  # longer than the FIFO lasts (85 samples)
    with caplog.at_level("WARNING", logger="imud.device"):
        rig.run(3.0)
    assert rig.driver.counters.fifo_overflows >= 25
    # nothing got through but the poll already scheduled at the old interval...
    assert rig.runner.samples - delivered_before <= 30
    # ...and yet every sample the chip produced meanwhile is already counted as lost
    assert rig.runner.lost_samples == pytest.approx(3.0 * 1005, abs=120)
    assert any("samples lost" in r.getMessage() for r in caplog.records)
    rig.driver.poll_interval_ns = 20_000_000
    rig.run(2.0)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    i = match_truth(m, t)
    assert len(np.unique(t["seq"][i] - m["seq"])) == 1  # the books still balance exactly
    assert rig.runner.lost_samples == (np.diff(m["seq"]) - 1).sum()
    late = rig.batches()[-100:]
    assert sum(b.lost_before for b in rig.batches()) == rig.runner.lost_samples
    assert late
