"""The chips' configured low-pass filters delay every sample by their documented group delay
(docs/timestamps.md), the simulators model it, and the pipeline moves every stamp back by it:

- measured on the simulator's output from a known motion (a sinusoidal rate: the published
  gyro against the true rate, as amplitude and phase at the motion's frequency), the delay is
  the datasheet's;
- through driver and pipeline, published stamps match the truth (the instant the motion
  happened) and the published gyro shows no delay left against the true rate at its stamps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imud.chips.mpu6050.driver import group_delay_s
from imud.chips.mpu6050.registers import DLPF_BANDWIDTHS_HZ
from imud.chips.mpu6050.registers import Register as R
from imud.chips.mpu6050.sim import Mpu6050Sim
from imud.clock import VirtualClock
from imud.sim.settings import SimSettings
from tests.helpers import concat, make_rig, match_truth

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
    sim._emit = lambda t, fm, wm, temp: out.append((t, wm))  # type: ignore[method-assign]
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
