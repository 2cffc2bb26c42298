"""Register-level MPU6050 simulator: registers, sample clock, 1024-byte FIFO, physics.

Samples are produced lazily: every bus access first advances the chip to the clock's present, so
the same model runs in real time (daemon) or at virtual time (tests, benchmarks).
"""

from __future__ import annotations

import numpy as np

from imud.chips.mpu6050.noise import (
    ACCEL_DLPF_HZ,
    ACCEL_NOISE_UG_RTHZ,
    GYRO_DLPF_HZ,
    GYRO_NOISE_DPS_RTHZ,
)
from imud.chips.mpu6050.registers import (
    ACCEL_RANGES_G,
    FIFO_SIZE,
    GYRO_RANGES_DPS,
    WHO_AM_I_VALUE,
    FifoEn,
    IntStatus,
    PwrMgmt1,
    UserCtrl,
)
from imud.chips.mpu6050.registers import Register as R
from imud.clock import Clock
from imud.sim.chip import Encoded, Measured
from imud.sim.filters import FilteredChip, SensorFilter, design
from imud.sim.physics import ChipFigures, quantise
from imud.sim.settings import SimSettings
from imud.units import STANDARD_GRAVITY as G

# Noise densities from the datasheet (imud/chips/mpu6050/noise.py, shared with the ROS 2
# covariances); bias and drift sigmas are typical turn-on spreads, moderated
FIGURES = ChipFigures(
    accel_noise_ug_rthz=ACCEL_NOISE_UG_RTHZ,
    gyro_noise_dps_rthz=GYRO_NOISE_DPS_RTHZ,
    accel_bias_mg=25.0,
    gyro_bias_dps=1.0,
    accel_bias_instability_ug=100.0,
    gyro_bias_instability_dph=20.0,
    scale_error=0.01,
    misalignment_deg=0.3,
    accel_temp_drift_mg_per_c=0.5,
    gyro_temp_drift_dps_per_c=0.02,
)

# The DLPF's group delay per DLPF_CFG 0..6 (s), accel at Fs 1 kHz and gyro (RM-MPU-6000A-00 rev
# 4.2, §4.3, register 26 table; docs/chips/mpu6050.md); its bandwidths are noise.py's
ACCEL_DLPF_DELAY_S = (0.0, 2.0e-3, 3.0e-3, 4.9e-3, 8.5e-3, 13.8e-3, 19.0e-3)
GYRO_DLPF_DELAY_S = (0.98e-3, 1.9e-3, 2.8e-3, 4.8e-3, 8.3e-3, 13.4e-3, 18.6e-3)

# plain ints on the hot path: an operator on an IntFlag builds a new enum member each time
_DATA_RDY = int(IntStatus.DATA_RDY_INT)
_OFLOW = int(IntStatus.FIFO_OFLOW_INT)
_FIFO_ON = int(UserCtrl.FIFO_EN)
_EN_ACCEL, _EN_TEMP = int(FifoEn.ACCEL), int(FifoEn.TEMP)
_EN_GYRO = ((int(FifoEn.XG), 0), (int(FifoEn.YG), 1), (int(FifoEn.ZG), 2))
RESET_BUSY_NS = 20_000_000  # the chip ignores the bus while it reloads after DEVICE_RESET
_WRITABLE = {
    R.SMPLRT_DIV,
    R.CONFIG,
    R.GYRO_CONFIG,
    R.ACCEL_CONFIG,
    R.FIFO_EN,
    R.INT_ENABLE,
    R.SIGNAL_PATH_RESET,
    R.USER_CTRL,
    R.PWR_MGMT_1,
    R.PWR_MGMT_2,
}


class ResetInProgress(OSError):
    pass


class Mpu6050Sim(FilteredChip):
    def __init__(self, settings: SimSettings, clock: Clock) -> None:
        super().__init__(settings, clock, FIGURES)
        self.fifo_bytes_dropped = 0
        self._power_on_reset()

    # --- chip state -----------------------------------------------------------------------
    def _power_on_reset(self) -> None:
        self.regs = bytearray(128)
        self.regs[R.PWR_MGMT_1] = PwrMgmt1.SLEEP
        self.regs[R.WHO_AM_I] = WHO_AM_I_VALUE
        self.fifo = bytearray()
        self.last_fifo_byte = 0
        self.int_status = 0
        self.sampling = False
        self.busy_until_ns = 0
        self.latest_accel = np.zeros(3, dtype=np.int32)
        self.latest_gyro = np.zeros(3, dtype=np.int32)
        self.latest_temp_raw = 0
        self._data_regs: bytes | None = bytes(14)  # ACCEL_XOUT_H .. GYRO_ZOUT_L
        self._accel_hold: tuple[int, np.ndarray] | None = None
        self._anchor(self.clock.now_ns())

    @property
    def dlpf_cfg(self) -> int:
        return self.regs[R.CONFIG] & 0x07

    @property
    def internal_hz(self) -> float:
        return 8000.0 if self.dlpf_cfg in (0, 7) else 1000.0

    @property
    def rate_hz(self) -> float:
        """True output rate: nominal internal/(1+div), off by the oscillator error."""
        return self.internal_hz / (1 + self.regs[R.SMPLRT_DIV]) * (1 + self.clock_error)

    _filter_cache: tuple[tuple[int, int], tuple[SensorFilter, SensorFilter]] | None = None

    def filters(self) -> tuple[SensorFilter, SensorFilter]:
        """The DLPF of DLPF_CFG (register 26 table, docs/chips/mpu6050.md): the gyro's at its
        internal rate (8 kHz with the DLPF off, 1 kHz on), the accel's at 1 kHz; the table's
        bandwidth taken as the noise bandwidth (the sheet's 0.05 deg/s RMS at DLPF_CFG 2 is
        0.005 deg/s/rtHz * sqrt(100 Hz)). With the DLPF off the accel is unfiltered 1 kHz
        (delay 0) and held over 8 gyro samples."""
        key = (self.dlpf_cfg, self.regs[R.SMPLRT_DIV])
        if self._filter_cache is None or self._filter_cache[0] != key:
            cfg = key[0] if key[0] < 7 else 0
            m = 1 + key[1]
            gbw, gdelay = GYRO_DLPF_HZ[cfg], GYRO_DLPF_DELAY_S[cfg]
            abw, adelay = ACCEL_DLPF_HZ[cfg], ACCEL_DLPF_DELAY_S[cfg]
            internal = self.internal_hz
            gyro = design(gbw, gdelay, internal, m)
            if internal == 8000.0:  # accel at 1 kHz, held: white over its own 500 Hz band
                accel = design(abw, adelay, internal, m, white_band_hz=500.0)
            else:
                accel = design(abw, adelay, internal, m)
            self._filter_cache = (key, (accel, gyro))
        return self._filter_cache[1]

    @property
    def accel_lsb(self) -> float:
        """m/s^2 per count: the ADC spans +-full scale over 2^16 counts."""
        full_scale_g = ACCEL_RANGES_G[(self.regs[R.ACCEL_CONFIG] >> 3) & 3]
        return 2 * full_scale_g * G / 65536

    @property
    def gyro_lsb(self) -> float:
        """rad/s per count."""
        full_scale_dps = GYRO_RANGES_DPS[(self.regs[R.GYRO_CONFIG] >> 3) & 3]
        return 2 * full_scale_dps * (np.pi / 180) / 65536

    # --- sampling -------------------------------------------------------------------------
    def _emit(self, t_ns: np.ndarray, fm: np.ndarray, wm: np.ndarray, temp: np.ndarray) -> None:
        self._emit_rows(self._encode_rows(t_ns, fm, wm, temp), 0, t_ns.shape[0])

    def _encode(self, m: Measured) -> Encoded:
        return self._encode_rows(m.t_ns, m.accel, m.gyro, m.temp_c)

    def _encode_rows(
        self, t_ns: np.ndarray, fm: np.ndarray, wm: np.ndarray, temp: np.ndarray
    ) -> Encoded:
        """Counts for the data registers and the FIFO's bytes per sample, as FIFO_EN selects
        them (accel, temperature, then each gyro axis enabled: big-endian words)."""
        if self.internal_hz == 8000.0:
            fm = self._hold_accel_1khz(t_ns, fm)
        acc = quantise(fm, self.accel_lsb)
        gyr = quantise(wm, self.gyro_lsb)
        temp_raw = np.rint((temp - 36.53) * 340.0).astype(np.int32)
        enc: Encoded = {"acc": acc, "gyr": gyr, "temp": temp_raw}
        en = self.regs[R.FIFO_EN]
        cols: list[np.ndarray] = []
        if en & _EN_ACCEL:
            cols.append(acc)
        if en & _EN_TEMP:
            cols.append(temp_raw[:, None])
        for bit, axis in _EN_GYRO:
            if en & bit:
                cols.append(gyr[:, axis : axis + 1])
        if cols:
            words = np.concatenate(cols, axis=1).astype(">i2")
            enc["fifo"] = words.view(np.uint8).reshape(words.shape[0], -1)
        return enc

    def _emit_rows(self, enc: Encoded, i: int, j: int) -> None:
        self.latest_accel, self.latest_gyro = enc["acc"][j - 1], enc["gyr"][j - 1]
        self.latest_temp_raw = int(enc["temp"][j - 1])
        self._data_regs = None  # rebuilt when next read
        self.int_status |= _DATA_RDY
        rows = enc.get("fifo")
        if rows is not None and self.regs[R.USER_CTRL] & _FIFO_ON:
            self._push_fifo(rows[i:j].tobytes())

    def _hold_accel_1khz(self, t_ns: np.ndarray, fm: np.ndarray) -> np.ndarray:
        """With the DLPF off the gyro runs at 8 kHz but the accel at 1 kHz: hold accel values."""
        period = 1e6 / (1 + self.clock_error)
        idx = np.floor((t_ns - self.grid_origin_ns) / period).astype(np.int64)
        first = np.ones(len(idx), dtype=bool)
        first[1:] = idx[1:] != idx[:-1]
        if self._accel_hold is not None and idx[0] == self._accel_hold[0]:
            first[0] = False
            fm[0] = self._accel_hold[1]
        pos = np.maximum.accumulate(np.where(first, np.arange(len(idx)), 0))
        out = fm[pos]
        self._accel_hold = (int(idx[-1]), out[-1].copy())
        return out

    def _push_fifo(self, data: bytes) -> None:
        self.fifo += data
        excess = len(self.fifo) - FIFO_SIZE
        if excess > 0:  # the MPU6050 overwrites its oldest bytes and flags the overflow
            del self.fifo[:excess]
            self.fifo_bytes_dropped += excess
            self.int_status |= _OFLOW

    # --- bus side ---------------------------------------------------------------------------
    def _check_busy(self) -> None:
        if self.clock.now_ns() < self.busy_until_ns:
            raise ResetInProgress(121, "Remote I/O error (MPU6050 resetting)")

    def read(self, register: int, length: int) -> bytes:
        self._check_busy()
        self.advance()
        if register == R.FIFO_R_W:
            out = bytearray(self.fifo[:length])
            del self.fifo[:length]
            if out:
                self.last_fifo_byte = out[-1]
            out += bytes([self.last_fifo_byte]) * (length - len(out))
            return bytes(out)
        image = bytearray(self.regs)
        image[R.INT_STATUS] = self.int_status
        if self._data_regs is None:  # at most once per chunk of samples, only when read
            self._data_regs = (
                np.concatenate([self.latest_accel, [self.latest_temp_raw], self.latest_gyro])
                .astype(">i2")
                .tobytes()
            )
        image[R.ACCEL_XOUT_H : R.GYRO_XOUT_H + 6] = self._data_regs
        image[R.FIFO_COUNT_H : R.FIFO_COUNT_H + 2] = len(self.fifo).to_bytes(2, "big")
        end = min(register + length, len(image))
        if register <= R.INT_STATUS < end:
            self.int_status = 0  # INT_STATUS clears on read
        if register <= R.WHO_AM_I < end:
            image[R.WHO_AM_I] = self.identity(image[R.WHO_AM_I])
        return bytes(image[register:end]) + bytes(register + length - end)

    def write(self, register: int, data: bytes) -> None:
        self._check_busy()  # unlike the shared path, this chip NAKs while resetting
        self.advance()
        for i, value in enumerate(data):
            self._write_one(register + i, value)

    def power_on_reset(self) -> None:
        """A brown-out: as DEVICE_RESET (defaults, asleep, FIFO empty and off, busy)."""
        self._write_one(R.PWR_MGMT_1, PwrMgmt1.DEVICE_RESET)

    def _write_one(self, reg: int, value: int) -> None:
        if reg not in _WRITABLE:
            return  # read-only or reserved: silicon ignores it
        now = self.clock.now_ns()
        if reg == R.PWR_MGMT_1:
            if value & PwrMgmt1.DEVICE_RESET:
                self._power_on_reset()
                self.busy_until_ns = now + RESET_BUSY_NS
                return
            was_active = self.sampling
            self.regs[reg] = value
            self.sampling = not value & PwrMgmt1.SLEEP
            if self.sampling and not was_active:
                self._anchor(now)
            return
        if reg == R.USER_CTRL:
            if value & UserCtrl.FIFO_RESET:
                self.fifo.clear()
            self.regs[reg] = value & ~int(UserCtrl.FIFO_RESET | 0x03)  # reset bits self-clear
            return
        old = self.regs[reg]
        self.regs[reg] = value
        if reg in (R.SMPLRT_DIV, R.CONFIG) and old != value:
            self._anchor(now)
