"""The simulated chips' noise against their datasheets' own figures, under the one-sided
convention (docs/timestamps.md): RMS over the configured filter's band = density * sqrt(noise
bandwidth), and Allan N (the Allan deviation at tau = 1 s) = density / sqrt(2).

Each chip is driven directly at virtual time, still and ideal (no bias, drift, instability or
clock error), and its samples taken before quantisation."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from imud.chips.adis16465.sim import Adis16465Sim
from imud.chips.bmi088.registers import AccelRegister as AR
from imud.chips.bmi088.registers import GyroRegister as GR
from imud.chips.bmi088.sim import Bmi088Sim
from imud.chips.icm42688p.registers import Bank0 as ICM
from imud.chips.icm42688p.sim import Icm42688pSim
from imud.chips.mpu6050.registers import Register as R
from imud.chips.mpu6050.sim import Mpu6050Sim
from imud.chips.stim300.sim import Stim300Sim
from imud.clock import VirtualClock
from imud.sim.settings import SimSettings

G = 9.80665


def allan_dev(x: np.ndarray, rate_hz: float, tau_s: float) -> np.ndarray:
    """Overlapping Allan deviation per column at tau (a whole number of samples)."""
    m = round(tau_s * rate_hz)
    c = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    avg = (c[m:] - c[:-m]) / m  # every m-sample mean
    d = avg[m:] - avg[:-m]
    return np.sqrt(0.5 * np.mean(d * d, axis=0))


def mpu6050_still(dlpf_cfg: int, div: int, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    clock = VirtualClock()
    sim = Mpu6050Sim(SimSettings(seed=21, errors={"ideal": True}), clock)
    out: list[tuple[np.ndarray, np.ndarray]] = []
    sim._reveal = lambda m, i, j: out.append((m.accel[i:j], m.gyro[i:j]))  # type: ignore[method-assign]
    sim.write(R.PWR_MGMT_1, bytes([0x01]))
    sim.write(R.SMPLRT_DIV, bytes([div]))
    sim.write(R.CONFIG, bytes([dlpf_cfg]))
    out.clear()
    clock.advance(int(seconds * 1e9))
    sim.advance()
    return np.concatenate([o[0] for o in out]), np.concatenate([o[1] for o in out])


def test_mpu6050_gyro_rms_and_allan_n_at_dlpf_100hz() -> None:
    """PS-MPU-6000A-00 rev 3.4 §6.1: rate noise spectral density 0.005 deg/s/rtHz, total RMS
    noise 0.05 deg/s at DLPF_CFG = 2 (100 Hz); §6.2: accel 400 ug/rtHz (no total given: the
    model's figure, the density over the accel's 94 Hz band, is checked)."""
    fm, wm = mpu6050_still(2, 0, 600.0)
    assert len(wm) == pytest.approx(600_000, abs=2)
    gyro_rms = np.degrees(wm.std(axis=0))
    assert gyro_rms == pytest.approx([0.05] * 3, rel=0.05)  # the datasheet's total
    n_gyro = np.degrees(allan_dev(wm, 1000.0, 1.0)).mean()
    assert n_gyro == pytest.approx(0.005 / math.sqrt(2), rel=0.05)
    accel_rms = (fm - fm.mean(axis=0)).std(axis=0)
    assert accel_rms == pytest.approx([400e-6 * G * math.sqrt(94.0)] * 3, rel=0.05)
    n_accel = allan_dev(fm, 1000.0, 1.0).mean()
    assert n_accel == pytest.approx(400e-6 * G / math.sqrt(2), rel=0.05)


def test_mpu6050_decimated_output_keeps_the_band_rms() -> None:
    """At 200 Hz out of the 1 kHz filter (SMPLRT_DIV 4) the chip keeps every fifth filtered
    sample: the RMS is still density * sqrt(98 Hz); the noise aliases, so only the RMS is the
    datasheet's here."""
    _, wm = mpu6050_still(2, 4, 300.0)
    assert np.degrees(wm.std(axis=0)) == pytest.approx([0.005 * math.sqrt(98.0)] * 3, rel=0.05)


# --- the other chips: each drawn one-sided from its datasheet, checked against it -------------
# Allan N is read at tau = 0.1 s (N = sigma_A(tau) sqrt(tau) on the white-noise line): 100 s of
# samples give a thousand 0.1 s windows, and every filter's memory is a few ms at most.
TAU = 0.1


def allan_n(x: np.ndarray, rate_hz: float) -> float:
    """Allan N (per sqrt(Hz)) from the Allan deviation at TAU, averaged over the axes."""
    return float(allan_dev(x, rate_hz, TAU).mean() * math.sqrt(TAU))


def capture(sim: Any, seconds: float, clock: VirtualClock) -> tuple[np.ndarray, np.ndarray]:
    """Accel and gyro as a sampled chip emits them (before quantisation) for `seconds`."""
    out: list[tuple[np.ndarray, np.ndarray]] = []
    sim._reveal = lambda m, i, j: out.append((m.accel[i:j], m.gyro[i:j]))
    clock.advance(int(seconds * 1e9))
    sim.advance()
    return np.concatenate([o[0] for o in out]), np.concatenate([o[1] for o in out])


def test_stim300_allan_n_is_the_datasheets_arw_and_vrw() -> None:
    """TS1524 rev.31 Table 5-3: ARW 0.15 deg/sqrt(h) = 0.0025 deg/s/sqrt(Hz) of Allan N; Table
    5-4: VRW 0.024 m/s/sqrt(h) = 4.0e-4 m/s^2/sqrt(Hz) (10 g). No total RMS is given: the RMS
    is the one-sided density (sqrt(2) N) over the 262 Hz filter's noise band."""
    clock = VirtualClock()
    sim = Stim300Sim(SimSettings(seed=31, errors={"ideal": True}), clock, filter_hz=262)
    fm, wm = capture(sim, 100.0, clock)
    assert len(wm) == pytest.approx(200_000, abs=25)  # and the 10 ms it makes ahead
    n_gyro, n_accel = 0.15 / 60, 0.024 / 60
    assert math.degrees(allan_n(wm, 2000.0)) == pytest.approx(n_gyro, rel=0.05)
    assert allan_n(fm, 2000.0) == pytest.approx(n_accel, rel=0.05)
    band = math.sqrt(2 * 262.0)  # sqrt(2) N sqrt(262 Hz)
    assert np.degrees(wm.std(axis=0)) == pytest.approx([n_gyro * band] * 3, rel=0.05)
    assert (fm - fm.mean(axis=0)).std(axis=0) == pytest.approx([n_accel * band] * 3, rel=0.05)


def test_adis16465_output_noise_and_density() -> None:
    """ADIS16465 Rev. B Table 1, the -3: rate noise density 0.007 deg/s/rtHz and output noise
    0.17 deg/s rms without filtering; accel 23 ug/rtHz and 0.6 mg rms. Allan N = density /
    sqrt(2): the -3's ARW, 0.30 deg/sqrt(h) = 0.005 deg/s/rtHz, agrees within 1 %."""
    clock = VirtualClock()
    sim = Adis16465Sim(SimSettings(seed=32, errors={"ideal": True}), clock, model=3)
    means: list[np.ndarray] = []
    words = sim._words

    def keep(mean: np.ndarray, *rest: Any) -> Any:
        means.append(mean[:, :6].copy())
        return words(mean, *rest)

    sim._words = keep  # type: ignore[method-assign]
    clock.advance(100_000_000_000)
    sim.advance()
    x = np.concatenate(means)
    wm, fm = x[:, :3], x[:, 3:]
    assert len(wm) == pytest.approx(200_000, abs=130)
    assert np.degrees(wm.std(axis=0)) == pytest.approx([0.17] * 3, rel=0.05)
    assert (fm - fm.mean(axis=0)).std(axis=0) == pytest.approx([0.6e-3 * G] * 3, rel=0.05)
    assert math.degrees(allan_n(wm, 2000.0)) == pytest.approx(0.007 / math.sqrt(2), rel=0.05)
    assert allan_n(fm, 2000.0) == pytest.approx(23e-6 * G / math.sqrt(2), rel=0.05)


def test_bmi088_gyro_rms_is_boschs_band_and_allan_n_the_density() -> None:
    """BMI088: gyro 0.014 deg/s/rtHz, accel 175 ug/rtHz (docs/chips/bmi088.md); Bosch's own
    RMS rule for the filtered gyro is density * sqrt(1.22 * bandwidth) (Bosch Sensortec
    community forum, 2020), here 2000 Hz / 230 Hz. The accel's bandwidth table was not
    retrieved: its noise is the density up to its 800 Hz Nyquist."""
    clock = VirtualClock()
    sim = Bmi088Sim(SimSettings(seed=33, errors={"ideal": True}), clock)
    sim.gyro.write(GR.GYRO_BANDWIDTH, bytes([0x01]))  # 2000 Hz ODR, 230 Hz filter
    acc = sim.accel
    acc.write(AR.ACC_PWR_CTRL, bytes([0x04]))
    clock.advance(6_000_000)
    acc.write(AR.ACC_PWR_CONF, bytes([0x00]))
    clock.advance(6_000_000)
    acc.write(AR.ACC_CONF, bytes([0xAC]))  # normal, 1600 Hz
    got: dict[str, list[np.ndarray]] = {"a": [], "g": []}
    acc._reveal = lambda m, i, j: got["a"].append(m.accel[i:j])  # type: ignore[method-assign]
    sim.gyro._reveal = lambda m, i, j: got["g"].append(m.gyro[i:j])  # type: ignore[method-assign]
    clock.advance(100_000_000_000)
    acc.advance()
    sim.gyro.advance()
    wm, fm = np.concatenate(got["g"]), np.concatenate(got["a"])
    assert len(wm) == pytest.approx(200_000, rel=0.001) and len(fm) > 159_000
    rms = 0.014 * math.sqrt(1.22 * 230)
    assert np.degrees(wm.std(axis=0)) == pytest.approx([rms] * 3, rel=0.05)
    assert math.degrees(allan_n(wm, 2000.0)) == pytest.approx(0.014 / math.sqrt(2), rel=0.05)
    f0 = fm - fm.mean(axis=0)
    assert f0.std(axis=0) == pytest.approx([175e-6 * G * math.sqrt(800)] * 3, rel=0.05)
    assert allan_n(fm, 1600.0) == pytest.approx(175e-6 * G / math.sqrt(2), rel=0.05)


def test_icm42688p_density_over_the_ui_filter_band() -> None:
    """DS-000347 v1.7 front page: 2.8 mdps/rtHz and 70 ug/rtHz (no total RMS retrieved). At
    1 kHz with the UI filter at ODR/4 (the reset value), the noise band is 250 Hz."""
    clock = VirtualClock()
    sim = Icm42688pSim(SimSettings(seed=34, errors={"ideal": True}), clock)
    sim.write(ICM.PWR_MGMT0, bytes([0x0F]))  # gyro and accel low-noise, 1 kHz, ODR/4
    fm, wm = capture(sim, 100.0, clock)
    assert len(wm) == pytest.approx(100_000, abs=2)
    assert np.degrees(wm.std(axis=0)) == pytest.approx([0.0028 * math.sqrt(250)] * 3, rel=0.05)
    assert math.degrees(allan_n(wm, 1000.0)) == pytest.approx(0.0028 / math.sqrt(2), rel=0.05)
    f0 = fm - fm.mean(axis=0)
    assert f0.std(axis=0) == pytest.approx([70e-6 * G * math.sqrt(250)] * 3, rel=0.05)
    assert allan_n(fm, 1000.0) == pytest.approx(70e-6 * G / math.sqrt(2), rel=0.05)
