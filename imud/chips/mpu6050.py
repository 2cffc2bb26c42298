"""InvenSense MPU6050 over I2C: register map, config model and FIFO driver.

Facts (register addresses, scale factors, FIFO layout, reset sequence) from the datasheet and
register map as summarised in docs/chips.md; the FIFO holds accel xyz then gyro xyz, big-endian
int16, 12 bytes a sample, no header, 1024 bytes deep.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
from pydantic import Field, ValidationInfo, field_validator

from imud.buses.registers import RegisterDevice
from imud.chips.base import (
    BusError,
    DeviceBase,
    DeviceIdentityError,
    DriverCounters,
    RawBatch,
)
from imud.chips.checks import RegisterChecker
from imud.clock import Clock

STANDARD_GRAVITY = 9.80665

# Register map
SMPLRT_DIV = 0x19
CONFIG = 0x1A
GYRO_CONFIG = 0x1B
ACCEL_CONFIG = 0x1C
FIFO_EN = 0x23
INT_ENABLE = 0x38
INT_STATUS = 0x3A
ACCEL_XOUT_H = 0x3B
TEMP_OUT_H = 0x41
GYRO_XOUT_H = 0x43
SIGNAL_PATH_RESET = 0x68
USER_CTRL = 0x6A
PWR_MGMT_1 = 0x6B
PWR_MGMT_2 = 0x6C
FIFO_COUNT_H = 0x72
FIFO_R_W = 0x74
WHO_AM_I = 0x75

WHO_AM_I_VALUE = 0x68
PWR1_DEVICE_RESET = 0x80
PWR1_SLEEP = 0x40
PWR1_CLKSEL_PLL_XGYRO = 0x01
USER_CTRL_FIFO_EN = 0x40
USER_CTRL_FIFO_RESET = 0x04
FIFO_EN_TEMP = 0x80
FIFO_EN_XG = 0x40
FIFO_EN_YG = 0x20
FIFO_EN_ZG = 0x10
FIFO_EN_ACCEL = 0x08
INT_FIFO_OFLOW = 0x10
INT_DATA_RDY = 0x01

FIFO_SIZE = 1024
SAMPLE_BYTES = 12  # accel xyz + gyro xyz
RESET_WAIT_NS = 100_000_000
WAKE_WAIT_NS = 10_000_000

GYRO_RANGES_DPS = (250, 500, 1000, 2000)
ACCEL_RANGES_G = (2, 4, 8, 16)
# DLPF_CFG 0..6 by gyro bandwidth in Hz; 256 is "filter off": the gyro then samples at 8 kHz
DLPF_BANDWIDTHS_HZ = (256, 188, 98, 42, 20, 10, 5)
MAX_ODR_HZ = 1000.0


def internal_rate_hz(dlpf_hz: int) -> float:
    return 8000.0 if dlpf_hz == 256 else 1000.0


def allowed_odrs_hz(dlpf_hz: int) -> list[float]:
    """Every rate internal/(1 + SMPLRT_DIV) that is at most 1 kHz."""
    base = internal_rate_hz(dlpf_hz)
    return [base / (1 + d) for d in range(256) if base / (1 + d) <= MAX_ODR_HZ + 1e-9]


def divider_for(odr_hz: float, dlpf_hz: int) -> int | None:
    base = internal_rate_hz(dlpf_hz)
    d = round(base / odr_hz - 1)
    if 0 <= d <= 255 and math.isclose(base / (1 + d), odr_hz, rel_tol=1e-4) and odr_hz <= 1000.0:
        return d
    return None


def _fmt_rates(rates: list[float]) -> str:
    return ", ".join(f"{r:.6g}" for r in rates)


class Mpu6050Config(DeviceBase):
    """An MPU6050. `dlpf_hz` is the gyro DLPF bandwidth (256 = off, gyro sampling at 8 kHz)."""

    chip: Literal["mpu6050"]
    gyro_range_dps: Literal[250, 500, 1000, 2000] = 500
    accel_range_g: Literal[2, 4, 8, 16] = 4
    dlpf_hz: Literal[256, 188, 98, 42, 20, 10, 5] = 188
    odr_hz: float = Field(
        1000.0, gt=0, strict=True, description="internal/(1+SMPLRT_DIV), at most 1 kHz"
    )

    @field_validator("odr_hz")
    @classmethod
    def _reachable(cls, v: float, info: ValidationInfo) -> float:
        dlpf = info.data.get("dlpf_hz")
        if dlpf is None:  # dlpf_hz itself failed; its own error says why
            return v
        if divider_for(v, dlpf) is None:
            rates = allowed_odrs_hz(dlpf)
            nearest = min(rates, key=lambda r: abs(r - v))
            base = internal_rate_hz(dlpf)
            raise ValueError(
                f"the MPU6050 cannot produce {v:g} Hz with dlpf_hz = {dlpf}: allowed are "
                f"{base:g}/(1+n) Hz up to 1000 Hz, i.e. {_fmt_rates(rates[:8])}, ... "
                f"{_fmt_rates(rates[-2:])}; nearest is {nearest:.6g}"
            )
        return v

    @property
    def smplrt_div(self) -> int:
        d = divider_for(self.odr_hz, self.dlpf_hz)
        assert d is not None  # guaranteed by validation
        return d


def accel_scale_ms2(range_g: int) -> float:
    return range_g * STANDARD_GRAVITY / 32768.0


def gyro_scale_rads(range_dps: int) -> float:
    return math.radians(range_dps) / 32768.0


def temperature_c(raw: int | npt.NDArray[np.int32]) -> Any:
    """TEMP_OUT counts to degrees Celsius: raw/340 + 36.53."""
    return np.asarray(raw, dtype=np.float64) / 340.0 + 36.53


def decode_fifo(data: bytes) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.int32]]:
    """Whole 12-byte FIFO sets (accel xyz, gyro xyz; big-endian int16) to (accel, gyro) counts."""
    n = len(data) // SAMPLE_BYTES
    words = np.frombuffer(data, dtype=">i2", count=n * 6).reshape(n, 6).astype(np.int32)
    return words[:, 0:3], words[:, 3:6]


def decode_status_block(block: bytes) -> tuple[int, int]:
    """INT_STATUS..TEMP_OUT_L (9 bytes from 0x3A) to (int_status, temperature counts)."""
    if len(block) != 9:
        raise BusError(0, f"status block: expected 9 bytes, got {len(block)}")
    return block[0], int.from_bytes(block[7:9], "big", signed=True)


_NONE = np.zeros((0, 3), dtype=np.int32)


class Mpu6050Driver:
    """FIFO-mode driver. Blocking; owned by its bus's worker thread."""

    fifo_capacity = FIFO_SIZE // SAMPLE_BYTES

    def __init__(self, cfg: Mpu6050Config, dev: RegisterDevice, clock: Clock) -> None:
        self.cfg = cfg
        self.dev = dev
        self.clock = clock
        self.counters = DriverCounters()
        self.nominal_period_ns = 1e9 / cfg.odr_hz
        # a quarter of the FIFO between polls keeps it under half full with +-5 % clock error
        self.poll_interval_ns = int(min(50e6, self.nominal_period_ns * self.fifo_capacity / 4))
        self.accel_scale = accel_scale_ms2(cfg.accel_range_g)
        self.gyro_scale = gyro_scale_rads(cfg.gyro_range_dps)
        self._checked = self._register_plan()
        self._checker = RegisterChecker(dev, self._checked, clock, self.counters)
        self._need_reset = False
        self._resync = False
        self._restart_ns: tuple[int, int] | None = None

    def _register_plan(self) -> list[tuple[int, int]]:
        c = self.cfg
        return [
            (PWR_MGMT_1, PWR1_CLKSEL_PLL_XGYRO),
            (SMPLRT_DIV, c.smplrt_div),
            (CONFIG, DLPF_BANDWIDTHS_HZ.index(c.dlpf_hz)),
            (GYRO_CONFIG, GYRO_RANGES_DPS.index(c.gyro_range_dps) << 3),
            (ACCEL_CONFIG, ACCEL_RANGES_G.index(c.accel_range_g) << 3),
            (INT_ENABLE, INT_FIFO_OFLOW),
            (FIFO_EN, FIFO_EN_XG | FIFO_EN_YG | FIFO_EN_ZG | FIFO_EN_ACCEL),
        ]

    def start(self) -> Iterator[int]:
        """Identity, reset, configure, FIFO on. Yields the waits (ns) so that the bus worker can
        serve the other devices on the bus during the 100 ms reset."""
        who = self.dev.read_u8(WHO_AM_I)
        if who != WHO_AM_I_VALUE:
            raise DeviceIdentityError(
                f"WHO_AM_I (0x{WHO_AM_I:02x}) at address 0x{self.dev.address:02x} reads "
                f"0x{who:02x}, expected 0x{WHO_AM_I_VALUE:02x} for an MPU6050: check the chip, "
                f"the address (AD0 low 0x68, high 0x69) and the wiring"
            )
        self.dev.write_u8(PWR_MGMT_1, PWR1_DEVICE_RESET)
        yield RESET_WAIT_NS
        pwr = self.dev.read_u8(PWR_MGMT_1)
        if pwr & PWR1_DEVICE_RESET:
            raise DeviceIdentityError(
                f"MPU6050 still in reset after 100 ms (PWR_MGMT_1=0x{pwr:02x})"
            )
        self.counters.resets += 1
        for reg, val in self._checked:
            if reg == FIFO_EN:
                continue
            self.dev.write_u8(reg, val)
            if reg == PWR_MGMT_1:
                yield WAKE_WAIT_NS
        for reg, val in self._checked:
            if reg == FIFO_EN:
                continue
            got = self.dev.read_u8(reg)
            if got != val:
                raise DeviceIdentityError(
                    f"register 0x{reg:02x} reads 0x{got:02x} after writing 0x{val:02x}"
                )
        self._fifo_restart()
        self._resync = False  # a fresh start: the runner rebases its sample clock anyway
        self._checker.restart()

    def _fifo_restart(self) -> None:
        """Stop the FIFO, empty it, re-enable accel+gyro: the Linux/PX4 recovery sequence.

        Samples are discarded from the first write on, so the next batch returned must say so
        (`resync`) even if this or a later transfer fails first."""
        self._resync = True
        self._need_reset = True
        self.dev.write_u8(FIFO_EN, 0)
        self.dev.write_u8(USER_CTRL, USER_CTRL_FIFO_RESET)
        self.dev.write_u8(FIFO_EN, FIFO_EN_XG | FIFO_EN_YG | FIFO_EN_ZG | FIFO_EN_ACCEL)
        t0 = self.clock.now_ns()
        self.dev.write_u8(USER_CTRL, USER_CTRL_FIFO_EN)
        self._restart_ns = (t0, self.clock.now_ns())
        self.dev.read_u8(INT_STATUS)  # clear a stale overflow flag
        self.counters.fifo_resets += 1
        self._need_reset = False

    def _batch(
        self,
        accel: npt.NDArray[np.int32],
        gyro: npt.NDArray[np.int32],
        temp: float,
        t_before: int,
        t_after: int,
    ) -> RawBatch:
        resync, self._resync = self._resync, False
        return RawBatch(
            accel,
            gyro,
            np.full(accel.shape[0], temp),
            self.accel_scale,
            self.gyro_scale,
            t_before,
            t_after,
            resync=resync,
            restart_ns=self._restart_ns if resync else None,
        )

    def read(self) -> RawBatch:
        if self._need_reset:
            self._fifo_restart()
        int_status, temp_raw = decode_status_block(self.dev.read(INT_STATUS, 9))
        temp = float(temperature_c(temp_raw))
        t_before = self.clock.now_ns()
        count = int.from_bytes(self.dev.read(FIFO_COUNT_H, 2), "big")
        t_after = self.clock.now_ns()
        # Overflow flag, or so close to full that the count->read race could wrap (Linux margin)
        if int_status & INT_FIFO_OFLOW or count > FIFO_SIZE - 3 * SAMPLE_BYTES:
            self.counters.fifo_overflows += 1
            self._fifo_restart()
            return self._batch(_NONE, _NONE, temp, t_before, t_after)
        n = count // SAMPLE_BYTES
        self._checker.check_next()
        if n == 0:
            return self._batch(_NONE, _NONE, temp, t_before, t_after)
        try:
            data = self.dev.read(FIFO_R_W, n * SAMPLE_BYTES)
        except BusError:
            # the burst may have stopped mid-sample: the FIFO is no longer aligned. (A failed
            # status or count read leaves the FIFO untouched and needs no reset.)
            self._need_reset = True
            raise
        accel, gyro = decode_fifo(data)
        return self._batch(accel, gyro, temp, t_before, t_after)

    def stop(self) -> None:
        try:
            self.dev.write_u8(USER_CTRL, 0)
            self.dev.write_u8(PWR_MGMT_1, PWR1_SLEEP)
        except BusError:
            pass
