"""MPU6050 decoding and register plan, checked against datasheet facts.

Byte vectors are written out by hand from the register map (big-endian int16, FIFO set = accel
X,Y,Z then gyro X,Y,Z, INT_STATUS..TEMP_OUT_L from 0x3A); nothing here is produced by an encoder
from the code under test. Facts: docs/chips/mpu6050.md.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from imud.buses.i2c import I2CDevice
from imud.buses.models import SimBus
from imud.channels import Channel
from imud.chips.api import FifoRead, start_blocking
from imud.chips.mpu6050.config import Mpu6050Config
from imud.chips.mpu6050.driver import (
    Mpu6050Driver,
    accel_scale_ms2,
    decode_fifo,
    decode_status_block,
    gyro_scale_rads,
    temperature_c,
)
from imud.chips.mpu6050.sim import Mpu6050Sim
from imud.clock import VirtualClock
from imud.errors import BusError, DeviceIdentityError, RegisterMismatch
from imud.sim.i2c import SimI2CBus
from imud.sim.settings import SimSettings

G = 9.80665  # standard gravity, m/s^2

# One FIFO set: accel x=+16384, y=-16384, z=1, gyro x=-1, y=32767, z=-32768 (BE int16)
SET_A = bytes(
    [
        0x40, 0x00,  # accel x  +16384
        0xC0, 0x00,  # accel y  -16384
        0x00, 0x01,  # accel z  1
        0xFF, 0xFF,  # gyro x   -1
        0x7F, 0xFF,  # gyro y   32767
        0x80, 0x00,  # gyro z   -32768
    ]
)  # fmt: skip
SET_A_ACCEL = [16384, -16384, 1]
SET_A_GYRO = [-1, 32767, -32768]

# A second set: accel 0x0102=258, 0xFEFF=-257, 0x7FFF=32767; gyro 0x8001=-32767, 0, 0x00FF=255
SET_B = bytes([0x01, 0x02, 0xFE, 0xFF, 0x7F, 0xFF, 0x80, 0x01, 0x00, 0x00, 0x00, 0xFF])
SET_B_ACCEL = [258, -257, 32767]
SET_B_GYRO = [-32767, 0, 255]


# --- FIFO sets -----------------------------------------------------------------------------------


def test_decode_one_fifo_set() -> None:
    accel, gyro = decode_fifo(SET_A)
    assert accel.shape == (1, 3) and gyro.shape == (1, 3)
    assert accel.tolist() == [SET_A_ACCEL]
    assert gyro.tolist() == [SET_A_GYRO]


def test_decoded_counts_are_wide_ints() -> None:
    # int16 extremes must survive arithmetic (e.g. negation of -32768) downstream
    accel, gyro = decode_fifo(SET_A)
    assert np.issubdtype(accel.dtype, np.signedinteger) and accel.dtype.itemsize >= 4
    assert np.issubdtype(gyro.dtype, np.signedinteger) and gyro.dtype.itemsize >= 4
    assert int((-gyro)[0, 2]) == 32768


def test_decode_several_sets_in_order() -> None:
    accel, gyro = decode_fifo(SET_A + SET_B + SET_A)
    assert accel.tolist() == [SET_A_ACCEL, SET_B_ACCEL, SET_A_ACCEL]
    assert gyro.tolist() == [SET_A_GYRO, SET_B_GYRO, SET_A_GYRO]


@pytest.mark.parametrize("extra", [1, 2, 6, 11])
def test_trailing_partial_set_ignored(extra: int) -> None:
    accel, gyro = decode_fifo(SET_B + SET_A[:extra])
    assert accel.tolist() == [SET_B_ACCEL]
    assert gyro.tolist() == [SET_B_GYRO]


@pytest.mark.parametrize("data", [b"", SET_A[:11]])
def test_no_whole_set_gives_empty_arrays(data: bytes) -> None:
    accel, gyro = decode_fifo(data)
    assert accel.shape == (0, 3) and gyro.shape == (0, 3)


# --- scale factors -------------------------------------------------------------------------------


@pytest.mark.parametrize(("range_g", "lsb_per_g"), [(2, 16384), (4, 8192), (8, 4096), (16, 2048)])
def test_accel_scale(range_g: int, lsb_per_g: int) -> None:
    scale = accel_scale_ms2(range_g)
    assert math.isclose(scale * lsb_per_g, G, rel_tol=1e-12)  # 1 g worth of counts


def test_accel_16384_counts_at_2g_is_one_g() -> None:
    accel, _ = decode_fifo(SET_A)
    ms2 = accel * accel_scale_ms2(2)
    assert ms2[0, 0] == pytest.approx(G, rel=1e-12)
    assert ms2[0, 1] == pytest.approx(-G, rel=1e-12)


@pytest.mark.parametrize(
    ("range_dps", "lsb_per_dps", "linux_rad_per_lsb"),
    [
        # LSB = FS/32768 (PX4); Linux's rad/s table rounds differently, within 0.1 %
        (250, 131.072, 0.000133090),
        (500, 65.536, 0.000266181),
        (1000, 32.768, 0.000532362),
        (2000, 16.384, 0.001064724),
    ],
)
def test_gyro_scale(range_dps: int, lsb_per_dps: float, linux_rad_per_lsb: float) -> None:
    scale = gyro_scale_rads(range_dps)
    assert math.isclose(scale * lsb_per_dps, math.pi / 180.0, rel_tol=1e-12)
    assert scale == pytest.approx(linux_rad_per_lsb, rel=1e-3)  # rad/s, not deg/s


# --- temperature ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("raw", "celsius"),
    [
        (0, 36.53),
        (-4230, -4230 / 340 + 36.53),  # about 24.09 degC
        (340, 37.53),
        (32767, 32767 / 340 + 36.53),
    ],
)
def test_temperature(raw: int, celsius: float) -> None:
    assert float(temperature_c(raw)) == pytest.approx(celsius, abs=1e-9)


def test_temperature_of_minus_4230_is_about_24_degrees() -> None:
    assert float(temperature_c(-4230)) == pytest.approx(24.0888, abs=1e-4)


def test_temperature_agrees_with_linux_offset() -> None:
    # Linux: (raw + 12420) / 340, i.e. 0 degC at raw -12420 (36.53 * 340 = 12420.2)
    assert float(temperature_c(-12420)) == pytest.approx(0.0, abs=1e-3)


def test_temperature_vectorised() -> None:
    out = temperature_c(np.array([0, 340, -680], dtype=np.int32))
    assert out.tolist() == pytest.approx([36.53, 37.53, 34.53], abs=1e-9)


# --- status block (INT_STATUS 0x3A .. TEMP_OUT_L 0x42) ------------------------------------------


def test_status_block_with_fifo_overflow() -> None:
    block = bytes(
        [
            0x11,  # INT_STATUS: FIFO_OFLOW_INT (bit 4) | DATA_RDY_INT (bit 0)
            0x40, 0x00, 0x00, 0x00, 0xC0, 0x00,  # ACCEL_XOUT_H..ACCEL_ZOUT_L (ignored)
            0xEF, 0x7A,  # TEMP_OUT_H/L: 0xEF7A = -4230
        ]
    )  # fmt: skip
    status, temp_raw = decode_status_block(block)
    assert status == 0x11
    assert status & 0x10  # overflow
    assert temp_raw == -4230
    assert float(temperature_c(temp_raw)) == pytest.approx(-4230 / 340 + 36.53, abs=1e-9)


def test_status_block_without_overflow_positive_temperature() -> None:
    block = bytes([0x01, 0xFF, 0xFF, 0x12, 0x34, 0x80, 0x00, 0x01, 0x54])  # TEMP 0x0154 = 340
    status, temp_raw = decode_status_block(block)
    assert status == 0x01
    assert not status & 0x10
    assert temp_raw == 340


@pytest.mark.parametrize("length", [0, 8, 10, 14])
def test_status_block_wrong_length(length: int) -> None:
    with pytest.raises(BusError, match=f"expected 9 bytes, got {length}"):
        decode_status_block(bytes(length))


# --- register plan, through the simulator --------------------------------------------------------

SMPLRT_DIV, CONFIG, GYRO_CONFIG, ACCEL_CONFIG = 0x19, 0x1A, 0x1B, 0x1C
FIFO_EN, INT_ENABLE, USER_CTRL, PWR_MGMT_1, WHO_AM_I = 0x23, 0x38, 0x6A, 0x6B, 0x75


def make_cfg(fields: dict[str, object] | None = None, address: int = 0x68) -> Mpu6050Config:
    return Mpu6050Config.model_validate(
        {
            "chip": "mpu6050",
            "name": "imu0",
            "bus": {"kind": "sim", "bus": "sim0", "address": address},
            **(fields or {}),
        }
    )


def started(cfg: Mpu6050Config) -> tuple[Mpu6050Sim, Mpu6050Driver, VirtualClock]:
    clock = VirtualClock()
    bus = SimI2CBus(seed=1)
    sim = Mpu6050Sim(SimSettings(seed=1), clock)
    assert isinstance(cfg.bus, SimBus)
    bus.attach(cfg.bus.address, sim)
    driver = Mpu6050Driver(cfg, I2CDevice(bus, cfg.bus.address), clock)
    start_blocking(driver, clock)
    return sim, driver, clock


def test_register_plan_default_config() -> None:
    # 1 kHz with DLPF 188 Hz, +-500 dps, +-4 g
    sim, _, _ = started(
        make_cfg({"gyro_range_dps": 500, "accel_range_g": 4, "dlpf_hz": 188, "odr_hz": 1000})
    )
    regs = sim.regs
    assert regs[SMPLRT_DIV] == 0  # 1 kHz / (1 + 0)
    assert regs[CONFIG] == 1  # DLPF_CFG 1 = 188 Hz
    assert regs[GYRO_CONFIG] == 0x08  # FS_SEL 1 << 3
    assert regs[ACCEL_CONFIG] == 0x08  # AFS_SEL 1 << 3
    assert regs[FIFO_EN] == 0x78  # XG | YG | ZG | ACCEL, no TEMP
    assert regs[USER_CTRL] & 0x40  # FIFO_EN
    assert regs[PWR_MGMT_1] == 0x01  # awake, PLL with X gyro
    assert regs[INT_ENABLE] & 0x10  # FIFO_OFLOW_EN


@pytest.mark.parametrize(
    ("fields", "expect"),
    [
        (
            {"gyro_range_dps": 2000, "accel_range_g": 16, "dlpf_hz": 256, "odr_hz": 8000 / 9},
            {SMPLRT_DIV: 8, CONFIG: 0, GYRO_CONFIG: 3 << 3, ACCEL_CONFIG: 3 << 3},
        ),
        (
            {"gyro_range_dps": 250, "accel_range_g": 2, "dlpf_hz": 98, "odr_hz": 500},
            {SMPLRT_DIV: 1, CONFIG: 2, GYRO_CONFIG: 0, ACCEL_CONFIG: 0},
        ),
        (
            {"gyro_range_dps": 1000, "accel_range_g": 8, "dlpf_hz": 5, "odr_hz": 1000 / 256},
            {SMPLRT_DIV: 255, CONFIG: 6, GYRO_CONFIG: 2 << 3, ACCEL_CONFIG: 2 << 3},
        ),
    ],
)
def test_register_plan_other_settings(fields: dict[str, object], expect: dict[int, int]) -> None:
    sim, _, _ = started(make_cfg(fields))
    assert {reg: sim.regs[reg] for reg in expect} == expect


def test_started_chip_fills_fifo_with_12_byte_sets() -> None:
    _, driver, clock = started(make_cfg({"odr_hz": 500}))
    clock.advance(20_000_000)  # 20 ms at 500 Hz: about 10 samples
    batch = driver.read()
    assert 8 <= batch.n <= 12
    acc = batch.channels[Channel.ACCEL]
    gyr = batch.channels[Channel.GYRO]
    assert acc.data.shape == (batch.n, 3) and gyr.data.shape == (batch.n, 3)
    # still and level, +-4 g: z near +1 g (8192 counts), x and y near 0
    assert np.all(np.abs(acc.data[:, 2] - 8192) < 800)
    assert np.all(np.abs(acc.data[:, :2]) < 800)
    assert acc.scale == pytest.approx(4 * G / 32768)  # 8192 LSB/g
    assert gyr.scale == pytest.approx(math.radians(1) / 65.536)  # +-500 dps: 65.536 LSB/(deg/s)
    # no invalid marker in an MPU6050 FIFO (docs/chips/mpu6050.md, FIFO): nothing is masked
    assert acc.invalid is None and gyr.invalid is None
    # an int16 reading saturates at +-32767 counts
    assert acc.full_scale == 32767 and gyr.full_scale == 32767
    # host-time brackets of the count read, for the sample-clock fit; the first read after the
    # start continues from the FIFO the start sequence enabled
    assert isinstance(batch.timing, FifoRead)
    assert batch.timing.t_before_ns <= batch.timing.t_after_ns <= clock.now_ns()
    temp = batch.channels[Channel.TEMPERATURE].data
    assert temp.shape == (batch.n,)
    assert np.all(np.abs(temp - 25.0) < 1.0)  # the simulator's default 25 degC, 1/340 degC LSB


class HoldsReservedBits:
    """An MPU6050 whose registers hold bits imud does not configure from its reset on."""

    def __init__(self, sim: Mpu6050Sim, held: dict[int, int]) -> None:
        self.sim, self.held = sim, held

    def read(self, register: int, length: int) -> bytes:
        return self.sim.read(register, length)

    def write(self, register: int, data: bytes) -> None:
        self.sim.write(register, data)
        if register == PWR_MGMT_1 and data[0] & 0x80:  # DEVICE_RESET
            for reg, bits in self.held.items():
                self.sim.regs[reg] |= bits

    def spi_select(self) -> bool:
        return True


def test_register_plan_keeps_bits_it_does_not_own() -> None:
    """Configuration is read-modify-write: reserved bits keep what the chip holds, and the
    periodic check does not take them for a corrupted register."""
    held = {
        GYRO_CONFIG: 0x04,  # [2:0] reserved
        CONFIG: 0x80,  # bit 7: above EXT_SYNC_SET [5:3] and bit 6
        PWR_MGMT_1: 0x10,  # bit 4 reserved
    }
    cfg = make_cfg({"gyro_range_dps": 500, "accel_range_g": 4, "dlpf_hz": 188, "odr_hz": 1000})
    clock = VirtualClock()
    bus = SimI2CBus(seed=1)
    sim = Mpu6050Sim(SimSettings(seed=1), clock)
    bus.attach(0x68, HoldsReservedBits(sim, held))
    driver = Mpu6050Driver(cfg, I2CDevice(bus, 0x68), clock)
    start_blocking(driver, clock)
    assert sim.regs[GYRO_CONFIG] == 0x04 | 0x08  # FS_SEL 1 (500 deg/s)
    assert sim.regs[CONFIG] == 0x80 | 1  # DLPF_CFG 1 (188 Hz)
    assert sim.regs[PWR_MGMT_1] == 0x10 | 0x01  # awake, PLL with the X gyro
    rounds = len(driver.plan.settings) + 2  # a whole round of the periodic check, 100 ms each
    for _ in range(2 * rounds):  # polls 50 ms apart: 600 bytes, the FIFO never overflows
        clock.advance(50_000_000)
        assert driver.read().n > 0
    assert driver.counters.bad_registers == 0 and driver.counters.fifo_overflows == 0
    # while a configured bit that changed is noticed within a round
    sim.regs[GYRO_CONFIG] ^= 0x18  # FS_SEL 1 -> 2
    with pytest.raises(RegisterMismatch, match="0x1b"):
        for _ in range(2 * rounds):
            clock.advance(50_000_000)
            driver.read()
    assert driver.counters.bad_registers == 1


def test_wrong_who_am_i_raises_identity_error() -> None:
    clock = VirtualClock()
    bus = SimI2CBus()
    sim = Mpu6050Sim(SimSettings(), clock)
    bus.attach(0x69, sim)
    sim.regs[WHO_AM_I] = 0x70  # an MPU6500
    cfg = make_cfg(address=0x69)
    driver = Mpu6050Driver(cfg, I2CDevice(bus, 0x69), clock)
    with pytest.raises(DeviceIdentityError) as info:
        start_blocking(driver, clock)
    msg = str(info.value)
    assert "0x70" in msg  # what it read
    assert "0x68" in msg  # what an MPU6050 answers
    assert "0x69" in msg  # where it looked
    assert sim.regs[PWR_MGMT_1] == 0x40  # nothing written: still asleep after power-on


def test_no_chip_at_address_is_a_bus_error() -> None:
    clock = VirtualClock()
    bus = SimI2CBus()
    driver = Mpu6050Driver(make_cfg(), I2CDevice(bus, 0x68), clock)
    with pytest.raises(BusError, match="0x68"):
        start_blocking(driver, clock)
