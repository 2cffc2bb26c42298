"""ADIS16465 driver + simulator at virtual time: the 16-bit frame protocol, reset and identity,
a constant rotation read right (rate and integrated delta angle, the oscillator error taken
out), noise, DATA_CNTR gaps and bad checksums counted exactly, DIAG_STAT alarms, delta races,
and the register re-check."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from imud.channels import Channel, SampleFlag
from imud.chips.adis16465.driver import Adis16465Driver
from imud.chips.adis16465.registers import Register as Reg
from imud.chips.adis16465.sim import BLOCK_STAGES, Adis16465Sim
from imud.chips.api import start_blocking
from imud.clock import VirtualClock
from imud.config import parse_config
from imud.device import DeviceRunner
from imud.errors import DeviceIdentityError
from imud.sim.settings import SimSettings
from imud.sim.spiframe import SimSpiFrames
from imud.wiring import connect
from tests.helpers import Rig, make_rig, match_truth

G = 9.80665
SPI = {"kind": "sim", "transport": "spi", "speed_hz": 2_000_000}
TUMBLE_Z = {"kind": "tumble", "rate_dps": [0.0, 0.0, 100.0]}
QUIET = {"ideal": True, "gyro_noise_dps_rthz": 0.0, "accel_noise_ug_rthz": 0.0}


def _rig(sim: dict[str, Any] | None = None, **device: Any) -> Rig:
    return make_rig({"chip": "adis16465", "model": 2, "bus": SPI, **device},
                    {"errors": {"ideal": True}, **(sim or {})})  # fmt: skip


def _cat(rig: Rig, truth: bool = False) -> dict[str, np.ndarray]:
    bs = rig.truth_batches() if truth else rig.batches()
    out = {"seq": np.concatenate([b.seq for b in bs]), "t_ns": np.concatenate([b.t_ns for b in bs])}
    out["flags"] = np.concatenate([b.sample_flags for b in bs])
    for c in (Channel.ACCEL, Channel.GYRO, Channel.TEMPERATURE, Channel.DELTA_ANGLE,
              Channel.DELTA_VELOCITY):  # fmt: skip
        if c in bs[0].channels:
            out[c.name] = np.concatenate([b.channels[c] for b in bs]).astype(np.float64)
    return out


def _word(sim: Adis16465Sim, cmd: int, hz: int = 1_000_000) -> int:
    rx = sim.spi_frame(cmd.to_bytes(2, "big"), hz)
    return int.from_bytes(rx, "big")


# --- the frame protocol --------------------------------------------------------------------------
def test_reads_answer_in_the_next_frame_and_writes_go_byte_by_byte() -> None:
    sim = Adis16465Sim(SimSettings(), VirtualClock(), model=2)
    assert _word(sim, 0x7200) == 0x0000  # nothing pending yet
    assert _word(sim, 0x5E00) == 0x4051  # PROD_ID (0x72) = 16465
    assert _word(sim, 0x6000) == 0x0007  # RANG_MDL: [3:2] = 01 (-2), [1:0] = 11
    assert _word(sim, 0x0000) == 0x00C1  # MSC_CTRL default
    # the datasheet's example: FILT_CTRL = 4 is DIN 0xDC04, 0xDD00
    _word(sim, 0xDC04)
    _word(sim, 0xDD00)
    _word(sim, 0x5C00)
    assert _word(sim, 0x0000) == 0x0004


def test_software_reset_silences_the_port_for_its_198_ms() -> None:
    clock = VirtualClock()
    sim = Adis16465Sim(SimSettings(), clock, model=3)
    _word(sim, 0xE880)  # GLOB_CMD bit 7, low byte first
    _word(sim, 0xE900)
    clock.advance(190_000_000)
    _word(sim, 0x7200)
    assert _word(sim, 0x7200) == 0  # still resetting: no answer
    clock.advance(9_000_000)
    _word(sim, 0x7200)
    assert _word(sim, 0x7200) == 0x4051


def test_a_frame_not_of_16_bit_words_sets_the_spi_error_flag_until_read() -> None:
    sim = Adis16465Sim(SimSettings(), VirtualClock(), model=3)
    sim.spi_frame(b"\x72\x00\x00", 1_000_000)
    _word(sim, 0x0200)
    assert _word(sim, 0x0200) == 0x0008  # DIAG_STAT bit 3, and the read clears it
    assert _word(sim, 0x0000) == 0x0000


def test_a_burst_above_1_mhz_comes_out_with_a_bad_checksum() -> None:
    sim = Adis16465Sim(SimSettings(), VirtualClock(), model=3)
    tx = bytes([0x68, 0x00] + [0] * 20)
    good = sim.spi_frame(tx, 1_000_000)[2:]
    assert sum(good[:18]) & 0xFFFF == int.from_bytes(good[18:], "big")
    for _ in range(20):
        fast = sim.spi_frame(tx, 2_000_000)[2:]
        assert sum(fast[:18]) & 0xFFFF != int.from_bytes(fast[18:], "big")


# --- start: identity, reset, model ---------------------------------------------------------------
def _started(sim_model: int, cfg_model: int, pid: int | None = None) -> Adis16465Driver:
    cfg: Any = parse_config(
        {"device": [{"name": "a", "chip": "adis16465", "model": cfg_model, "bus": SPI}]}
    ).device[0]
    clock = VirtualClock()
    sim = Adis16465Sim(SimSettings(), clock, model=sim_model)
    if pid is not None:
        sim.words[Reg.PROD_ID >> 1] = pid
    drv = Adis16465Driver(cfg, SimSpiFrames(sim), clock)
    start_blocking(drv, clock)
    return drv


def test_start_resets_and_configures() -> None:
    drv = _started(3, 3)
    assert drv.counters.soft_resets == 1
    assert drv.read_words([Reg.DEC_RATE, Reg.FILT_CTRL]) == [1, 0]


def test_a_model_mismatch_names_both() -> None:
    with pytest.raises(DeviceIdentityError) as e:
        _started(1, 3)
    msg = str(e.value)
    assert "RANG_MDL (0x5e) reads 0x0003" in msg
    assert "ADIS16465-1 (+-125 deg/s)" in msg and "ADIS16465-3 (+-2000 deg/s)" in msg
    assert "set model = 1" in msg


def test_a_family_member_is_named() -> None:
    with pytest.raises(DeviceIdentityError, match=r"0x4056 \(16470\): an ADIS16470"):
        _started(3, 3, pid=0x4056)
    with pytest.raises(DeviceIdentityError, match="expected 0x4051"):
        _started(3, 3, pid=0x1234)


# --- streaming -----------------------------------------------------------------------------------
def test_constant_rotation_reads_right_rate_and_integrated_angle() -> None:
    """100 deg/s about z on a chip 2.5 % fast, at 1000 Hz (dec_rate 1): the gyro reads 1.745
    rad/s; each delta angle is the true rotation over its (shorter) interval, so the deltas sum
    to the angle turned, and the delta velocity to gravity over the time that passed."""
    rig = _rig({"seed": 5, "clock_error": 0.025, "motion": TUMBLE_Z, "errors": QUIET})
    rig.run(2.0)
    m, t = _cat(rig), _cat(rig, truth=True)
    assert rig.runner.state == "running" and rig.runner.lost_samples == 0
    assert np.all(np.diff(m["seq"]) == 1)
    true_rate = 1000 * 1.025
    assert rig.runner.status().chip_rate_hz == pytest.approx(true_rate, rel=2e-4)
    st = rig.driver.chip_status()
    assert st["odr_estimate_hz"] == pytest.approx(true_rate, rel=2e-4)
    assert st["clock_error_pct"] == pytest.approx(2.5, abs=0.02)
    w = math.radians(100.0)
    # the 16-bit word with its low word's midpoint (no room for the low words at 1 kHz with
    # deltas): within half a 16-bit code (1/80 deg/s)
    np.testing.assert_allclose(m["GYRO"][:, 2], w, atol=math.radians(0.5 / 40) * 1.001)
    # each delta: the rotation over 2 internal samples at 2050 Hz, 100 deg/s * 2/2050 s
    settled = m["t_ns"] > m["t_ns"][0] + 0.5e9  # the rate estimate has its baseline
    da = m["DELTA_ANGLE"][settled]
    assert np.all(np.isfinite(da))
    assert da[:, 2].mean() == pytest.approx(w * 2 / 2050, rel=1e-4)
    assert da[:, 2].sum() == pytest.approx(w * da.shape[0] / true_rate, rel=1e-4)
    assert np.abs(da[:, :2]).max() < 1e-5
    dv = m["DELTA_VELOCITY"][settled]
    assert dv[:, 2].mean() == pytest.approx(G * 2 / 2050, rel=1e-4)  # gravity's pull on z
    # sample by sample against the truth (same instants, same intervals)
    i = match_truth({"t_ns": m["t_ns"]}, {"t_ns": t["t_ns"]})
    assert np.abs(m["t_ns"] - t["t_ns"][i])[settled].max() < 0.3e6
    np.testing.assert_allclose(da, t["DELTA_ANGLE"][i][settled], atol=2e-7, rtol=2e-4)
    np.testing.assert_allclose(dv, t["DELTA_VELOCITY"][i][settled], atol=2e-6, rtol=2e-4)
    assert st["delta_races"] == 0 and st["diag_stat"] == "0x0000"


def test_deltas_before_the_rate_is_known_are_nominal_and_after_corrected() -> None:
    rig = _rig({"seed": 6, "clock_error": -0.03, "motion": TUMBLE_Z}, dec_rate=3)
    rig.run(2.0)
    m = _cat(rig)
    first = m["DELTA_ANGLE"][:50, 2]  # no baseline yet: the chip's own (nominal) scaling
    assert first.mean() == pytest.approx(math.radians(100.0) * 4 / 2000, rel=1e-3)
    last = m["DELTA_ANGLE"][-200:, 2]  # 4 internal samples at 1940 Hz each
    assert last.mean() == pytest.approx(math.radians(100.0) * 4 / 1940, rel=1e-4)


@pytest.mark.parametrize(("dec_rate", "deltas"), [(0, False), (3, True), (19, True)])
def test_each_rate_streams_continuously(dec_rate: int, deltas: bool) -> None:
    rig = _rig({"seed": 7, "clock_error": 0.012}, dec_rate=dec_rate, deltas=deltas, model=1)
    rig.run(2.0, jitter_ns=5_000)
    m = _cat(rig)
    odr = 2000 / (dec_rate + 1)
    assert rig.runner.lost_samples == 0 and np.all(np.diff(m["seq"]) == 1)
    assert len(m["seq"]) == pytest.approx(odr * 1.012 * (2.0 - 0.2), abs=odr * 0.02 + 2)
    assert ("DELTA_ANGLE" in m) == deltas
    assert m["ACCEL"][:, 2].mean() == pytest.approx(G, abs=2e-3)
    assert m["TEMPERATURE"].mean() == pytest.approx(25.0, abs=0.06)


def test_noise_matches_the_datasheet_output_noise() -> None:
    """Without filtering (dec_rate 0, FILT_CTRL 0) the noise is the datasheet's output noise
    (DS Table 1: 0.07 deg/s rms on the -1, 0.6 mg rms); tests/test_sim_noise.py checks the
    density and Allan N."""
    rig = _rig({"seed": 8}, model=1, dec_rate=0, deltas=False)
    rig.run(2.5)
    m = _cat(rig)
    assert m["GYRO"].std(axis=0) == pytest.approx([math.radians(0.07)] * 3, rel=0.08)
    assert m["ACCEL"].std(axis=0) == pytest.approx([0.6e-3 * G] * 3, rel=0.08)


def test_model_scales_and_16_bit_quantisation() -> None:
    """No noise: 100 deg/s is 16000 / 4000 / 1000 counts on -1 / -2 / -3, exact."""
    for model, counts in ((1, 16000), (2, 4000), (3, 1000)):
        rig = _rig({"motion": TUMBLE_Z, "errors": QUIET}, model=model, dec_rate=0, deltas=False)
        rig.run(0.4)
        gz = _cat(rig)["GYRO"][:, 2]
        lsb = {1: 160, 2: 40, 3: 10}[model]
        np.testing.assert_allclose(gz, math.radians(counts / lsb), rtol=1e-7)  # float32


def test_saturation_flags_the_sample() -> None:
    rig = _rig({"motion": {"kind": "tumble", "rate_dps": [0.0, 0.0, 300.0]}}, model=1)
    rig.run(0.4)
    m = _cat(rig)
    assert np.all(m["flags"] & SampleFlag.GYRO_SATURATED)
    top = m["GYRO"][:, 2].max()  # the 16-bit word at 32767, the low word below it
    assert math.radians(32767 / 160) * (1 - 1e-7) <= top < math.radians(32768 / 160)


def test_a_stall_loses_samples_counted_exactly_from_data_cntr() -> None:
    rig = _rig({"seed": 9, "clock_error": 0.01})
    rig.run(1.0)
    before = rig.sim.count
    rig.clock.advance(int(7.5e6))  # the worker did not run for 7.5 ms: 7 or 8 samples
    rig.runner.step()
    after = rig.sim.count
    rig.run(0.5)
    m = _cat(rig)
    lost = (after - before) % 65536 - 1
    assert lost >= 6
    assert rig.runner.lost_samples == lost == rig.driver.chip_status()["samples_skipped"]
    gaps = np.diff(m["seq"]) - 1
    assert gaps.sum() == lost and np.count_nonzero(gaps) == 1
    # and the published sequence matches the chip's counter one for one
    assert len(m["seq"]) + lost == m["seq"][-1] - m["seq"][0] + 1


def test_bad_checksums_are_counted_and_the_gap_they_leave_too() -> None:
    rig = _rig({"seed": 10})
    rig.run(0.5)
    published = len(_cat(rig)["seq"])
    rig.driver.burst_hz = 2_000_000  # above the burst's 1 MHz: every frame arrives garbled
    for _ in range(5):
        rig.runner.step()
        rig.clock.advance(400_000)
    assert rig.runner.bus_errors == 5 == rig.driver.counters.bad_transfers
    assert rig.driver.counters.chip["checksum_errors"] == 5
    st = rig.runner.status()  # by kind in status: all five caught by the checksum
    assert st.garbled_transfers == st.chip_counters["checksum_errors"] == 5
    assert len(_cat(rig)["seq"]) == published  # nothing from a bad frame was published
    rig.driver.burst_hz = 1_000_000
    rig.run(0.5)
    m = _cat(rig)
    gaps = np.diff(m["seq"]) - 1
    assert gaps.sum() == rig.runner.lost_samples == rig.driver.chip_status()["samples_skipped"]
    assert rig.runner.lost_samples >= 1


def test_diag_stat_flags_are_kept_and_mark_a_sample() -> None:
    rig = _rig({"seed": 11})
    rig.run(0.5)
    rig.sim.spi_frame(b"\x00\x00\x00", 1_000_000)  # 24 SCLKs: not a multiple of 16
    rig.run(0.2)
    m = _cat(rig)
    alarmed = np.count_nonzero(m["flags"] & SampleFlag.CHIP_ALARM)
    st = rig.driver.chip_status()
    assert alarmed == 1
    assert st["diag_stat"] == "0x0008" and st["diag_stat_counts"] == {"spi_communication_error": 1}


def test_deltas_at_dec_rate_0_overrun_the_datapath() -> None:
    """Why the config refuses deltas at 2000 Hz: 14 register reads per 12 allowed."""
    rig = _rig({"seed": 12}, dec_rate=0, deltas=False)
    cfg = rig.cfg.model_copy(update={"deltas": True})  # past the config's check
    driver, sim = connect(cfg, None, rig.clock)
    rig.runner = DeviceRunner(cfg, driver, None, rig.out.append, 0, now_ns=rig.clock.now_ns)
    rig.driver, rig.sim = driver, sim
    rig.run(0.5)
    st = rig.driver.chip_status()
    assert st["diag_stat_counts"].get("datapath_overrun", 0) > 100


class SlowFrames(SimSpiFrames):
    """Each frame takes `ns` of virtual time, as on a real bus (and a host between frames)."""

    def __init__(self, sim: Adis16465Sim, clock: VirtualClock, ns: int) -> None:
        super().__init__(sim)
        self.clock, self.ns = clock, ns

    def xfer2(self, values: list[int], speed_hz: int = 0, delay_usecs: int = 0,
              bits_per_word: int = 0) -> list[int]:  # fmt: skip
        self.clock.advance(self.ns)
        return super().xfer2(values, speed_hz, delay_usecs, bits_per_word)


def test_a_sample_landing_during_the_delta_reads_publishes_invalid_deltas() -> None:
    rig = _rig({"seed": 13, "motion": TUMBLE_Z}, dec_rate=1)
    clock, cfg = rig.clock, rig.cfg
    s = SimSettings.model_validate({"seed": 13, "motion": TUMBLE_Z, "errors": QUIET})
    sim = Adis16465Sim(s, clock, model=2)
    drv = Adis16465Driver(cfg, SlowFrames(sim, clock, 60_000), clock)  # 15 frames: 0.9 ms
    out: list[bytes] = []
    rig.runner = DeviceRunner(cfg, drv, None, out.append, 0, sim=sim, now_ns=clock.now_ns)
    rig.out, rig.driver, rig.sim = out, drv, sim
    rig.run(2.0)
    m = _cat(rig)
    bad = (m["flags"] & SampleFlag.DELTA_ANGLE_INVALID) != 0
    assert np.all(((m["flags"] & SampleFlag.DELTA_VELOCITY_INVALID) != 0) == bad)
    races = drv.chip_status()["delta_races"]
    # polls locked on the sample clock start the reads right after a sample lands, so only the
    # reads the sweep starts late overrun the next one: a few a second
    assert races > 5 and np.count_nonzero(bad) == races
    assert np.all(np.isnan(m["DELTA_ANGLE"][bad])) and np.all(np.isfinite(m["GYRO"][bad]))
    # every delta that is published is whole: the rotation of one sample interval
    good = m["DELTA_ANGLE"][~bad][200:, 2]
    np.testing.assert_allclose(good, math.radians(100) * 2 / 2000, rtol=5e-4)


def test_a_changed_register_is_found_and_the_chip_reinitialised() -> None:
    rig = _rig({"seed": 14})
    rig.run(0.5)
    rig.sim.words[Reg.DEC_RATE >> 1] = 9  # a glitch: the chip now runs at 200 Hz
    rig.run(1.0)
    assert rig.runner.restarts == 1 and rig.driver.counters.bad_registers == 1
    assert rig.driver.counters.soft_resets == 2
    assert rig.sim.words[Reg.DEC_RATE >> 1] == 1 and rig.runner.state == "running"
    m = _cat(rig)
    gaps = np.diff(m["seq"]) - 1
    assert np.all(gaps >= 0) and gaps.sum() == rig.runner.lost_samples > 0


def test_truth_has_one_sample_per_output_sample() -> None:
    rig = _rig({"seed": 15, "clock_error": 0.02, "motion": TUMBLE_Z}, dec_rate=3)
    rig.run(1.0)
    t = _cat(rig, truth=True)
    assert np.all(np.diff(t["seq"]) == 1)
    t = {k: v[-300:] for k, v in t.items()}  # at the configured DEC_RATE (after the reset)
    assert np.diff(t["t_ns"]).mean() == pytest.approx(4 / 2040 * 1e9, rel=1e-6)
    np.testing.assert_allclose(t["DELTA_ANGLE"][:, 2], math.radians(100) * 4 / 2040, rtol=1e-7)
    np.testing.assert_allclose(t["GYRO"][:, 2], math.radians(100), rtol=1e-7)


@pytest.mark.parametrize("clock_error", [-0.03, 0.0, 0.03])
def test_polls_lock_on_the_sample_clock_about_once_a_sample(clock_error: float) -> None:
    """Without a FIFO every sample must be read before the next replaces it. Once the chip's
    rate is measured the polls are aimed just after each expected sample, so a poll mostly
    finds exactly one new sample: at most 1.6 polls a sample (the fallback interval, polls
    spread so that none is more than ~half a period apart, made about 4 at 2 kHz), and none
    lost, with the chip's oscillator at either end of its +-3 % and polls up to 50 us late."""
    rig = _rig({"seed": 21, "clock_error": clock_error}, model=1, dec_rate=0, deltas=False)
    rig.run(1.0, jitter_ns=50_000)  # the rate estimate takes 400 samples: locked by now
    assert rig.driver.next_poll_ns is not None
    samples, duplicates = rig.runner.samples, rig.driver.duplicates
    rig.run(2.0, jitter_ns=50_000, seed=1)
    new = rig.runner.samples - samples
    polls = new + rig.driver.duplicates - duplicates
    assert new == pytest.approx(2.0 * 2000 * (1 + clock_error), rel=0.01)
    assert polls / new <= 1.6
    assert rig.runner.lost_samples == 0


@pytest.mark.parametrize(("dec_rate", "deltas"), [(0, False), (1, True)])
def test_the_simulators_own_work_does_not_cost_the_driver_a_sample(
    dec_rate: int, deltas: bool
) -> None:
    """The simulator makes its outputs ahead, a block of 64 ms at a time, and that work takes
    host time that silicon does not: 0.5-0.6 ms a block in a bus worker, more than a period at
    2 kHz. Made inside the DATA_CNTR poll that begins a sample's read, it delayed the burst after
    it past the next latch and the polled sample was lost (one a block: 0.8 % at 2 kHz); made
    between a burst and its delta words, it let the next sample overtake them; made whole after
    a sample's reads, it left the next poll late by its length (a sample a second lost). Here a
    block costs 1.2 ms of the virtual clock in all, more than two periods: made in parts, one
    at the end of each sample's reads, no sample may be lost, no delta overtaken."""
    rig = _rig({"seed": 21, "clock_error": 0.02}, model=1, dec_rate=dec_rate, deltas=deltas)
    sim = rig.sim
    cost = 1_200_000
    stages, whole = sim._block_stages, sim._make_block

    def costly_stages() -> Any:
        parts = stages()
        while True:
            rig.clock.advance(cost // BLOCK_STAGES)
            try:
                next(parts)
            except StopIteration as done:
                return done.value
            yield

    def costly_whole() -> Any:
        rig.clock.advance(cost)
        return whole()

    sim._block_stages = costly_stages  # type: ignore[method-assign]
    sim._make_block = costly_whole  # type: ignore[method-assign]
    rig.run(1.0, jitter_ns=20_000)
    assert rig.driver.next_poll_ns is not None  # locked on the sample clock
    lost, overtaken = rig.runner.lost_samples, rig.driver.overtaken
    rig.run(2.0, jitter_ns=20_000, seed=1)
    assert rig.runner.samples > 0.97 * 2.0 * 2000 / (dec_rate + 1)
    assert rig.runner.lost_samples == lost
    assert rig.driver.overtaken == overtaken


@pytest.mark.parametrize(("dec_rate", "deltas", "filt"), [(0, False, 0), (1, True, 3)])
def test_a_block_made_in_parts_is_the_block_made_whole(
    dec_rate: int, deltas: bool, filt: int
) -> None:
    """Spreading a block's making over reads changes when the work is done, not what it makes:
    the noise is drawn in the same order, so the published samples are the same bytes as with
    every block made whole."""
    noisy = {"seed": 5, "clock_error": 0.01, "errors": {"ideal": False}}
    runs = []
    for parts in (True, False):
        rig = _rig(noisy, model=1, dec_rate=dec_rate, deltas=deltas, filt_ctrl=filt)
        if not parts:
            sim = rig.sim

            def whole(sim: Any = sim) -> None:
                if sim._ahead is None and sim.sampling and len(sim._block.k) - sim._oi <= 8:
                    sim._ahead = sim._make_block()

            sim._make_ahead = whole  # type: ignore[method-assign]
        rig.run(1.0)
        runs.append(_cat(rig))
    parted, whole_ = runs
    assert parted.keys() == whole_.keys()
    for key in parted:
        np.testing.assert_array_equal(parted[key], whole_[key], err_msg=key)
