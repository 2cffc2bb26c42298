"""Register-level ICM-42688-P simulator: banked registers, soft reset, low-noise power modes with
start-up times, 2 kB FIFO in bypass / stream / stop-on-full mode with packets 1-4, the FIFO
timestamp counter on the chip's own clock, and the 'first count after a flush reads 0' quirk.

Modelled behaviour beyond the facts sheet (docs/chips/icm42688p.md), stated so it can be
checked against silicon: the accel/gyro rate is the gyro's ODR (imud always sets both alike); in
stream mode the oldest whole packets make room; reading an empty FIFO returns 0x80 bytes (the
'FIFO empty' header); while resetting, reads return zeros; a saturated reading stops one count
above the invalid marker, and the int8 FIFO temperature at -127.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from imud.chips.icm42688p import registers as R
from imud.chips.icm42688p.noise import ACCEL_NOISE_UG_RTHZ, GYRO_NOISE_DPS_RTHZ, ui_bandwidth_hz
from imud.chips.icm42688p.registers import Bank0 as B0
from imud.chips.icm42688p.registers import Bank1 as B1
from imud.chips.icm42688p.registers import Bank2 as B2
from imud.clock import Clock
from imud.sim.chip import Encoded, Measured
from imud.sim.filters import FilteredChip, SensorFilter, enbw_fir
from imud.sim.physics import ChipFigures, quantise
from imud.sim.settings import SimSettings
from imud.units import STANDARD_GRAVITY as G

# Noise densities from the datasheet (imud/chips/icm42688p/noise.py, shared with the ROS 2
# covariances); bias and drift sigmas are typical turn-on spreads of the chip class, moderated
FIGURES = ChipFigures(
    accel_noise_ug_rthz=ACCEL_NOISE_UG_RTHZ,
    gyro_noise_dps_rthz=GYRO_NOISE_DPS_RTHZ,
    accel_bias_mg=20.0,
    gyro_bias_dps=0.5,
    accel_bias_instability_ug=40.0,
    gyro_bias_instability_dph=2.5,
    scale_error=0.005,
    misalignment_deg=0.2,
    accel_temp_drift_mg_per_c=0.15,
    gyro_temp_drift_dps_per_c=0.005,
)

ACCEL_STARTUP_NS = 20_000_000
GYRO_STARTUP_NS = 30_000_000
RESET_BUSY_NS = 1_000_000
INVALID16 = -32768
# plain ints on the hot path: an operator on an IntFlag builds a new enum member each time
_DATA_RDY = int(R.IntStatus.DATA_RDY_INT)
_FIFO_FULL = int(R.IntStatus.FIFO_FULL_INT)
_HIRES = int(R.FifoConfig1.HIRES_EN)
_BOTH = int(R.FifoConfig1.ACCEL_EN | R.FifoConfig1.GYRO_EN)
_HDR = int(R.Header.ACCEL | R.Header.GYRO) | R.HEADER_TMST_FSYNC.bits(R.TMST_FSYNC_ODR)
_HDR_20 = int(R.Header.HIRES_20)
ODR_BY_CODE = {code: hz for hz, code in R.ODR_CODES.items()}

_BANK0_DEFAULTS = {
    B0.WHO_AM_I: R.WHO_AM_I_VALUE, B0.INTF_CONFIG0: 0x30, B0.INTF_CONFIG1: 0x91,
    B0.GYRO_CONFIG0: 0x06, B0.ACCEL_CONFIG0: 0x06, B0.GYRO_ACCEL_CONFIG0: 0x11,
    B0.TMST_CONFIG: 0x23, B0.DEVICE_CONFIG: 0x00,
}  # fmt: skip
_BANK1_DEFAULTS = {B1.GYRO_CONFIG_STATIC2: 0xA0, B1.GYRO_CONFIG_STATIC3: 0x0D,
                   B1.GYRO_CONFIG_STATIC4: 0xAA, B1.GYRO_CONFIG_STATIC5: 0x80}  # fmt: skip
_BANK2_DEFAULTS = {B2.ACCEL_CONFIG_STATIC2: 0x30, B2.ACCEL_CONFIG_STATIC3: 0x40,
                   B2.ACCEL_CONFIG_STATIC4: 0x62}  # fmt: skip
_READ_ONLY0 = {B0.WHO_AM_I, B0.INT_STATUS, B0.FIFO_COUNTH, B0.FIFO_COUNTL, B0.FIFO_DATA,
               *range(B0.TEMP_DATA1, B0.TEMP_DATA1 + 14)}  # fmt: skip


class Icm42688pSim(FilteredChip):
    spi_dummy_bytes = 0

    def __init__(self, settings: SimSettings, clock: Clock) -> None:
        super().__init__(settings, clock, FIGURES)
        self.packets_dropped = 0
        self._power_on_reset()

    # --- state ------------------------------------------------------------------------------
    def _power_on_reset(self) -> None:
        self.banks = [bytearray(128) for _ in range(5)]
        for bank, defaults in ((0, _BANK0_DEFAULTS), (1, _BANK1_DEFAULTS), (2, _BANK2_DEFAULTS)):
            for reg, val in defaults.items():
                self.banks[bank][reg] = val
        self.bank = 0
        self.fifo = bytearray()
        self.int_status = 0
        self.sampling = False
        self.busy_until_ns = 0
        self.on_since_ns = 0
        self.count_zero_once = False
        self.latest = np.zeros(6, dtype=np.int32)
        self.latest_temp = 0
        self._anchor(self.clock.now_ns())

    @property
    def regs(self) -> bytearray:
        return self.banks[0]

    @property
    def rate_hz(self) -> float:
        code = self.regs[B0.GYRO_CONFIG0] & 0x0F
        return ODR_BY_CODE.get(code, 1000.0) * (1 + self.clock_error)

    _filter_cache: tuple[tuple[int, int], tuple[SensorFilter, SensorFilter]] | None = None

    def filters(self) -> tuple[SensorFilter, SensorFilter]:
        """Each sensor's UI filter as a colouring of its noise: the code's bandwidth taken as
        the noise bandwidth (noise.py), one-sided density; a band above the output's Nyquist
        (a low rate) is the aliased band, white at its variance. Its group delay is in the
        datasheet's per-ODR tables (DS-000347 section 5.5), which were not retrieved: none is
        modelled (0), so the motion passes unfiltered."""
        key = (self.regs[B0.GYRO_CONFIG0] & 0x0F, self.regs[B0.GYRO_ACCEL_CONFIG0])
        if self._filter_cache is None or self._filter_cache[0] != key:
            odr = ODR_BY_CODE.get(key[0], 1000.0)

            def ui(code: int) -> SensorFilter:
                bw = ui_bandwidth_hz(code, odr)
                if bw >= odr / 2:
                    return SensorFilter(0.0, odr, np.ones(1), 1, bw)
                return SensorFilter(0.0, odr, np.ones(1), 1, None, enbw_fir(bw, odr))

            self._filter_cache = (key, (ui(key[1] >> 4), ui(key[1] & 0x0F)))
        return self._filter_cache[1]

    @property
    def hires(self) -> bool:
        return bool(self.regs[B0.FIFO_CONFIG1] & _HIRES)

    def _lsb(self, hires: bool) -> tuple[float, float]:
        """SI units per count: +-full scale spans 2^16 (2^20) counts; full scale halves with
        each FS_SEL step from 2000 deg/s and 16 g."""
        g_fs = 2000.0 / 2 ** (self.regs[B0.GYRO_CONFIG0] >> 5)
        a_fs = 16.0 / 2 ** ((self.regs[B0.ACCEL_CONFIG0] >> 5) & 3)
        if hires:  # only 2000 deg/s and 16 g are operational in 20-bit mode
            g_fs, a_fs = 2000.0, 16.0
        counts = 2.0 ** (20 if hires else 16)
        return 2 * a_fs * G / counts, 2 * g_fs * np.pi / 180 / counts

    # --- sampling ---------------------------------------------------------------------------
    def _emit(
        self,
        t_ns: npt.NDArray[np.int64],
        fm: npt.NDArray[np.float64],
        wm: npt.NDArray[np.float64],
        temp: npt.NDArray[np.float64],
    ) -> None:
        self._emit_rows(self._encode_rows(t_ns, fm, wm, temp), 0, t_ns.shape[0])

    def _encode(self, m: Measured) -> Encoded:
        return self._encode_rows(m.t_ns, m.accel, m.gyro, m.temp_c)

    def _encode_rows(
        self,
        t_ns: npt.NDArray[np.int64],
        fm: npt.NDArray[np.float64],
        wm: npt.NDArray[np.float64],
        temp: npt.NDArray[np.float64],
    ) -> Encoded:
        """The data registers' counts (accel then gyro, 16-bit) and temperature, and the FIFO
        packets when both sensors go to it."""
        hires = self.hires
        a_lsb, g_lsb = self._lsb(hires)
        bits = 20 if hires else 16
        # the most negative code is the invalid marker: a saturated reading stops one above it
        acc = quantise(fm, a_lsb, bits, symmetric=True)
        gyr = quantise(wm, g_lsb, bits, symmetric=True)
        if hires:
            acc &= ~0x3  # 18-bit effective accel: the low two bits read 0
        # sensors still starting up deliver the invalid marker
        on = t_ns - self.on_since_ns
        acc[on < ACCEL_STARTUP_NS] = -(2 ** (bits - 1))
        gyr[on < GYRO_STARTUP_NS] = -(2 ** (bits - 1))
        shift = 4 if hires else 0
        enc: Encoded = {"regs": np.concatenate([acc >> shift, gyr >> shift], axis=1),
               "temp": np.rint((temp - 25.0) * 132.48).astype(np.int32)}  # fmt: skip
        if self.regs[B0.FIFO_CONFIG1] & _BOTH == _BOTH:
            enc["packets"] = self._packets(t_ns, acc, gyr, temp, hires)
        return enc

    def _emit_rows(self, enc: Encoded, i: int, j: int) -> None:
        self.latest[:] = enc["regs"][j - 1]
        self.latest_temp = int(enc["temp"][j - 1])
        self.int_status |= _DATA_RDY
        mode = self.regs[B0.FIFO_CONFIG] >> 6
        packets = enc.get("packets")
        if mode and packets is not None:
            self._push(packets[i:j], mode)

    def _ticks(self, t_ns: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        """The FIFO timestamp: a free-running counter on the chip's own (imperfect) clock."""
        chip_ns = (t_ns - self.t_origin_ns) * (1 + self.clock_error)
        ticks: npt.NDArray[np.int64] = np.floor(chip_ns / R.TICK_NS).astype(np.int64) & 0xFFFF
        return ticks

    def _packets(
        self,
        t_ns: npt.NDArray[np.int64],
        acc: npt.NDArray[np.int32],
        gyr: npt.NDArray[np.int32],
        temp: npt.NDArray[np.float64],
        hires: bool,
    ) -> npt.NDArray[np.uint8]:
        n = t_ns.shape[0]
        size = R.PACKET4_BYTES if hires else R.PACKET3_BYTES
        out = np.zeros((n, size), dtype=np.uint8)
        out[:, 0] = _HDR | (_HDR_20 if hires else 0)
        hi_a, hi_g = (acc >> 4, gyr >> 4) if hires else (acc, gyr)
        be = np.concatenate([hi_a, hi_g], axis=1).astype(">i2").view(np.uint8).reshape(n, 12)
        out[:, 1:13] = be
        ticks = self._ticks(t_ns)
        if hires:
            t16 = np.rint((temp - 25.0) * 132.48).astype(">i2").view(np.uint8).reshape(n, 2)
            out[:, 13:15] = t16
            out[:, 15] = ticks >> 8
            out[:, 16] = ticks & 0xFF
            out[:, 17:20] = ((acc & 0xF) << 4 | (gyr & 0xF)).astype(np.uint8)
        else:
            out[:, 13] = (
                np.clip(np.rint((temp - 25.0) * 2.07), -127, 127).astype(np.int8).view(np.uint8)
            )
            out[:, 14] = ticks >> 8
            out[:, 15] = ticks & 0xFF
        return out

    def _push(self, packets: npt.NDArray[np.uint8], mode: int) -> None:
        size = packets.shape[1]
        room = (R.FIFO_SIZE - len(self.fifo)) // size
        if mode == 1:  # stream: the oldest whole packets make room
            self.fifo += packets.tobytes()
            excess = len(self.fifo) - R.FIFO_SIZE
            if excess > 0:
                drop = -(-excess // size) * size
                del self.fifo[:drop]
                self.packets_dropped += drop // size
                self.int_status |= _FIFO_FULL
            return
        keep = packets[:room]  # stop-on-full: what does not fit is dropped
        self.fifo += keep.tobytes()
        if len(packets) > room:
            self.packets_dropped += len(packets) - room
            self.int_status |= _FIFO_FULL

    def _room_for_due(self) -> bool:
        period = 1e9 / self.rate_hz
        due = (self.clock.now_ns() - self.grid_origin_ns) / period - self.next_k + 2
        size = R.PACKET4_BYTES if self.hires else R.PACKET3_BYTES
        return R.FIFO_SIZE - len(self.fifo) >= due * size

    # --- bus side ---------------------------------------------------------------------------
    def read(self, register: int, length: int) -> bytes:
        if self.clock.now_ns() < self.busy_until_ns:
            return bytes(length)
        if register != B0.FIFO_DATA or not self._room_for_due():
            # Samples due since the count read cannot be among the bytes a FIFO burst returns
            # (it reads at most what was counted), so while the FIFO has room for them their
            # generation can wait for the next access: same bytes, half the simulator's cost.
            self.advance()
        if register == B0.REG_BANK_SEL:
            return bytes([self.bank]) + bytes(length - 1)
        if self.bank != 0:
            return bytes(self.banks[self.bank][register : register + length]).ljust(length, b"\0")
        if register == B0.FIFO_DATA:
            out = bytes(self.fifo[:length])
            del self.fifo[:length]
            return out + b"\x80" * (length - len(out))
        image = bytearray(self.regs)
        image[B0.INT_STATUS] = self.int_status
        count = 0 if self.count_zero_once else len(self.fifo)
        if self.regs[B0.INTF_CONFIG0] & 0x40:  # FIFO_COUNT_REC: in packets
            count //= R.PACKET4_BYTES if self.hires else R.PACKET3_BYTES
        big = bool(self.regs[B0.INTF_CONFIG0] & 0x20)
        image[B0.FIFO_COUNTH : B0.FIFO_COUNTH + 2] = count.to_bytes(2, "big" if big else "little")
        data = np.concatenate([[self.latest_temp], self.latest]).astype(">i2").tobytes()
        image[B0.TEMP_DATA1 : B0.TEMP_DATA1 + 14] = data
        end = min(register + length, len(image))
        if register <= B0.INT_STATUS < end:
            self.int_status = 0  # clears on read
        if register <= B0.WHO_AM_I < end:
            image[B0.WHO_AM_I] = self.identity(image[B0.WHO_AM_I])
        if register <= B0.FIFO_COUNTH < end:
            self.count_zero_once = False
        return bytes(image[register:end]) + bytes(register + length - end)

    def power_on_reset(self) -> None:
        """A brown-out: as SOFT_RESET_CONFIG (defaults, sensors off, FIFO empty, busy)."""
        self.bank = 0  # DEVICE_CONFIG is in bank 0 (the reset selects bank 0 anyway)
        self._write_one(B0.DEVICE_CONFIG, int(R.DeviceConfig.SOFT_RESET_CONFIG))

    def _write_one(self, reg: int, value: int) -> None:
        now = self.clock.now_ns()
        if reg == B0.REG_BANK_SEL:
            self.bank = value & 0x07 if value & 0x07 <= 4 else self.bank
            return
        if self.bank != 0:
            self.banks[self.bank][reg] = value
            return
        if reg in _READ_ONLY0:
            return
        if reg == B0.DEVICE_CONFIG and value & R.DeviceConfig.SOFT_RESET_CONFIG:
            self._power_on_reset()
            self.busy_until_ns = now + RESET_BUSY_NS
            self.int_status = int(R.IntStatus.RESET_DONE_INT)
            return
        if reg == B0.SIGNAL_PATH_RESET:
            if value & R.SignalPathReset.FIFO_FLUSH:
                self.fifo.clear()
                self.count_zero_once = True
            return  # self-clearing bits
        old = self.regs[reg]
        self.regs[reg] = value
        if reg == B0.PWR_MGMT0:
            on = R.GYRO_MODE.get(value) == R.ACCEL_MODE.get(value) == R.MODE_LOW_NOISE
            if on and not self.sampling:
                self.on_since_ns = now
                self._anchor(now)
            self.sampling = on
        elif reg in (B0.GYRO_CONFIG0, B0.ACCEL_CONFIG0) and (old ^ value) & 0x0F:
            self._anchor(now)  # a new ODR restarts the sample grid
