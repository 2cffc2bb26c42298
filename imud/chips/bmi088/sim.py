"""Register-level BMI088 simulator: two dies, each on its own oscillator, one physical body.

Accel die: starts in I2C mode and suspended; a first SPI access only switches it to SPI (its
answer is garbage), and every SPI read clocks out one dummy byte first; soft reset (1 ms busy)
and FIFO flush through 0x7E; power registers need 5 ms before the next write takes; 1024-byte
framed FIFO (7-byte accel frames, a skip frame counting frames an overflow overwrote in stream
mode, a sensortime frame and 0x80 over-read bytes past the end); the 24-bit sensortime counter;
the temperature register. Gyro die: soft reset (30 ms busy), range and bandwidth/ODR, 100-frame
FIFO in bypass / FIFO (stop when full) / stream mode with the overrun bit.

Modelled behaviour beyond the facts sheet, stated so it can be checked against silicon: writes
to unknown or read-only registers and out-of-range codes are ignored (the chip keeps the old
value); a partially read FIFO frame stays in the FIFO; the temperature register updates every
1.28 s; the gyro's FIFO_CONFIG_1 write clears overrun but keeps the frames.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from imud.chips.bmi088 import registers as R
from imud.chips.bmi088.noise import (
    ACCEL_NOISE_UG_RTHZ,
    GYRO_NOISE_DPS_RTHZ,
    accel_bandwidth_hz,
    gyro_bandwidth_hz,
)
from imud.chips.bmi088.registers import AccelRegister as A
from imud.chips.bmi088.registers import GyroRegister as G
from imud.clock import Clock
from imud.sim.api import SimDie, Truth
from imud.sim.chip import Encoded, Measured
from imud.sim.filters import FilteredChip, SensorFilter, enbw_fir
from imud.sim.physics import ChipFigures, ErrorModel, quantise
from imud.sim.settings import SimSettings
from imud.units import STANDARD_GRAVITY as GRAVITY

# Noise densities (imud/chips/bmi088/noise.py, shared with the ROS 2 covariances) and gyro bias
# stability from the datasheet (docs/chips/bmi088.md); the other spreads are typical turn-on
# figures of this chip class, moderated
FIGURES = ChipFigures(
    accel_noise_ug_rthz=ACCEL_NOISE_UG_RTHZ,
    gyro_noise_dps_rthz=GYRO_NOISE_DPS_RTHZ,
    accel_bias_mg=20.0,
    gyro_bias_dps=0.5,
    accel_bias_instability_ug=40.0,
    gyro_bias_instability_dph=2.0,
    scale_error=0.005,
    misalignment_deg=0.3,
    accel_temp_drift_mg_per_c=0.2,
    gyro_temp_drift_dps_per_c=0.015,
)

# plain ints on the hot path: an operator on an IntFlag builds a new enum member each time
_ACC_EN = int(R.AccFifoConfig1.ACC_EN)
_STOP_WHEN_FULL = int(R.AccFifoConfig0.FIFO_MODE)
_HDR_ACCEL = int(R.AccFifoHeader.ACCEL)
ACC_RESET_BUSY_NS = 1_000_000
GYR_RESET_BUSY_NS = 30_000_000
POWER_SETTLE_NS = 5_000_000
TEMP_UPDATE_NS = 1_280_000_000
ACC_FRAMES_MAX = R.ACC_FIFO_BYTES // R.ACC_FRAME_BYTES  # 146 frames; with a skip frame, 1024 bytes
ACC_ODR_BY_CODE = {code: hz for hz, code in R.ACCEL_ODR_CODES.items()}
GYRO_FIFO_BYTES = R.GYRO_FIFO_FRAMES * R.GYRO_FRAME_BYTES


def _unfiltered(
    rate_hz: float, pre: npt.NDArray[np.float64] | None = None, band_hz: float | None = None
) -> SensorFilter:
    """No modelled delay (the filters' is not published), the output grid as the internal
    one; `pre` colours the noise, `band_hz` is the white noise's band (default rate / 2)."""
    return SensorFilter(0.0, rate_hz, np.ones(1), 1, band_hz, pre)


_ACC_DEFAULTS = {
    A.ACC_CHIP_ID: R.ACC_CHIP_ID_VALUE, A.ACC_CONF: 0xA8, A.ACC_RANGE: 0x01,
    A.FIFO_CONFIG_0: 0x02, A.FIFO_CONFIG_1: 0x10, A.ACC_PWR_CONF: 0x03,
    A.ACC_PWR_CTRL: 0x00, A.FIFO_DOWNS: 0x80, A.FIFO_WTM_0: 0x88, A.FIFO_WTM_1: 0x02,
}  # fmt: skip
_ACC_WRITABLE = {A.ACC_CONF, A.ACC_RANGE, A.FIFO_DOWNS, A.FIFO_WTM_0, A.FIFO_WTM_1,
                 A.FIFO_CONFIG_0, A.FIFO_CONFIG_1, A.INT1_IO_CONF, A.INT2_IO_CONF,
                 A.INT1_INT2_MAP_DATA, A.ACC_PWR_CONF, A.ACC_PWR_CTRL}  # fmt: skip
_GYR_DEFAULTS = {G.GYRO_CHIP_ID: R.GYRO_CHIP_ID_VALUE, G.GYRO_BANDWIDTH: 0x80}
_GYR_WRITABLE = {G.GYRO_RANGE, G.GYRO_BANDWIDTH, G.GYRO_LPM1, G.GYRO_INT_CTRL,
                 G.INT3_INT4_IO_CONF, G.INT3_INT4_IO_MAP, G.FIFO_WM_ENABLE,
                 G.FIFO_CONFIG_0, G.FIFO_CONFIG_1}  # fmt: skip


def temperature_bytes(temp_c: float) -> tuple[int, int]:
    """TEMP_MSB, TEMP_LSB for a temperature: 11-bit two's complement, 0.125 C/LSB, 0 at 23 C."""
    # TEMP_MSB 0x80 (-1024 ... -1017) means invalid: the lowest reading is -1016 (TEMP_MSB 0x81)
    s11 = max(-1016, min(1023, round((temp_c - 23.0) / 0.125)))
    u11 = s11 & 0x7FF
    return u11 >> 3, (u11 & 0x7) << 5


class Bmi088AccelSim(FilteredChip):
    def __init__(self, settings: SimSettings, clock: Clock) -> None:
        super().__init__(settings, clock, FIGURES)
        self.frames_dropped = 0
        self._power_on_reset()

    def _power_on_reset(self) -> None:
        self.regs = bytearray(128)
        for reg, val in _ACC_DEFAULTS.items():
            self.regs[reg] = val
        self.spi_mode = False
        self.fifo = bytearray()
        self.skipped = 0
        self.sampling = False
        self.busy_until_ns = 0
        self.settle_until_ns = 0
        self.latest = np.zeros(3, dtype=np.int32)
        self.drdy = False
        now_s = (self.clock.now_ns() - self.t_origin_ns) / 1e9
        self.temp_reg = temperature_bytes(float(self.temp.at(np.array([now_s]))[0]))
        self.temp_next_ns = self.clock.now_ns() + TEMP_UPDATE_NS
        self._anchor(self.clock.now_ns())

    def spi_select(self) -> bool:
        """A chip-select edge: the first one after power-on or reset only switches to SPI."""
        if self.spi_mode:
            return True
        self.spi_mode = True
        return False

    @property
    def rate_hz(self) -> float:
        return ACC_ODR_BY_CODE.get(self.regs[A.ACC_CONF] & 0x0F, 100.0) * (1 + self.clock_error)

    def filters(self) -> tuple[SensorFilter, SensorFilter]:
        """White one-sided noise up to the output's Nyquist (noise.py): the accel's bandwidth
        per ODR and oversampling mode was not retrieved (docs/chips/bmi088.md), nor any
        delay."""
        odr = ACC_ODR_BY_CODE.get(self.regs[A.ACC_CONF] & 0x0F, 100.0)
        return _unfiltered(odr, band_hz=accel_bandwidth_hz(odr)), _unfiltered(odr)

    def _emit(
        self,
        t_ns: npt.NDArray[np.int64],
        fm: npt.NDArray[np.float64],
        wm: npt.NDArray[np.float64],
        temp: npt.NDArray[np.float64],
    ) -> None:
        self._emit_rows(self._encode_rows(t_ns, fm, temp), 0, t_ns.shape[0])

    def _encode(self, m: Measured) -> Encoded:
        return self._encode_rows(m.t_ns, m.accel, m.temp_c)

    def _encode_rows(
        self,
        t_ns: npt.NDArray[np.int64],
        fm: npt.NDArray[np.float64],
        temp: npt.NDArray[np.float64],
    ) -> Encoded:
        """Counts and the FIFO's 7-byte accel frames (header, then X, Y, Z little-endian)."""
        # full scale doubles from 3 g with each ACC_RANGE step; +-full scale spans 2^16 counts
        full_scale_g = 1.5 * 2 ** ((self.regs[A.ACC_RANGE] & 3) + 1)
        acc = quantise(fm, 2 * full_scale_g * GRAVITY / 65536)
        n = acc.shape[0]
        frames = np.empty((n, 7), dtype=np.uint8)
        frames[:, 0] = _HDR_ACCEL
        frames[:, 1:] = acc.astype("<i2").view(np.uint8).reshape(n, 6)
        return {"acc": acc, "frames": frames, "t": t_ns, "temp": temp}

    def _emit_rows(self, enc: Encoded, i: int, j: int) -> None:
        self.latest = enc["acc"][j - 1]
        self.drdy = True
        t_last = int(enc["t"][j - 1])
        if t_last >= self.temp_next_ns:
            self.temp_reg = temperature_bytes(float(enc["temp"][j - 1]))
            self.temp_next_ns += TEMP_UPDATE_NS * max(
                1, math.ceil((t_last - self.temp_next_ns) / TEMP_UPDATE_NS)
            )
        if not self.regs[A.FIFO_CONFIG_1] & _ACC_EN:
            return
        n = j - i
        room = ACC_FRAMES_MAX - len(self.fifo) // 7
        if self.regs[A.FIFO_CONFIG_0] & _STOP_WHEN_FULL:  # stop when full
            self.fifo += enc["frames"][i : i + max(0, min(n, room))].tobytes()
            self.frames_dropped += max(0, n - room)
            return
        self.fifo += enc["frames"][i:j].tobytes()  # stream mode: the oldest frames make room
        excess = len(self.fifo) // 7 - ACC_FRAMES_MAX
        if excess > 0:
            del self.fifo[: 7 * excess]
            self.skipped += excess
            self.frames_dropped += excess

    def _sensortime(self) -> int:
        chip_ns = (self.clock.now_ns() - self.t_origin_ns) * (1 + self.clock_error)
        return int(chip_ns / (R.SENSORTIME_S_PER_LSB * 1e9)) & 0xFFFFFF

    def _fifo_read(self, length: int) -> bytes:
        out = bytearray()
        if self.skipped and length >= 2:
            out += bytes([R.AccFifoHeader.SKIP, min(self.skipped, 0xFF)])
            self.skipped = 0
        whole = min(len(self.fifo), (length - len(out)) // 7 * 7)
        out += self.fifo[:whole]
        del self.fifo[:whole]
        rest = length - len(out)
        if self.fifo:  # a frame cut short by the read length stays for the next read
            out += self.fifo[:rest]
        elif rest >= 4:
            st = self._sensortime()
            out += bytes([R.AccFifoHeader.SENSORTIME, st & 0xFF, st >> 8 & 0xFF, st >> 16])
        return bytes(out.ljust(length, bytes([R.AccFifoHeader.OVER_READ])))

    def read(self, register: int, length: int) -> bytes:
        if self.clock.now_ns() < self.busy_until_ns:
            return bytes(length)
        self.advance()
        if register == A.FIFO_DATA:
            return self._fifo_read(length)
        image = bytearray(self.regs)
        image[A.ACC_STATUS] = R.AccStatus.ACC_DRDY if self.drdy else 0
        image[A.ACC_X_LSB : A.ACC_X_LSB + 6] = self.latest.astype("<i2").tobytes()
        st = self._sensortime()
        image[A.SENSORTIME_0 : A.SENSORTIME_0 + 3] = st.to_bytes(3, "little")
        image[A.TEMP_MSB], image[A.TEMP_MSB + 1] = self.temp_reg
        size = len(self.fifo) + (2 if self.skipped else 0)
        image[A.FIFO_LENGTH_0 : A.FIFO_LENGTH_0 + 2] = size.to_bytes(2, "little")
        end = min(register + length, len(image))
        if register <= A.ACC_CHIP_ID < end:
            image[A.ACC_CHIP_ID] = self.identity(image[A.ACC_CHIP_ID])
        if register <= A.ACC_STATUS < end:
            self.drdy = False
        return bytes(image[register:end]) + bytes(register + length - end)

    def power_on_reset(self) -> None:
        """A brown-out: as a soft reset (defaults, suspended, I2C mode, FIFO empty, busy)."""
        self._write_one(A.ACC_SOFTRESET, R.SOFTRESET_CMD)

    def _write_one(self, reg: int, value: int) -> None:
        now = self.clock.now_ns()
        if reg == A.ACC_SOFTRESET:
            if value == R.SOFTRESET_CMD:
                self._power_on_reset()
                self.busy_until_ns = now + ACC_RESET_BUSY_NS
            elif value == R.ACC_FIFO_FLUSH_CMD:
                self.fifo.clear()
                self.skipped = 0
            return
        if reg not in _ACC_WRITABLE or now < self.settle_until_ns:
            return
        if reg == A.ACC_CONF and (value & 0x0F) not in ACC_ODR_BY_CODE:
            return  # an invalid ODR code: the chip flags an error and keeps its setting
        if reg == A.ACC_PWR_CONF and value not in (0x00, 0x03):
            return
        if reg == A.ACC_PWR_CTRL and value not in (0x00, 0x04):
            return
        old = self.regs[reg]
        must_be_one = R.AccFifoConfig0.MUST_BE_ONE if reg == A.FIFO_CONFIG_0 else 0
        self.regs[reg] = value | must_be_one
        if reg in (A.ACC_PWR_CONF, A.ACC_PWR_CTRL) and old != value:
            self.settle_until_ns = now + POWER_SETTLE_NS
            on = self.regs[A.ACC_PWR_CTRL] == 0x04 and self.regs[A.ACC_PWR_CONF] == 0x00
            if on and not self.sampling:
                self._anchor(now)
            self.sampling = on
        elif reg == A.ACC_CONF and (old ^ value) & 0x0F:
            self._anchor(now)


class Bmi088GyroSim(FilteredChip):
    def __init__(self, settings: SimSettings, clock: Clock, t_origin_ns: int) -> None:
        super().__init__(settings, clock, FIGURES)
        self.t_origin_ns = t_origin_ns  # one body: the same physics time as the accel die
        self.errors = ErrorModel(FIGURES, settings, stream=1)  # its own oscillator and noise
        self.clock_error = self.errors.clock_error
        self.frames_dropped = 0
        self._power_on_reset(busy_ns=0)

    def _power_on_reset(self, busy_ns: int) -> None:
        self.regs = bytearray(128)
        for reg, val in _GYR_DEFAULTS.items():
            self.regs[reg] = val
        self.fifo = bytearray()
        self.overrun = False
        self.latest = np.zeros(3, dtype=np.int32)
        now = self.clock.now_ns()
        self.busy_until_ns = now + busy_ns
        self.sampling = True  # normal mode out of reset
        self._anchor(now + busy_ns)

    @property
    def rate_hz(self) -> float:
        odr, _ = R.GYRO_BANDWIDTH_CODES[self.regs[G.GYRO_BANDWIDTH] & 0x07]
        return odr * (1 + self.clock_error)

    _filter_cache: tuple[int, tuple[SensorFilter, SensorFilter]] | None = None

    def filters(self) -> tuple[SensorFilter, SensorFilter]:
        """The gyro's noise coloured to 1.22 x the code's filter bandwidth (Bosch, noise.py);
        no delay (not published). The accel of this die is not output."""
        code = self.regs[G.GYRO_BANDWIDTH] & 0x07
        if self._filter_cache is None or self._filter_cache[0] != code:
            odr, bw = R.GYRO_BANDWIDTH_CODES[code]
            gyro = _unfiltered(odr, enbw_fir(gyro_bandwidth_hz(bw), odr))
            self._filter_cache = (code, (_unfiltered(odr), gyro))
        return self._filter_cache[1]

    def _emit(
        self,
        t_ns: npt.NDArray[np.int64],
        fm: npt.NDArray[np.float64],
        wm: npt.NDArray[np.float64],
        temp: npt.NDArray[np.float64],
    ) -> None:
        self._emit_rows(self._encode_rows(wm), 0, t_ns.shape[0])

    def _encode(self, m: Measured) -> Encoded:
        return self._encode_rows(m.gyro)

    def _encode_rows(self, wm: npt.NDArray[np.float64]) -> Encoded:
        """Counts and the FIFO's 6-byte frames (X, Y, Z little-endian)."""
        full_scale_dps = 2000 / 2 ** self.regs[G.GYRO_RANGE]  # halves with each code from 0
        gyr = quantise(wm, 2 * full_scale_dps * math.pi / 180 / 65536)
        frames = gyr.astype("<i2").view(np.uint8).reshape(gyr.shape[0], R.GYRO_FRAME_BYTES)
        return {"gyr": gyr, "frames": frames}

    def _emit_rows(self, enc: Encoded, i: int, j: int) -> None:
        self.latest = enc["gyr"][j - 1]
        mode = self.regs[G.FIFO_CONFIG_1] >> 6
        if mode == 0:
            return
        frames = enc["frames"][i:j].tobytes()
        room = GYRO_FIFO_BYTES - len(self.fifo)
        if len(frames) > room:
            self.overrun = True
            self.frames_dropped += (len(frames) - room) // R.GYRO_FRAME_BYTES
        if mode == 1:  # FIFO mode: stop when full
            self.fifo += frames[:room]
        else:  # stream: the oldest frames make room
            self.fifo += frames
            del self.fifo[: max(0, len(self.fifo) - GYRO_FIFO_BYTES)]

    def read(self, register: int, length: int) -> bytes:
        if self.clock.now_ns() < self.busy_until_ns:
            return bytes(length)
        self.advance()
        if register == G.FIFO_DATA:
            whole = min(len(self.fifo), length // R.GYRO_FRAME_BYTES * R.GYRO_FRAME_BYTES)
            out = bytes(self.fifo[:whole])
            del self.fifo[:whole]
            return out.ljust(length, b"\0")
        image = bytearray(self.regs)
        image[G.RATE_X_LSB : G.RATE_X_LSB + 6] = self.latest.astype("<i2").tobytes()
        overrun = R.GyroFifoStatus.OVERRUN if self.overrun else 0
        image[G.FIFO_STATUS] = overrun | len(self.fifo) // R.GYRO_FRAME_BYTES
        end = min(register + length, len(image))
        if register <= G.GYRO_CHIP_ID < end:
            image[G.GYRO_CHIP_ID] = self.identity(image[G.GYRO_CHIP_ID])
        return bytes(image[register:end]) + bytes(register + length - end)

    def power_on_reset(self) -> None:
        """A brown-out: as a soft reset (defaults, FIFO in bypass, busy 30 ms)."""
        self._power_on_reset(GYR_RESET_BUSY_NS)

    def _write_one(self, reg: int, value: int) -> None:
        if reg == G.GYRO_SOFTRESET:
            if value == R.SOFTRESET_CMD:
                self._power_on_reset(GYR_RESET_BUSY_NS)
            return
        if reg not in _GYR_WRITABLE:
            return
        if reg == G.GYRO_RANGE and value > 4:
            return
        if reg == G.GYRO_LPM1 and value not in (0x00, 0x20, 0x80):
            return
        if reg == G.GYRO_BANDWIDTH:
            value = 0x80 | (value & 0x0F)
            if value & 0x0F > 7:
                return
            if value != self.regs[reg]:
                self._anchor(self.clock.now_ns())
        self.regs[reg] = value
        if reg == G.GYRO_LPM1:
            on = value == 0x00
            if on and not self.sampling:
                self._anchor(self.clock.now_ns())
            self.sampling = on
        elif reg == G.FIFO_CONFIG_0:  # writing the watermark empties the FIFO
            self.fifo.clear()
            self.overrun = False
        elif reg == G.FIFO_CONFIG_1:
            self.overrun = False


class Bmi088Sim:
    """Both dies of one BMI088, attached to the bus separately (`dies`: accel, gyro, as the
    spec's dies). Ground truth is taken at the gyro's sample instants, the published stream's."""

    def __init__(self, settings: SimSettings, clock: Clock) -> None:
        self.accel = Bmi088AccelSim(settings, clock)
        self.gyro = Bmi088GyroSim(settings, clock, self.accel.t_origin_ns)
        self.accel.record_truth = False

    @property
    def dies(self) -> Sequence[SimDie]:
        return (self.accel, self.gyro)

    def drain_truth(self) -> Truth | None:
        return self.gyro.drain_truth()
