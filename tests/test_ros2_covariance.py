"""The ROS 2 messages' covariances (imud/ros2/covariance.py, docs/ros2.md "Covariances").

Per-sample variances against each chip's datasheet figures, written out here (density^2 times the
configured filter's noise bandwidth, one-sided); the variance of a message's k-sample mean against
simulations written here (white noise through a first-order IIR, a first-order Gauss-Markov
sequence, held readings) within their statistical tolerance; and what a chip without noise
figures gets: REP-145's "unknown", all zeros, never -1."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from imud import registry
from imud.chips.api import DeviceBase, NoiseFigures
from imud.config import load_config, parse_config
from imud.ros2 import covariance as cv
from imud.ros2.decimate import factor
from imud.ros2.messages import _noise

G = 9.80665
REPO = Path(__file__).resolve().parent.parent
DOC = (REPO / "docs" / "ros2.md").read_text()
SPI = {"kind": "sim", "bus": "spiT", "transport": "spi", "cs": 0, "speed_hz": 10_000_000}
BUSES: dict[str, dict[str, Any]] = {
    "mpu6050": {"bus": {"kind": "sim", "bus": "simT", "address": 0x68}},
    "icm42688p": {"bus": SPI},
    "bmi088": {"bus": SPI, "gyro_bus": {**SPI, "cs": 1}},
    "bno055": {"bus": {"kind": "sim", "bus": "uartT", "transport": "serial", "baud": 115200}},
    "adis16465": {"bus": {**SPI, "speed_hz": 2_000_000}, "model": 3},
    "stim300": {"bus": {"kind": "sim", "bus": "rs422T", "transport": "serial", "baud": 1843200}},
}


def device(chip: str, tmp_path: Path, **fields: Any) -> DeviceBase:
    raw = {"device": [{"name": "d0", "chip": chip, **BUSES[chip], **fields}]}
    d: DeviceBase = parse_config(raw, tmp_path).device[0]
    return d


def figures(chip: str, tmp_path: Path, **fields: Any) -> NoiseFigures:
    nf = _noise(device(chip, tmp_path, **fields))
    assert nf is not None
    return nf


def var1(density: float, band_hz: float) -> float:
    return density**2 * band_hz


def dps(x: float) -> float:
    return math.radians(x)


# --- one sample: the datasheets' figures ---------------------------------------------------------
def test_mpu6050_density_over_the_dlpf_band(tmp_path: Path) -> None:
    """PS-MPU-6000A-00 §6.1/6.2: 0.005 deg/s/rtHz and 400 ug/rtHz; the register-26 table: the
    gyro DLPF of dlpf_hz, the accel's 44 Hz beside the gyro's 42."""
    nf = figures("mpu6050", tmp_path, dlpf_hz=42, odr_hz=1000.0)
    c = cv.covariances(nf, 1000.0, 1)
    assert c.gyro[0] == pytest.approx(dps(0.005) ** 2 * 42, rel=1e-12)
    assert c.accel[0] == pytest.approx((400e-6 * G) ** 2 * 44, rel=1e-12)
    # the sheet's own total: 0.05 deg/s rms at the 100 Hz DLPF (98 Hz in the table)
    nf = figures("mpu6050", tmp_path, dlpf_hz=98, odr_hz=1000.0)
    assert math.degrees(math.sqrt(var1(nf.gyro_density, nf.gyro_bandwidth_hz))) == pytest.approx(
        0.05, rel=0.02
    )
    # DLPF off: the gyro's 256 Hz (at 8 kHz inside), the accel's 260 Hz
    nf = figures("mpu6050", tmp_path, dlpf_hz=256, odr_hz=1000.0)
    assert (nf.gyro_bandwidth_hz, nf.accel_bandwidth_hz) == (256.0, 260.0)


def test_icm42688p_density_over_the_ui_filter_band(tmp_path: Path) -> None:
    """DS-000347 front page: 2.8 mdps/rtHz, 70 ug/rtHz; UI filter max(400 Hz, ODR)/div."""
    nf = figures("icm42688p", tmp_path, odr_hz=1000, ui_filter="odr/4")
    assert var1(nf.gyro_density, nf.gyro_bandwidth_hz) == pytest.approx(dps(0.0028) ** 2 * 250)
    assert var1(nf.accel_density, nf.accel_bandwidth_hz) == pytest.approx((70e-6 * G) ** 2 * 250)
    assert figures("icm42688p", tmp_path, odr_hz=8000, ui_filter="odr/4").gyro_bandwidth_hz == 2000
    assert figures("icm42688p", tmp_path, odr_hz=1000, ui_filter="odr/2").gyro_bandwidth_hz == 500
    assert (
        figures("icm42688p", tmp_path, odr_hz=1000, ui_filter="low_latency").gyro_bandwidth_hz
        == 500
    )
    # below 400 Hz the filter's band stays max(400, ODR)/div: aliased, not narrowed to Nyquist
    assert figures("icm42688p", tmp_path, odr_hz=100, ui_filter="odr/4").gyro_bandwidth_hz == 100


def test_bmi088_gyro_is_boschs_1_22_times_its_filter(tmp_path: Path) -> None:
    """0.014 deg/s/rtHz over 1.22 x the GYRO_BANDWIDTH filter; accel 175 ug/rtHz to its own
    Nyquist (its bandwidth table was not retrieved)."""
    nf = figures("bmi088", tmp_path, odr_hz=2000, gyro_filter_hz=230, accel_odr_hz=1600)
    assert var1(nf.gyro_density, nf.gyro_bandwidth_hz) == pytest.approx(
        dps(0.014) ** 2 * 1.22 * 230
    )
    assert var1(nf.accel_density, nf.accel_bandwidth_hz) == pytest.approx((175e-6 * G) ** 2 * 800)


def test_bno055_locked_filters_and_its_magnetometer(tmp_path: Path) -> None:
    """Its sensors' class densities (no BNO055 figure exists) over the fusion's locked filters,
    accel 62.5 Hz and gyro 32 Hz; the magnetometer 0.3 uT a reading, held five 100 Hz samples."""
    nf = figures("bno055", tmp_path)
    c = cv.covariances(nf, 100.0, 1)
    assert c.gyro[0] == pytest.approx(dps(0.014) ** 2 * 32)
    assert c.accel[0] == pytest.approx((150e-6 * G) ** 2 * 62.5)
    assert c.mag[0] == pytest.approx((0.3e-6) ** 2)
    assert nf.mag_hold == 5


def test_adis16465_unfiltered_variance_is_the_sheets_output_noise(tmp_path: Path) -> None:
    """DS Rev. B Table 1, the -3: with neither the Bartlett window nor decimation, one output's
    variance is the sheet's output noise without filtering, 0.17 deg/s and 0.6 mg rms; both
    filters narrow it."""
    nf = figures("adis16465", tmp_path, dec_rate=0, filt_ctrl=0, deltas=False)
    assert var1(nf.gyro_density, nf.gyro_bandwidth_hz) == pytest.approx(dps(0.17) ** 2)
    assert var1(nf.accel_density, nf.accel_bandwidth_hz) == pytest.approx((0.6e-3 * G) ** 2)
    wide = nf.gyro_bandwidth_hz
    assert figures("adis16465", tmp_path, dec_rate=1).gyro_bandwidth_hz < 0.7 * wide
    # B = 6: two 64-sample averages at 2 kHz, a noise bandwidth of about 2000 / 2 * (2/3) / 64
    narrow = figures("adis16465", tmp_path, dec_rate=1, filt_ctrl=6).gyro_bandwidth_hz
    assert narrow == pytest.approx(1000 * 2 / 3 / 64, rel=0.02)


def test_stim300_random_walks_as_one_sided_densities(tmp_path: Path) -> None:
    """TS1524 Tables 5-3/5-4: ARW 0.15 deg/sqrt(h), VRW 0.024 m/s/sqrt(h) (10 g), 0.15 (80 g):
    Allan N = x / 60, one-sided density sqrt(2) N, over the filter's -3 dB frequency."""
    nf = figures("stim300", tmp_path, filter_hz=262)
    n_gyro, n_accel = dps(0.15 / 60), 0.024 / 60
    assert var1(nf.gyro_density, nf.gyro_bandwidth_hz) == pytest.approx(2 * n_gyro**2 * 262)
    assert var1(nf.accel_density, nf.accel_bandwidth_hz) == pytest.approx(2 * n_accel**2 * 262)
    nf = figures("stim300", tmp_path, filter_hz=16, accel_range_g=80)
    assert var1(nf.accel_density, nf.accel_bandwidth_hz) == pytest.approx(2 * (0.15 / 60) ** 2 * 16)


def test_every_chip_of_imuds_states_its_noise(tmp_path: Path) -> None:
    for chip in BUSES:
        assert registry.CHIPS[chip].noise is not None, chip
        c = cv.covariances(figures(chip, tmp_path), 100.0, 3)
        for m in (c.accel, c.gyro):
            assert m.shape == (9,) and m.dtype == np.float64
            assert np.all(m[[0, 4, 8]] > 0) and np.all(np.delete(m, [0, 4, 8]) == 0)


# --- the simulators draw what the covariances state ---------------------------------------------
def test_the_simulated_filters_have_the_stated_noise_bandwidths(tmp_path: Path) -> None:
    """The simulators' filters read their bandwidths from the same module as the specs. The
    MPU6050's FIR models keep the table's group delay, which at DLPF_CFG 3-6 no filter of that
    bandwidth has: there, and for the unfiltered 1 kHz accel with the DLPF off, the simulator's
    noise is wider than the table's (docs/ros2.md)."""
    from imud.chips.icm42688p.registers import ODR_CODES, UI_FILTER_CODES
    from imud.chips.icm42688p.registers import Bank0 as ICM
    from imud.chips.icm42688p.sim import Icm42688pSim
    from imud.chips.mpu6050.registers import Register as MPU
    from imud.chips.mpu6050.sim import Mpu6050Sim
    from imud.clock import VirtualClock
    from imud.sim.settings import SimSettings

    icm = Icm42688pSim(SimSettings(seed=1), VirtualClock())
    for odr in (100, 1000, 8000):
        for ui in ("odr/2", "odr/4", "odr/20", "low_latency"):
            icm.write(ICM.GYRO_CONFIG0, bytes([ODR_CODES[odr]]))
            code = UI_FILTER_CODES[ui]
            icm.write(ICM.GYRO_ACCEL_CONFIG0, bytes([code << 4 | code]))
            nf = figures("icm42688p", tmp_path, odr_hz=odr, ui_filter=ui)
            accel, gyro = icm.filters()
            assert gyro.enbw_hz == pytest.approx(nf.gyro_bandwidth_hz, rel=1e-3), (odr, ui)
            assert accel.enbw_hz == pytest.approx(nf.accel_bandwidth_hz, rel=1e-3), (odr, ui)
    mpu = Mpu6050Sim(SimSettings(seed=1), VirtualClock())
    for cfg, dlpf in enumerate((256, 188, 98, 42)):
        mpu.write(MPU.CONFIG, bytes([cfg]))
        nf = figures("mpu6050", tmp_path, dlpf_hz=dlpf, odr_hz=1000.0)
        accel, gyro = mpu.filters()
        if cfg < 3:
            assert gyro.enbw_hz == pytest.approx(nf.gyro_bandwidth_hz, rel=1e-3), dlpf
        else:
            assert gyro.enbw_hz > nf.gyro_bandwidth_hz
        if cfg in (1, 2):
            assert accel.enbw_hz == pytest.approx(nf.accel_bandwidth_hz, rel=1e-3), dlpf
    assert accel.enbw_hz > nf.accel_bandwidth_hz  # DLPF_CFG 3


def test_the_simulated_adis16465_output_variance_is_the_stated_one(tmp_path: Path) -> None:
    """The -3 with the Bartlett window of B = 1 and DEC_RATE = 1 (1 kHz): each output's
    variance, as the simulator makes it, is density^2 * the spec's cascade bandwidth."""
    from imud.chips.adis16465.registers import Register as AR
    from imud.chips.adis16465.sim import Adis16465Sim
    from imud.clock import VirtualClock
    from imud.sim.settings import SimSettings

    clock = VirtualClock()
    sim = Adis16465Sim(SimSettings(seed=12, errors={"ideal": True}), clock, model=3)
    for reg, value in ((AR.FILT_CTRL, 1), (AR.DEC_RATE, 1)):  # low byte, then high byte
        sim.spi_frame(bytes([0x80 | reg, value, 0x80 | (reg + 1), 0]), 1_000_000)
    means: list[np.ndarray] = []
    words = sim._words

    def keep(mean: np.ndarray, *rest: Any) -> Any:
        means.append(mean[:, :6].copy())
        return words(mean, *rest)

    sim._words = keep  # type: ignore[method-assign,assignment]
    clock.advance(40_000_000_000)
    sim.advance()
    x = np.concatenate(means)[100:]  # after the new settings' first block
    nf = figures("adis16465", tmp_path, dec_rate=1, filt_ctrl=1)
    assert x.shape[0] == pytest.approx(40_000, rel=0.05)
    assert (
        nf.gyro_bandwidth_hz
        < 0.6 * figures("adis16465", tmp_path, dec_rate=0, deltas=False).gyro_bandwidth_hz
    )
    got_gyro = x[:, :3].var(axis=0)
    got_accel = (x[:, 3:] - x[:, 3:].mean(axis=0)).var(axis=0)
    assert got_gyro == pytest.approx([var1(nf.gyro_density, nf.gyro_bandwidth_hz)] * 3, rel=0.05)
    assert got_accel == pytest.approx([var1(nf.accel_density, nf.accel_bandwidth_hz)] * 3, rel=0.05)


# --- the quick start -----------------------------------------------------------------------------
def test_the_quick_starts_covariances_at_200_messages_a_second() -> None:
    """configs/sim.toml at [ros2]'s default 200 Hz, as docs/ros2.md's example table shows it.
    The mean of k samples is computed here pair by pair (an independent sum)."""
    cfg = load_config(REPO / "configs" / "sim.toml")
    want = {  # device: (k, gyro var_1, accel var_1, gyro B, accel B), from the datasheets
        "imu0": (5, dps(0.005) ** 2 * 188, (400e-6 * G) ** 2 * 184, 188.0, 184.0),
        "imu1": (3, dps(0.005) ** 2 * 98, (400e-6 * G) ** 2 * 94, 98.0, 94.0),
        "icm0": (40, dps(0.0028) ** 2 * 2000, (70e-6 * G) ** 2 * 2000, 2000.0, 2000.0),
        "bmi0": (10, dps(0.014) ** 2 * 1.22 * 532, (175e-6 * G) ** 2 * 800, 1.22 * 532, 800.0),
        "bno0": (1, dps(0.014) ** 2 * 32, (150e-6 * G) ** 2 * 62.5, 32.0, 62.5),
    }
    for d in cfg.device:
        k, g1, a1, gb, ab = want[d.name]
        assert factor(d.odr_hz, 200.0) == k
        c = cv.covariances(_noise(d), d.odr_hz, k)

        def mean_of_k(v: float, b: float, odr: float = d.odr_hz, k: int = k) -> float:
            a = math.exp(-4 * b / odr)  # exp(-2 pi fc / odr), fc = 2 B / pi
            return v / k**2 * sum(a ** abs(i - j) for i in range(k) for j in range(k))

        assert c.gyro[0] == pytest.approx(mean_of_k(g1, gb), rel=1e-9), d.name
        assert c.accel[0] == pytest.approx(mean_of_k(a1, ab), rel=1e-9), d.name
        # and docs/ros2.md's example table says so
        (row,) = [r for r in DOC.splitlines() if r.startswith(f"| {d.name} |")]
        for v in (g1, c.gyro[0], a1, c.accel[0]):
            assert f"{v:.2e}".replace("e-0", "e-") in row, (d.name, v, row)


# --- the mean of k samples, against simulations ---------------------------------------------------
# Each simulated series starts in its stationary state and gives one k-sample mean (and one last
# sample), so the N means are independent: the variance's relative standard error is sqrt(2 / N).
def first_order_iir(x: np.ndarray, a: float, start: np.ndarray) -> np.ndarray:
    """y[n] = a y[n-1] + (1 - a) x[n] down axis 0 from y[-1] = `start`: a loop over the k time
    steps, vectorised over the many series."""
    y = np.empty_like(x)
    prev = start
    for n in range(x.shape[0]):
        prev = a * prev + (1 - a) * x[n]
        y[n] = prev
    return y


@pytest.mark.parametrize(
    ("odr", "band", "k"), [(1000.0, 42.0, 5), (1000.0, 20.0, 8), (500.0, 10.0, 3)]
)
def test_white_noise_through_a_first_order_filter_then_averaged(
    odr: float, band: float, k: int
) -> None:
    """White noise of one-sided density D at `odr` (per-sample sigma D sqrt(odr / 2)) through a
    first-order IIR of noise bandwidth `band` (corner 2 band / pi; bands well below odr, where
    the discrete filter's noise bandwidth is the continuous one's within 0.5 %), averaged k at a
    time: one sample's variance is D^2 band and the mean's imud's, within 4 standard errors."""
    rng = np.random.default_rng(20240611)
    density, series = 3e-3, 400_000
    sigma_x = density * math.sqrt(odr / 2)
    a = math.exp(-2 * math.pi * (2 * band / math.pi) / odr)
    stationary = sigma_x * math.sqrt((1 - a) / (1 + a))
    y = first_order_iir(
        rng.normal(0.0, sigma_x, (k, series)), a, rng.normal(0.0, stationary, series)
    )
    want = cv.covariances(NoiseFigures(density, band, density, band), odr, k).gyro[0]
    tol = 4 * math.sqrt(2 / series) + 0.005
    assert float(y[-1].var()) == pytest.approx(density**2 * band, rel=tol)
    assert float(y.mean(axis=0).var()) == pytest.approx(want, rel=tol)
    assert want < density**2 * band  # averaging helps, less than k-fold (neighbours alike)
    assert want > density**2 * band / k


@pytest.mark.parametrize(
    ("odr", "band", "k"), [(2000.0, 649.0, 10), (8000.0, 2000.0, 40), (100.0, 62.5, 2)]
)
def test_a_first_order_gauss_markov_sequence_averaged(odr: float, band: float, k: int) -> None:
    """Wide bands, where a sample barely resembles the next: a sequence with exactly the
    model's correlation exp(-2 pi fc m / odr) and variance D^2 B, averaged k at a time."""
    rng = np.random.default_rng(99)
    density, series = 1e-3, 2_000_000 // k
    v1 = density**2 * band
    a = math.exp(-2 * math.pi * (2 * band / math.pi) / odr)
    y = np.empty((k, series))
    y[0] = rng.normal(0.0, math.sqrt(v1), series)
    for n in range(1, k):
        y[n] = a * y[n - 1] + rng.normal(0.0, math.sqrt(v1 * (1 - a * a)), series)
    want = cv.covariances(NoiseFigures(density, band, density, band), odr, k).accel[0]
    assert float(y.mean(axis=0).var()) == pytest.approx(want, rel=4 * math.sqrt(2 / series))


@pytest.mark.parametrize("k", [1, 2, 5, 7, 12])
def test_held_magnetometer_readings_averaged_at_any_phase(k: int) -> None:
    """Independent readings each held five samples, averaged k at a time from every starting
    sample (the hold's phase against the groups is not known): imud's variance."""
    rng = np.random.default_rng(5)
    sigma, hold = 0.3e-6, 5
    y = np.repeat(rng.normal(0.0, sigma, 400_000), hold)
    c = np.concatenate([[0.0], np.cumsum(y)])
    means = (c[k:] - c[:-k]) / k  # every k-sample window
    nf = NoiseFigures(1.0, 1.0, 1.0, 1.0, mag_sigma_t=sigma, mag_hold=hold)
    want = cv.covariances(nf, 100.0, k).mag[0]
    assert float(means.var()) == pytest.approx(want, rel=0.02)


def test_long_means_tend_to_the_densitys_low_frequency_limit() -> None:
    """T = k / odr seconds of a one-sided density D: D^2 / (2 T), whatever a band well below
    the output's Nyquist. A band at the Nyquist (white samples, which average k-fold) keeps the
    model's first-order correlation exp(-2) between neighbours: it over-states such a long
    mean's variance by (1 + e^-2) / (1 - e^-2), docs/ros2.md says so."""
    d, odr, k = 2e-3, 8000.0, 16000  # 2 s: many times the filters' memory
    for band in (20.0, 50.0, 200.0):
        v = cv.covariances(NoiseFigures(d, band, d, band), odr, k).gyro[0]
        assert v == pytest.approx(d**2 / (2 * k / odr), rel=0.01)
    v = cv.covariances(NoiseFigures(d, odr / 2, d, odr / 2), odr, k).gyro[0]
    e2 = math.exp(-2)
    assert v / (d**2 / (2 * k / odr)) == pytest.approx((1 + e2) / (1 - e2), rel=0.01)


# --- unknown, and never -1 ------------------------------------------------------------------------
def test_a_chip_without_noise_figures_publishes_unknown_never_minus_one(tmp_path: Path) -> None:
    from tests.toychip import SPEC

    c = cv.covariances(None, 200.0, 1)
    for m in (c.accel, c.gyro, c.mag):
        assert m.shape == (9,) and not m.any()
    registry.register(SPEC)
    try:
        toy = SPEC.config_model.model_validate(
            {"name": "t0", "chip": "toy", "bus": {**SPI, "speed_hz": 1_000_000}}
        )
        assert _noise(toy) is None
    finally:
        registry.unregister(SPEC.name)


@pytest.mark.parametrize(
    "bad",
    [
        {"accel_density": 0.0},
        {"gyro_bandwidth_hz": -1.0},
        {"accel_bandwidth_hz": math.nan},
        {"mag_sigma_t": 0.0},
        {"mag_hold": 0},
    ],
)
def test_noise_figures_refuse_what_would_read_as_unknown(bad: dict[str, float]) -> None:
    good: dict[str, Any] = {"accel_density": 1e-3, "accel_bandwidth_hz": 10.0,
                            "gyro_density": 1e-4, "gyro_bandwidth_hz": 10.0}  # fmt: skip
    NoiseFigures(**good)
    with pytest.raises(ValueError, match="finite and positive"):
        NoiseFigures(**{**good, **bad})
