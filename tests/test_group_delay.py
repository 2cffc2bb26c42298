"""The chips' configured low-pass filters delay every sample by their documented group delay
(docs/timestamps.md), the simulators model it, and the pipeline moves every stamp back by it:

- measured on the simulator's output from a known motion (a sinusoidal rate: the published
  gyro against the true rate, as amplitude and phase at the motion's frequency), the delay is
  the datasheet's;
- through driver and pipeline, published stamps match the truth (the instant the motion
  happened) and the published gyro shows no delay left against the true rate at its stamps."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from imud.channels import Channel
from imud.chips.adis16465.driver import Adis16465Driver
from imud.chips.adis16465.registers import Register as AdisReg
from imud.chips.adis16465.sim import Adis16465Sim
from imud.chips.api import FifoRead, RawBatch, RawChannel
from imud.chips.mpu6050.driver import group_delay_s
from imud.chips.mpu6050.registers import DLPF_BANDWIDTHS_HZ
from imud.chips.mpu6050.registers import Register as R
from imud.chips.mpu6050.sim import Mpu6050Sim
from imud.chips.stim300.driver import GYRO_GROUP_DELAY_S as STIM300_GYRO_DELAY_S
from imud.chips.stim300.sim import Stim300Sim
from imud.clock import VirtualClock
from imud.config import parse_config
from imud.pipeline import Pipeline
from imud.sim.settings import SimSettings
from imud.timestamps import SampleClock
from imud.wire import decode
from tests.helpers import concat, make_rig, match_truth
from tests.test_stim300_sim import rig as stim_rig
from tests.test_stim300_sim import run as stim_run

ADIS_SPI = {"kind": "sim", "transport": "spi", "speed_hz": 2_000_000}

F0 = 2.0  # Hz, the rate's frequency
AMP = math.radians(100.0)
PHASE = np.array([0.0, 1.0, 2.0])


class SineRate:
    """A rate of AMP sin(2 pi F0 t + phase) per axis; gravity along z (a test motion, not a
    consistent rigid-body one: only the gyro is looked at)."""

    def sample(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = AMP * np.sin(2 * math.pi * F0 * t_s[:, None] + PHASE)
        return np.broadcast_to([0.0, 0.0, 9.80665], w.shape).copy(), w


def delay_of(t_s: np.ndarray, gyro: np.ndarray) -> float:
    """The delay (s) of `gyro` behind the true rate at times t_s: least squares on sin and cos
    at F0, the phase lag over 2 pi F0 (exact for any gain at F0)."""
    om = 2 * math.pi * F0
    lags = []
    for a in range(3):
        ph = om * t_s + PHASE[a]
        basis = np.stack([np.sin(ph), np.cos(ph)], axis=1)
        (c, s), *_ = np.linalg.lstsq(basis, gyro[:, a], rcond=None)
        lags.append(math.atan2(-s, c) / om)  # g sin(ph - om d) = g cos(om d) sin - g sin(om d) cos
    return float(np.mean(lags))


# RM-MPU-6000A-00 rev 4.2 §4.3 (register 26): gyro delay per DLPF_CFG, and a rate it allows
MPU6050_GYRO = [(0, 0.98e-3, 0), (1, 1.9e-3, 0), (2, 2.8e-3, 1), (3, 4.8e-3, 4),
                (4, 8.3e-3, 9), (5, 13.4e-3, 19), (6, 18.6e-3, 0)]  # fmt: skip


@pytest.mark.parametrize(("dlpf_cfg", "delay_s", "div"), MPU6050_GYRO)
def test_mpu6050_simulated_gyro_is_delayed_by_the_dlpf_table(
    dlpf_cfg: int, delay_s: float, div: int
) -> None:
    clock = VirtualClock()
    sim = Mpu6050Sim(SimSettings(seed=3, errors={"ideal": True, "gyro_noise_dps_rthz": 0.0}),
                     clock)  # fmt: skip
    sim.motion = SineRate()  # type: ignore[assignment]
    out: list[tuple[np.ndarray, np.ndarray]] = []
    sim._reveal = lambda m, i, j: out.append((m.t_ns[i:j], m.gyro[i:j]))  # type: ignore[method-assign]
    sim.write(R.PWR_MGMT_1, bytes([0x01]))
    sim.write(R.SMPLRT_DIV, bytes([div]))
    sim.write(R.CONFIG, bytes([dlpf_cfg]))
    out.clear()
    clock.advance(2_000_000_000)
    sim.advance()
    t_ns = np.concatenate([o[0] for o in out])
    wm = np.concatenate([o[1] for o in out])
    d = delay_of((t_ns - sim.t_origin_ns) / 1e9, wm)
    assert d == pytest.approx(delay_s, abs=1e-6)
    # and the driver declares that delay for the same setting
    assert group_delay_s(DLPF_BANDWIDTHS_HZ[dlpf_cfg]) == delay_s


def test_mpu6050_stamps_mean_the_instant_of_the_motion() -> None:
    """DLPF 98 Hz (2.8 ms, 1.4 periods at 500 Hz) on a chip clock 1.1 % fast: the filter's delay
    is 2.8 ms of the chip's own clock, and the pipeline scales it to the fitted period."""
    rig = make_rig(
        {"odr_hz": 500, "dlpf_hz": 98, "gyro_range_dps": 250},
        {"errors": {"ideal": True, "gyro_noise_dps_rthz": 0.0}, "clock_error": 0.011, "seed": 12},
    )
    rig.sim.motion = SineRate()
    rig.run(8.0, jitter_ns=100_000)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    assert np.all(np.diff(m["t_ns"]) > 0) and m["t_ns"].dtype == np.int64
    settled = m["t_ns"] > m["t_ns"][0] + 3e9
    i = match_truth(m, t)
    err = (m["t_ns"] - t["t_ns"][i])[settled]
    period = 1e9 / (500 * 1.011)
    assert abs(err.mean()) < 0.05 * period  # the stamp is the truth's instant, not the latch's
    assert len(np.unique(t["seq"][i] - m["seq"])) == 1
    # the published gyro against the true rate at its own stamps: no delay left
    t_s = (m["t_ns"][settled] - rig.sim.t_origin_ns) / 1e9
    assert abs(delay_of(t_s, m["gyro"][settled])) < 0.05 * period
    # and the stamps' shift is the table's 2.8 ms on the fitted chip clock
    assert rig.runner.pipeline is not None
    assert rig.runner.pipeline.delay_ns(1e9 / 505.5) == pytest.approx(2.8e6 / 1.011, abs=1e3)


# TS1524 rev.31 Table 5-3: the STIM300 gyro's group delay per filter (-3 dB, Hz)
STIM300_GYRO = [(262, 2.2e-3), (131, 3.7e-3), (66, 6.7e-3), (33, 12.7e-3), (16, 24.7e-3)]


@pytest.mark.parametrize(("filter_hz", "delay_s"), STIM300_GYRO)
def test_stim300_simulated_gyro_is_delayed_by_the_filter_table(
    filter_hz: int, delay_s: float
) -> None:
    clock = VirtualClock()
    sim = Stim300Sim(SimSettings(seed=3, errors={"ideal": True, "gyro_noise_dps_rthz": 0.0}),
                     clock, odr_hz=500, filter_hz=filter_hz)  # fmt: skip
    sim.motion = SineRate()  # type: ignore[assignment]
    out: list[tuple[np.ndarray, np.ndarray]] = []
    sim._reveal = lambda m, i, j: out.append((m.t_ns[i:j], m.gyro[i:j]))  # type: ignore[method-assign]
    clock.advance(2_000_000_000)
    sim.advance()
    t_ns = np.concatenate([o[0] for o in out])
    wm = np.concatenate([o[1] for o in out])
    assert delay_of((t_ns - sim.t_origin_ns) / 1e9, wm) == pytest.approx(delay_s, abs=1e-6)
    assert STIM300_GYRO_DELAY_S[filter_hz] == delay_s  # the driver declares the same


def test_stim300_stamps_mean_the_instant_of_the_motion() -> None:
    """33 Hz filter (12.7 ms, 25 periods at 2000/s) on a unit 0.8 % slow: through the driver's
    datagram brackets and the pipeline, the stamps are the truth's instants."""
    cfg, clock, sim, _, runner, out, truth = stim_rig(
        {"errors": {"ideal": True, "gyro_noise_dps_rthz": 0.0}, "clock_error": -0.008,
         "seed": 14}, filter_hz=33
    )  # fmt: skip
    assert cfg.filter_hz == 33
    sim.filter_hz = 33  # the rig builds the unit at its default filter: set it as configured
    sim._filter_cache = None
    sim.motion = SineRate()
    stim_run(clock, runner, 4.0)
    m = concat([decode(b) for b in out])
    t = concat([decode(b) for b in truth])
    settled = m["t_ns"] > m["t_ns"][0] + 2e9
    i = match_truth(m, t)
    period = 1e9 / (2000 * 0.992)
    err = (m["t_ns"] - t["t_ns"][i])[settled]
    # the filter's 12.7 ms (25 periods) is gone; what remains (~0.1 period) is the datagram
    # brackets' own, the same at every filter setting
    assert abs(err.mean()) < 0.2 * period
    t_s = (m["t_ns"][settled] - sim.t_origin_ns) / 1e9
    assert abs(delay_of(t_s, m["gyro"][settled])) < 0.2 * period / 1e9


# ADIS16465 Rev. B: the Bartlett window of FILT_CTRL = B (two 2^B-sample averages, 2^B - 1
# samples of delay) and the DEC_RATE average of D = DEC_RATE + 1 samples ((D - 1) / 2), at the
# internal 2000 Hz: (B, DEC_RATE, delay in s)
ADIS_DELAYS = [(0, 0, 0.0), (2, 0, 3 / 2000), (3, 1, 7.5 / 2000), (5, 3, 32.5 / 2000)]


@pytest.mark.parametrize(("filt", "dec_rate", "delay_s"), ADIS_DELAYS)
def test_adis16465_simulated_outputs_are_delayed_by_their_filters(
    filt: int, dec_rate: int, delay_s: float
) -> None:
    clock = VirtualClock()
    sim = Adis16465Sim(SimSettings(seed=3, errors={"ideal": True, "gyro_noise_dps_rthz": 0.0}),
                       clock)  # fmt: skip
    sim.motion = SineRate()  # type: ignore[assignment]
    sim.words[AdisReg.FILT_CTRL >> 1] = filt
    sim.words[AdisReg.DEC_RATE >> 1] = dec_rate
    sim._anchor(clock.now_ns())
    got: list[tuple[np.ndarray, np.ndarray]] = []
    make = sim._make_block

    def keep() -> Any:
        block = make()
        k = np.asarray(block.k, dtype=np.float64)
        t_s = (sim.grid_origin_ns + k * 1e9 / sim.rate_hz - sim.t_origin_ns) / 1e9
        words = block.rows[:, 1:6:2]  # X/Y/Z_GYRO_OUT, the 16-bit words
        got.append((t_s, words))
        return block

    sim._make_block = keep  # type: ignore[method-assign]
    clock.advance(2_000_000_000)
    sim.advance()
    t_s = np.concatenate([g[0] for g in got])
    out = np.concatenate([g[1] for g in got]).astype(np.int16).astype(np.float64)
    gyro = np.radians(out * 2000 / 20000)  # -3: 10 LSB per deg/s
    assert delay_of(t_s, gyro) == pytest.approx(delay_s, abs=5e-6)  # 16-bit words
    cfg = parse_config({"device": [{"name": "a", "chip": "adis16465", "bus": ADIS_SPI, "model": 3,
                                    "filt_ctrl": filt, "dec_rate": dec_rate,
                                    "deltas": False}]}).device[0]  # fmt: skip
    drv = Adis16465Driver(cfg, None, clock)  # type: ignore[arg-type]
    assert drv.group_delay_ns == round(delay_s * 1e9)


def test_adis16465_stamps_mean_the_instant_of_the_motion() -> None:
    """FILT_CTRL 3 and DEC_RATE 1 (3.75 ms, 7.5 samples at 1000/s) on a chip 1.5 % fast."""
    rig = make_rig(
        {"chip": "adis16465", "bus": ADIS_SPI, "model": 3, "filt_ctrl": 3, "dec_rate": 1,
         "deltas": False},
        {"errors": {"ideal": True, "gyro_noise_dps_rthz": 0.0}, "clock_error": 0.015,
         "seed": 15},
    )  # fmt: skip
    rig.sim.motion = SineRate()
    rig.run(3.0)
    m = concat(rig.batches())
    t = concat(rig.truth_batches())
    settled = m["t_ns"] > m["t_ns"][0] + 1e9
    i = match_truth(m, t)
    period = 1e9 / (1000 * 1.015)
    err = (m["t_ns"] - t["t_ns"][i])[settled]
    assert abs(err.mean()) < 0.05 * period
    t_s = (m["t_ns"][settled] - rig.sim.t_origin_ns) / 1e9
    assert abs(delay_of(t_s, m["gyro"][settled])) < 0.05 * period / 1e9


def test_stamps_stay_increasing_when_the_fitted_period_moves_under_a_long_delay() -> None:
    """The delay subtracted is so many of the chip's samples, so it follows the fitted period;
    when the fit moves (reads whose brackets say little: here jittery brackets that are not
    hard bounds, late reads and frequent resyncs), the delay moves with it, by the same fraction
    of a 25 ms filter delay (1 % is 250 µs), while the clock only promises its own stamps
    increase.
    Published stamps must still increase strictly: a consumer integrating the gyro divides by
    their differences."""
    period = 1e6  # 1 kHz
    pipe = Pipeline(SampleClock(period), None, 0, group_delay_ns=25_000_000)
    rng = np.random.default_rng(2)  # a seed whose reads move the delay back before the fix
    k, t_host, out = -1, 1e9, []
    for _ in range(3000):
        t_host += rng.choice([2e6, 5e6, 40e6], p=[0.6, 0.35, 0.05])
        newest = int(t_host // period)
        # now and then samples are lost (a FIFO reset): the batch is placed by its read alone
        resync = bool(rng.random() < 0.3)
        n = max(1, (newest - k) // 2) if resync else newest - k
        k = newest
        # a bracket that is not a hard bound: up to 2 periods either side
        t0 = int(t_host - rng.uniform(0.0, 2.0) * period)
        t1 = int(t_host + rng.uniform(0.0, 2.0) * period)
        gyro = RawChannel(np.zeros((n, 3), dtype=np.int32), 1.0)
        b = pipe.process(RawBatch(n, {Channel.GYRO: gyro}, FifoRead(t0, t1, resync=resync)))
        out.append(b.t_ns)
    t = np.concatenate(out)
    assert np.all(np.diff(t) > 0)
