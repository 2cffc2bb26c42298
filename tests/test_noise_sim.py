"""The simulated chips' white noise through `imud noise`'s fit: each chip, still and ideal at
virtual time (tests/test_sim_noise.py drives them), gives back its datasheet density as Allan
N = density / sqrt(2) inside the fit's 95 % interval (the one-sided convention, docs/noise.md
"Which density"). The chips' own filters (the MPU6050's 100 Hz DLPF at 1 kHz, the ICM-42688-P's
UI filter at ODR / 4) flatten the curve's first taus: the fit starts past them."""

from __future__ import annotations

import math

import numpy as np

from imud.chips.icm42688p.registers import Bank0 as ICM
from imud.chips.icm42688p.sim import Icm42688pSim
from imud.chips.stim300.sim import Stim300Sim
from imud.clock import VirtualClock
from imud.noise.allan import oadev
from imud.noise.fit import fit
from imud.sim.settings import SimSettings
from tests.test_sim_noise import capture, mpu6050_still


def _check(
    accel: np.ndarray, gyro: np.ndarray, rate: float, gyro_dps: float, accel_si: float
) -> None:
    fits = fit(oadev(np.hstack((gyro, accel)), rate))
    want = [math.radians(gyro_dps) / math.sqrt(2)] * 3 + [accel_si / math.sqrt(2)] * 3
    for k, (f, n) in enumerate(zip(fits, want, strict=True)):
        t = f.terms["N"]
        assert t.lo <= n <= t.hi, (k, t, n)
        # and the other convention (Allan N = the datasheet's density) is outside it
        assert not t.lo <= n * math.sqrt(2) <= t.hi, (k, t, n)


def test_mpu6050_at_1khz_behind_its_100hz_dlpf() -> None:
    accel, gyro = mpu6050_still(2, 0, 200.0)
    _check(accel, gyro, 1000.0, 0.005, 400e-6 * 9.80665)


def test_icm42688p_at_1khz() -> None:
    clock = VirtualClock()
    sim = Icm42688pSim(SimSettings(seed=34, errors={"ideal": True}), clock)
    sim.write(ICM.PWR_MGMT0, bytes([0x0F]))  # gyro and accel low-noise, 1 kHz, ODR/4
    accel, gyro = capture(sim, 200.0, clock)
    _check(accel, gyro, 1000.0, 0.0028, 70e-6 * 9.80665)


def test_stim300_at_2khz() -> None:
    """The STIM300's figures are Allan ARW/VRW already: 0.15 deg/sqrt(h), 0.024 m/s/sqrt(h);
    as densities (sqrt(2) N) they go through the same check."""
    clock = VirtualClock()
    sim = Stim300Sim(SimSettings(seed=31, errors={"ideal": True}), clock, filter_hz=262)
    accel, gyro = capture(sim, 100.0, clock)
    _check(accel, gyro, 2000.0, 0.15 / 60 * math.sqrt(2), 0.024 / 60 * math.sqrt(2))
