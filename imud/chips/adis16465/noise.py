"""The ADIS16465's white noise: the datasheet's densities, its sensors' own noise bands, and the
noise bandwidth of one output after the Bartlett window (FILT_CTRL) and the DEC_RATE average, the
one source of them for the simulator and for the ROS 2 covariances (docs/ros2.md "Covariances").

The densities are one-sided: with the output noise without filtering (DS Table 1: gyro 0.07 /
0.08 / 0.17 deg/s rms at 0.003 / 0.003 / 0.007 deg/s/rtHz, accel 0.6 mg rms at 23 ug/rtHz) they
give each sensor's noise band, (rms / density)^2, close to the 550 / 600 Hz sensor bandwidths
(docs/chips/adis16465.md "Noise convention"). That band limit's shape is not published: it is
modelled as a short symmetric Gaussian FIR on the 2 kHz grid with that noise bandwidth (its delay
is not published either: it colours the noise only)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from imud.chips.adis16465.registers import INTERNAL_RATE_HZ
from imud.chips.api import NoiseFigures
from imud.units import STANDARD_GRAVITY as G

F64 = npt.NDArray[np.float64]
GYRO_NOISE_DPS_RTHZ = {1: 0.003, 2: 0.003, 3: 0.007}  # DS Rev. B Table 1, per model -1/-2/-3
GYRO_RMS_DPS = {1: 0.07, 2: 0.08, 3: 0.17}  # output noise, no filtering
ACCEL_NOISE_UG_RTHZ = 23.0
ACCEL_RMS_MG = 0.6
GYRO_NOISE_BAND_HZ = {m: (GYRO_RMS_DPS[m] / d) ** 2 for m, d in GYRO_NOISE_DPS_RTHZ.items()}
ACCEL_NOISE_BAND_HZ = (ACCEL_RMS_MG * 1e3 / ACCEL_NOISE_UG_RTHZ) ** 2


def band_taps(band_hz: float, rate_hz: float = INTERNAL_RATE_HZ) -> F64:
    """A sensor's band limit: a symmetric Gaussian FIR of unit DC gain whose one-sided noise
    bandwidth on the grid, rate/2 * sum(h^2), is `band_hz` (the identity from the Nyquist up)."""
    target = 2.0 * band_hz / rate_hz  # sum h^2 wanted
    if target >= 1.0:
        return np.ones(1)
    k = np.arange(2 * math.ceil(1.0 / target) + 1, dtype=np.float64)
    k -= k.mean()

    def taps(width: float) -> F64:
        h = np.exp(-0.5 * (k / width) ** 2)
        out: F64 = h / h.sum()
        return out

    lo, hi = 0.1, 1e3 * k.shape[0]  # sum h^2 falls as the width grows
    for _ in range(80):
        mid = math.sqrt(lo * hi)
        if float((taps(mid) ** 2).sum()) > target:
            lo = mid
        else:
            hi = mid
    return taps(math.sqrt(lo * hi))


def bartlett(filt_ctrl: int) -> F64:
    """FILT_CTRL's Bartlett window: two cascaded averages of 2^B internal samples."""
    box = np.full(1 << filt_ctrl, 1.0 / (1 << filt_ctrl))
    out: F64 = np.convolve(box, box)
    return out


def output_bandwidth_hz(band_hz: float, filt_ctrl: int, dec: int) -> float:
    """The noise bandwidth of one output sample: white noise through the sensor's band limit,
    the Bartlett window and the average of `dec` (DEC_RATE + 1) internal samples, all on the
    2 kHz grid: rate/2 * sum(h^2) of their cascade."""
    h = np.convolve(np.convolve(band_taps(band_hz), bartlett(filt_ctrl)), np.full(dec, 1.0 / dec))
    return INTERNAL_RATE_HZ / 2 * float((h * h).sum())


def noise_figures(model: int, filt_ctrl: int, dec_rate: int) -> NoiseFigures:
    """At a configured model (-1, -2, -3), FILT_CTRL and DEC_RATE."""
    dec = dec_rate + 1
    return NoiseFigures(
        accel_density=ACCEL_NOISE_UG_RTHZ * 1e-6 * G,
        accel_bandwidth_hz=output_bandwidth_hz(ACCEL_NOISE_BAND_HZ, filt_ctrl, dec),
        gyro_density=math.radians(GYRO_NOISE_DPS_RTHZ[model]),
        gyro_bandwidth_hz=output_bandwidth_hz(GYRO_NOISE_BAND_HZ[model], filt_ctrl, dec),
    )
