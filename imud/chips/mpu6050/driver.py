"""MPU6050 FIFO driver: identity, reset, configuration as register masks, FIFO reads.

The FIFO holds accel xyz then gyro xyz, big-endian int16, 12 bytes a sample, no header, 1024 bytes
deep; it overwrites its oldest bytes when full and raises FIFO_OFLOW (docs/chips/mpu6050.md).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

from imud.buses.registers import RegisterDevice
from imud.channels import Channel
from imud.chips.api import DriverCounters, RawBatch, RawChannel
from imud.chips.bits import BitField
from imud.chips.fifotiming import FifoTiming, fifo_poll_interval_ns
from imud.chips.mpu6050 import registers as R
from imud.chips.mpu6050.config import Mpu6050Config
from imud.chips.regplan import RegisterChecker, RegisterPlan, RegisterSetting
from imud.clock import Clock
from imud.errors import BusError, DeviceIdentityError, ErrorKind, error_kind
from imud.units import STANDARD_GRAVITY

SAMPLE_BYTES = 12  # accel xyz + gyro xyz
FULL_SCALE = 32767  # |count| of a saturated int16 reading
FIFO_SENSORS = int(R.FifoEn.XG | R.FifoEn.YG | R.FifoEn.ZG | R.FifoEn.ACCEL)
_WHOLE = BitField(0xFF)
_OFLOW = int(R.IntStatus.FIFO_OFLOW_INT)  # an int: `&` with an IntFlag builds an enum member


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


def register_plan(c: Mpu6050Config) -> list[RegisterSetting]:
    """The configured registers, PWR_MGMT_1 (wake) first, the FIFO's own last."""
    fs = RegisterSetting.fields
    P1 = R.PwrMgmt1
    return [
        fs(
            R.Register.PWR_MGMT_1,
            (R.PWR1_CLKSEL, R.CLKSEL_PLL_XGYRO),
            clear_bits=P1.DEVICE_RESET | P1.SLEEP | P1.CYCLE | P1.TEMP_DIS,
        ),
        fs(R.Register.SMPLRT_DIV, (_WHOLE, c.smplrt_div)),
        fs(
            R.Register.CONFIG,
            (R.CONFIG_DLPF_CFG, R.DLPF_BANDWIDTHS_HZ.index(c.dlpf_hz)),
            (R.CONFIG_EXT_SYNC_SET, 0),
        ),
        fs(
            R.Register.GYRO_CONFIG,
            (R.GYRO_FS_SEL, R.GYRO_RANGES_DPS.index(c.gyro_range_dps)),
            clear_bits=R.SELF_TEST_BITS,
        ),
        fs(
            R.Register.ACCEL_CONFIG,
            (R.ACCEL_AFS_SEL, R.ACCEL_RANGES_G.index(c.accel_range_g)),
            clear_bits=R.SELF_TEST_BITS,
        ),
        RegisterSetting(R.Register.INT_ENABLE, set_bits=R.IntEnable.FIFO_OFLOW_EN),
        fs(R.Register.FIFO_EN, (_WHOLE, FIFO_SENSORS)),
        RegisterSetting(
            R.Register.USER_CTRL, set_bits=R.UserCtrl.FIFO_EN, clear_bits=R.UserCtrl.I2C_MST_EN
        ),
    ]


# The gyro DLPF's group delay per DLPF_CFG 0..6 (RM-MPU-6000A-00 rev 4.2, §4.3, register 26
# table; docs/chips/mpu6050.md). The simulator keeps its own copy of the table: it models the
# silicon, not this driver.
GYRO_DLPF_DELAY_S = (0.98e-3, 1.9e-3, 2.8e-3, 4.8e-3, 8.3e-3, 13.4e-3, 18.6e-3)


def group_delay_s(dlpf_hz: int) -> float:
    """The gyro's DLPF group delay at this bandwidth: what a stamp is moved back by (the
    accel's differs by at most 0.2 ms, except DLPF off: 0 ms against 0.98)."""
    return GYRO_DLPF_DELAY_S[R.DLPF_BANDWIDTHS_HZ.index(dlpf_hz)]


_NONE = np.zeros((0, 3), dtype=np.int32)
_FIFO_REGISTERS = (R.Register.FIFO_EN, R.Register.USER_CTRL)  # written by the FIFO restart
_ACTIONS = R.UserCtrl.FIFO_RESET | R.UserCtrl.I2C_MST_RESET | R.UserCtrl.SIG_COND_RESET


class Mpu6050Driver:
    """FIFO-mode driver. Blocking; owned by its bus's worker."""

    fifo_capacity = R.FIFO_SIZE // SAMPLE_BYTES

    def __init__(self, cfg: Mpu6050Config, dev: RegisterDevice, clock: Clock) -> None:
        self.cfg = cfg
        self.dev = dev
        self.clock = clock
        self.counters = DriverCounters()
        self.nominal_period_ns = 1e9 / cfg.odr_hz
        self.group_delay_ns = round(group_delay_s(cfg.dlpf_hz) * 1e9)
        # a quarter of the FIFO between polls: at a half, the first batch after a start (read
        # before any batch measured the chip's period) is stamped at the nominal one, up to
        # half a period off at its oldest (docs/performance.md section 19)
        self.poll_interval_ns = fifo_poll_interval_ns(
            self.fifo_capacity, self.nominal_period_ns, halves=False
        )
        self.next_poll_ns: int | None = None  # a FIFO: polled at its interval
        self.accel_scale = accel_scale_ms2(cfg.accel_range_g)
        self.gyro_scale = gyro_scale_rads(cfg.gyro_range_dps)
        self.plan = RegisterPlan(dev, register_plan(cfg))
        # PWR_MGMT_1: any reset leaves the chip asleep (SLEEP set), which the plan clears
        self._checker = RegisterChecker(
            [self.plan], clock, self.counters, sentinels=[(self.plan, self.plan.settings[0])],
            poll_ns=self.poll_interval_ns + self.nominal_period_ns,
        )  # fmt: skip
        self._need_reset = False
        self.timing = FifoTiming()

    def start(self) -> Iterator[int]:
        """Identity, reset, configure, FIFO on. Yields the waits (ns) so that the bus worker can
        serve the other devices on the bus during the 100 ms reset."""
        who = self.dev.read_u8(R.Register.WHO_AM_I)
        if who != R.WHO_AM_I_VALUE:
            raise DeviceIdentityError(
                f"WHO_AM_I (0x{R.Register.WHO_AM_I:02x}) at address 0x{self.dev.address:02x} "
                f"reads 0x{who:02x}, expected 0x{R.WHO_AM_I_VALUE:02x} for an MPU6050: check "
                "the chip, the address (AD0 low 0x68, high 0x69) and the wiring"
            )
        self.dev.write_u8(R.Register.PWR_MGMT_1, R.PwrMgmt1.DEVICE_RESET)
        yield R.RESET_WAIT_NS
        pwr = self.dev.read_u8(R.Register.PWR_MGMT_1)
        if pwr & R.PwrMgmt1.DEVICE_RESET:
            raise DeviceIdentityError(
                f"MPU6050 still in reset after 100 ms (PWR_MGMT_1=0x{pwr:02x})"
            )
        self.counters.soft_resets += 1
        config = [s for s in self.plan.settings if s.register not in _FIFO_REGISTERS]
        self.plan.write(config[0])  # wake up first
        yield R.WAKE_WAIT_NS
        for s in config[1:]:
            self.plan.write(s)
        self._fifo_restart()
        self.plan.verify_all()
        self.timing.started()
        self._checker.restart()

    def _fifo_restart(self) -> None:
        """Stop the FIFO, empty it, re-enable accel+gyro: the Linux/PX4 recovery sequence.

        Samples are discarded from the first write on, so the next batch returned must say so
        (`resync`) even if this or a later transfer fails first."""
        self.timing.broke()
        self._need_reset = True
        user = self.dev.read_u8(R.Register.USER_CTRL) & ~int(R.UserCtrl.FIFO_EN | _ACTIONS)
        self.dev.write_u8(R.Register.FIFO_EN, 0)
        self.dev.write_u8(R.Register.USER_CTRL, user | R.UserCtrl.FIFO_RESET)
        self.dev.write_u8(R.Register.FIFO_EN, FIFO_SENSORS)  # every bit of FIFO_EN is defined
        t0 = self.clock.now_ns()
        self.dev.write_u8(R.Register.USER_CTRL, user | R.UserCtrl.FIFO_EN)
        self.timing.flushed(t0, self.clock.now_ns())
        self.dev.read_u8(R.Register.INT_STATUS)  # clear a stale overflow flag
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
        n = int(accel.shape[0])
        return RawBatch(
            n,
            {
                Channel.ACCEL: RawChannel(accel, self.accel_scale, FULL_SCALE),
                Channel.GYRO: RawChannel(gyro, self.gyro_scale, FULL_SCALE),
                Channel.TEMPERATURE: RawChannel(np.full(n, temp)),
            },
            self.timing.read(t_before, t_after),
        )

    def read(self) -> RawBatch:
        if self._need_reset:
            self._fifo_restart()
        int_status, temp_raw = decode_status_block(self.dev.read(R.Register.INT_STATUS, 9))
        temp = temp_raw / 340.0 + 36.53  # temperature_c's formula, without NumPy for one value
        t_before = self.clock.now_ns()
        count = int.from_bytes(self.dev.read(R.Register.FIFO_COUNT_H, 2), "big")
        t_after = self.clock.now_ns()
        # Overflow flag, or so close to full that the count->read race could wrap (Linux margin)
        if int_status & _OFLOW or count > R.FIFO_SIZE - 3 * SAMPLE_BYTES:
            self.counters.fifo_overflows += 1
            self._fifo_restart()
            return self._batch(_NONE, _NONE, temp, t_before, t_after)
        n = count // SAMPLE_BYTES
        self._checker.check_next()
        if n == 0:
            return self._batch(_NONE, _NONE, temp, t_before, t_after)
        try:
            data = self.dev.read(R.Register.FIFO_R_W, n * SAMPLE_BYTES)
        except BusError as e:
            # A NAK comes in an address phase, before the chip sends a byte: the FIFO is as it
            # was, and the next poll reads it all (nothing lost while it has room). Any other
            # failure may have stopped the burst mid-sample: the FIFO is no longer aligned.
            # (A failed status or count read leaves the FIFO untouched and needs no reset.)
            if error_kind(e) != ErrorKind.NAK:
                self._need_reset = True
            raise
        accel, gyro = decode_fifo(data)
        return self._batch(accel, gyro, temp, t_before, t_after)

    def stop(self) -> None:
        try:
            self.dev.write_u8(R.Register.USER_CTRL, 0)
            self.dev.write_u8(R.Register.PWR_MGMT_1, R.PwrMgmt1.SLEEP)
        except BusError:
            pass

    def chip_status(self) -> dict[str, Any]:
        return {}
