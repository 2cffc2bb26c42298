"""Register-level tests of the BMI088 simulator (both dies), through the real bus layers.

The accel die is reached as the driver reaches it: `SpiDevice` (one dummy byte) over `SimSpiDev`,
or `I2CDevice` over `SimI2CBus` (which, past 32 bytes, uses smbus2's own `i2c_msg`). Expected
values come from the facts sheet (docs/chips/bmi088.md) and
the simulator's stated model (imud/chips/bmi088/sim.py docstring); each is worked out in the test.
Virtual time only moves when a test advances the clock, so counts of samples are exact up to one
sample at either end of an interval.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from imud.buses.i2c import I2CDevice
from imud.buses.spi import SpiDevice
from imud.chips.bmi088 import decode as d
from imud.chips.bmi088 import registers as R
from imud.chips.bmi088.registers import AccelRegister as A
from imud.chips.bmi088.registers import GyroRegister as G
from imud.chips.bmi088.sim import Bmi088Sim
from imud.chips.bmi088.spec import SPEC
from imud.clock import VirtualClock
from imud.sim.i2c import SimI2CBus
from imud.sim.settings import SimSettings
from imud.sim.spi import SimSpiDev

MS = 1_000_000
GRAVITY = 9.80665
# SPI dummy bytes before register data on reads: one on the accel die, none on the gyro die
# (docs/chips/bmi088.md, I2C addresses, interface)
ACC_DUMMY, GYR_DUMMY = 1, 0
ACC_ADDR, GYR_ADDR = 0x18, 0x68
# ACC_CONF ODR code -> Hz, and GYRO_BANDWIDTH code -> ODR Hz (facts sheet 3.2)
ACC_ODR_CODES = {0x5: 12.5, 0x6: 25, 0x7: 50, 0x8: 100, 0x9: 200, 0xA: 400, 0xB: 800, 0xC: 1600}
GYR_ODR_CODES = {0: 2000, 1: 2000, 2: 1000, 3: 400, 4: 200, 5: 100, 6: 200, 7: 100}
ACC_NORMAL_1600 = 0xAC  # bwp normal (0xA) << 4 | ODR 1600 Hz (0xC)
GYR_FIFO_MODE, GYR_STREAM_MODE = 0x40, 0x80


def make(**settings: Any) -> tuple[Bmi088Sim, VirtualClock]:
    clock = VirtualClock()
    return Bmi088Sim(SimSettings(**settings), clock), clock


def accel_spi(sim: Bmi088Sim, dummy_bytes: int = ACC_DUMMY) -> SpiDevice:
    """The accel die on its own chip select, wired as the chip's spec says and wrapped as the
    driver wraps it (dummy byte = 1)."""
    return SpiDevice(SimSpiDev(sim.accel, dummy_bytes=SPEC.dies[0].spi_dummy_bytes), dummy_bytes)


def accel_spi_ready(sim: Bmi088Sim) -> SpiDevice:
    acc = accel_spi(sim)
    acc.read_u8(A.ACC_CHIP_ID)  # the dummy read that switches the die to SPI
    assert acc.read_u8(A.ACC_CHIP_ID) == R.ACC_CHIP_ID_VALUE
    return acc


def i2c_dies(sim: Bmi088Sim) -> tuple[I2CDevice, I2CDevice]:
    bus = SimI2CBus()
    bus.attach(ACC_ADDR, sim.accel)
    bus.attach(GYR_ADDR, sim.gyro)
    return I2CDevice(bus, ACC_ADDR), I2CDevice(bus, GYR_ADDR)


def power_on(acc: SpiDevice | I2CDevice, clock: VirtualClock) -> None:
    acc.write_u8(A.ACC_PWR_CONF, 0x00)  # active
    clock.advance(5 * MS)
    acc.write_u8(A.ACC_PWR_CTRL, 0x04)  # accel on
    clock.advance(5 * MS)
    assert (acc.read_u8(A.ACC_PWR_CONF), acc.read_u8(A.ACC_PWR_CTRL)) == (0x00, 0x04)


def start_accel_fifo(
    acc: SpiDevice | I2CDevice, clock: VirtualClock, conf: int = ACC_NORMAL_1600
) -> None:
    power_on(acc, clock)
    acc.write_u8(A.FIFO_CONFIG_1, 0x50)  # acc_en | the bit that must be 1
    acc.write_u8(A.ACC_CONF, conf)
    assert acc.read_u8(A.ACC_CONF) == conf
    assert acc.read_u8(A.FIFO_CONFIG_1) == 0x50


def accel_length(acc: SpiDevice | I2CDevice) -> int:
    lsb, msb = acc.read(A.FIFO_LENGTH_0, 2)
    return d.fifo_length(lsb, msb)


def drain_accel(acc: SpiDevice | I2CDevice) -> d.AccelFifo:
    """Read exactly what FIFO_LENGTH says (no over-read)."""
    n = accel_length(acc)
    return d.decode_accel_fifo(acc.read(A.FIFO_DATA, n) if n else b"")


def accel_data(acc: SpiDevice | I2CDevice) -> list[int]:
    raw = acc.read(A.ACC_X_LSB, 6)
    return np.frombuffer(raw, dtype="<i2").astype(int).tolist()


def gyro_status(gyr: SpiDevice | I2CDevice) -> tuple[bool, int]:
    s = gyr.read_u8(G.FIFO_STATUS)
    return bool(s & 0x80), s & 0x7F


def drain_gyro(gyr: SpiDevice | I2CDevice) -> np.ndarray:
    _, n = gyro_status(gyr)
    return d.decode_gyro_fifo(gyr.read(G.FIFO_DATA, n * R.GYRO_FRAME_BYTES) if n else b"")


def gyro_data(gyr: SpiDevice | I2CDevice) -> list[int]:
    return np.frombuffer(gyr.read(G.RATE_X_LSB, 6), dtype="<i2").astype(int).tolist()


# --- accel die: SPI mode switch and the dummy byte -----------------------------------------------


def test_accel_first_spi_transfer_only_switches_to_spi() -> None:
    sim, _ = make()
    acc = accel_spi(sim)
    assert sim.accel.spi_mode is False
    assert acc.read_u8(A.ACC_CHIP_ID) == 0x00  # the answer to the switching transfer is garbage
    assert sim.accel.spi_mode is True
    assert acc.read_u8(A.ACC_CHIP_ID) == 0x1E
    assert acc.read_u8(A.ACC_CHIP_ID) == 0x1E


def test_accel_first_spi_transfer_write_does_not_happen() -> None:
    sim, _ = make()
    acc = accel_spi(sim)
    acc.write_u8(A.ACC_RANGE, 0x03)  # first transfer: only switches the die to SPI
    assert acc.read_u8(A.ACC_RANGE) == 0x01  # the reset value: the write was lost
    acc.write_u8(A.ACC_RANGE, 0x03)
    assert acc.read_u8(A.ACC_RANGE) == 0x03


def test_accel_over_i2c_needs_no_switch() -> None:
    sim, _ = make()
    acc, _ = i2c_dies(sim)
    assert acc.read_u8(A.ACC_CHIP_ID) == 0x1E
    assert sim.accel.spi_mode is False


def test_accel_soft_reset_puts_it_back_in_i2c_mode() -> None:
    sim, clock = make()
    acc = accel_spi_ready(sim)
    acc.write_u8(A.ACC_RANGE, 0x03)
    assert acc.read_u8(A.ACC_RANGE) == 0x03
    acc.write_u8(A.ACC_SOFTRESET, R.SOFTRESET_CMD)
    clock.advance(2 * MS)  # past the 1 ms reset
    assert acc.read_u8(A.ACC_CHIP_ID) == 0x00  # switching again
    assert acc.read_u8(A.ACC_CHIP_ID) == 0x1E
    assert acc.read_u8(A.ACC_RANGE) == 0x01  # registers back to reset values


def test_accel_soft_reset_busy_for_1ms() -> None:
    sim, clock = make()
    acc, _ = i2c_dies(sim)
    acc.write_u8(A.ACC_RANGE, 0x02)
    acc.write_u8(A.ACC_SOFTRESET, R.SOFTRESET_CMD)
    clock.advance(900_000)
    assert acc.read_u8(A.ACC_CHIP_ID) == 0x00  # busy: reads zeros
    acc.write_u8(A.ACC_RANGE, 0x03)  # and ignores writes
    clock.advance(100_000)
    assert acc.read_u8(A.ACC_CHIP_ID) == 0x1E
    assert acc.read_u8(A.ACC_RANGE) == 0x01


def test_accel_spi_reads_carry_one_dummy_byte() -> None:
    sim, _ = make()
    assert SPEC.dies[0].name == "accel" and SPEC.dies[0].spi_dummy_bytes == ACC_DUMMY
    spi = SimSpiDev(sim.accel, dummy_bytes=SPEC.dies[0].spi_dummy_bytes)
    good, naive = SpiDevice(spi, dummy_bytes=1), SpiDevice(spi, dummy_bytes=0)
    good.read_u8(A.ACC_CHIP_ID)  # switch to SPI
    # on the wire: address, dummy byte, then the register data
    assert spi.xfer2([0x80 | A.ACC_CHIP_ID, 0, 0]) == [0, 0, 0x1E]
    assert good.read(A.ACC_CONF, 2) == bytes([0xA8, 0x01])  # ACC_CONF, ACC_RANGE reset values
    # without skipping the dummy byte every value is shifted by one byte
    assert naive.read_u8(A.ACC_CHIP_ID) == 0x00
    assert naive.read(A.ACC_CONF, 2) == bytes([0x00, 0xA8])
    assert naive.read(A.ACC_CHIP_ID, 2) == bytes([0x00, 0x1E])


def test_gyro_spi_has_no_dummy_byte_and_no_mode_switch() -> None:
    sim, _ = make()
    assert SPEC.dies[1].name == "gyro" and SPEC.dies[1].spi_dummy_bytes == GYR_DUMMY
    gyr = SpiDevice(SimSpiDev(sim.gyro, dummy_bytes=SPEC.dies[1].spi_dummy_bytes), dummy_bytes=0)
    assert gyr.read_u8(G.GYRO_CHIP_ID) == 0x0F  # the very first transfer answers
    assert gyr.read(G.GYRO_RANGE, 2) == bytes([0x00, 0x80])  # RANGE, BANDWIDTH reset values


# --- accel die: power --------------------------------------------------------------------------


def test_accel_starts_suspended_without_fifo_data() -> None:
    sim, clock = make(clock_error=0.0)
    acc = accel_spi_ready(sim)
    assert (acc.read_u8(A.ACC_PWR_CONF), acc.read_u8(A.ACC_PWR_CTRL)) == (0x03, 0x00)
    acc.write_u8(A.FIFO_CONFIG_1, 0x50)
    clock.advance(100 * MS)
    assert accel_length(acc) == 0
    acc.write_u8(A.ACC_PWR_CONF, 0x00)  # active, but the accel is not enabled yet
    clock.advance(50 * MS)
    assert accel_length(acc) == 0
    acc.write_u8(A.ACC_PWR_CTRL, 0x04)
    clock.advance(50 * MS)
    n = accel_length(acc)
    # reset ODR 100 Hz: 50 ms holds 5 sample periods
    assert n % 7 == 0 and 4 <= n // 7 <= 5, n


def test_accel_enabled_but_suspended_gives_no_data() -> None:
    sim, clock = make()
    acc = accel_spi_ready(sim)
    acc.write_u8(A.FIFO_CONFIG_1, 0x50)
    acc.write_u8(A.ACC_PWR_CTRL, 0x04)  # on, but PWR_CONF still 0x03: suspend
    clock.advance(100 * MS)
    assert acc.read_u8(A.ACC_PWR_CTRL) == 0x04
    assert accel_length(acc) == 0


def test_write_within_5ms_of_a_power_register_change_is_ignored() -> None:
    sim, clock = make()
    acc = accel_spi_ready(sim)
    acc.write_u8(A.ACC_PWR_CONF, 0x00)
    clock.advance(4_900_000)
    acc.write_u8(A.ACC_PWR_CTRL, 0x04)
    acc.write_u8(A.ACC_RANGE, 0x02)
    assert acc.read_u8(A.ACC_PWR_CTRL) == 0x00  # too early
    assert acc.read_u8(A.ACC_RANGE) == 0x01
    clock.advance(100_000)  # 5 ms after the PWR_CONF change
    acc.write_u8(A.ACC_PWR_CTRL, 0x04)
    assert acc.read_u8(A.ACC_PWR_CTRL) == 0x04
    acc.write_u8(A.ACC_RANGE, 0x02)  # within 5 ms of the PWR_CTRL change
    assert acc.read_u8(A.ACC_RANGE) == 0x01
    clock.advance(5 * MS)
    acc.write_u8(A.ACC_RANGE, 0x02)
    assert acc.read_u8(A.ACC_RANGE) == 0x02


@pytest.mark.parametrize("code", [0x0, 0x1, 0x4, 0xD, 0xE, 0xF])
def test_invalid_acc_conf_odr_code_ignored(code: int) -> None:
    sim, _ = make(clock_error=0.0)
    acc = accel_spi_ready(sim)
    acc.write_u8(A.ACC_CONF, 0xA0 | code)
    assert acc.read_u8(A.ACC_CONF) == 0xA8  # the reset value: normal, 100 Hz
    assert sim.accel.rate_hz == 100.0
    acc.write_u8(A.ACC_CONF, 0xA9)  # a valid code is taken
    assert acc.read_u8(A.ACC_CONF) == 0xA9
    assert sim.accel.rate_hz == 200.0


@pytest.mark.parametrize(
    ("reg", "value", "expect"),
    [
        (A.ACC_CHIP_ID, 0x55, 0x1E),  # read-only
        (A.ACC_STATUS, 0xFF, 0x00),  # read-only (no data ready while suspended)
        (0x30, 0x55, 0x00),  # not a register
        (0x7F, 0x55, 0x00),  # not a register
        (A.ACC_PWR_CONF, 0x01, 0x03),  # only 0x00 and 0x03 exist
        (A.ACC_PWR_CTRL, 0x02, 0x00),  # only 0x00 and 0x04 exist
    ],
)
def test_accel_ignores_writes_to_read_only_unknown_or_invalid(
    reg: int, value: int, expect: int
) -> None:
    sim, _ = make()
    acc = accel_spi_ready(sim)
    acc.write_u8(reg, value)
    assert acc.read_u8(reg) == expect
    acc.write_u8(A.ACC_RANGE, 0x02)  # the same path does carry a valid write
    assert acc.read_u8(A.ACC_RANGE) == 0x02


# --- accel die: FIFO ---------------------------------------------------------------------------


@pytest.mark.parametrize("code", sorted(ACC_ODR_CODES))
def test_accel_fifo_frames_at_the_configured_odr(code: int) -> None:
    clock_error = 0.01
    sim, clock = make(clock_error=clock_error)
    acc = accel_spi_ready(sim)
    start_accel_fifo(acc, clock, conf=0xA0 | code)
    odr = ACC_ODR_CODES[code]
    drain_accel(acc)
    frames = 400 if odr >= 100 else 200  # enough that a 1 % clock error is 2+ frames
    seconds = frames / odr
    step_ns = int(100 / odr * 1e9)  # read every 100 frames: the FIFO holds 146
    n, end = 0, clock.now_ns() + int(seconds * 1e9)
    while clock.now_ns() < end:
        clock.advance(min(step_ns, end - clock.now_ns()))
        length = accel_length(acc)
        data = acc.read(A.FIFO_DATA, length)
        assert length % 7 == 0 and all(b == 0x84 for b in data[::7]), data[:14].hex()
        fifo = d.decode_accel_fifo(data)
        assert fifo.skipped_before == [] and fifo.corrupt_at is None
        n += len(fifo.accel)
    assert abs(n - seconds * odr * (1 + clock_error)) <= 1, (n, seconds * odr)
    assert abs(n - seconds * odr) >= 2  # the die's oscillator, not the nominal rate


def test_accel_fifo_needs_acc_en() -> None:
    sim, clock = make()
    acc = accel_spi_ready(sim)
    power_on(acc, clock)
    assert acc.read_u8(A.FIFO_CONFIG_1) == 0x10  # reset value: acc_en off
    clock.advance(100 * MS)
    assert accel_length(acc) == 0
    assert acc.read_u8(A.ACC_STATUS) & 0x80  # but the die is sampling: data ready


def test_stream_overflow_gives_a_skip_frame_counting_dropped_frames() -> None:
    sim, clock = make(clock_error=0.0)
    acc = accel_spi_ready(sim)
    start_accel_fifo(acc, clock)
    assert sim.accel.frames_dropped == 0
    clock.advance(200 * MS)  # 320 frames at 1600 Hz; the FIFO holds 1024 // 7 = 146
    newest = accel_data(acc)
    length = accel_length(acc)
    assert length == 146 * 7 + 2  # the frames and the skip frame
    data = acc.read(A.FIFO_DATA, length)
    assert data[0] == R.AccFifoHeader.SKIP
    fifo = d.decode_accel_fifo(data)
    assert len(fifo.accel) == 146
    assert len(fifo.skipped_before) == 1
    at, count = fifo.skipped_before[0]
    assert at == 0
    assert count == sim.accel.frames_dropped
    assert abs(count + 146 - 0.2 * 1600) <= 1  # kept + dropped = produced
    assert fifo.accel[-1].tolist() == newest  # stream mode dropped the oldest, kept the newest
    # the skip is reported once
    clock.advance(10 * MS)
    again = drain_accel(acc)
    assert again.skipped_before == [] and 15 <= len(again.accel) <= 16


def test_stream_overflow_of_more_than_255_frames_reports_255() -> None:
    sim, clock = make(clock_error=0.0)
    acc = accel_spi_ready(sim)
    start_accel_fifo(acc, clock)
    clock.advance(1000 * MS)  # 1600 frames, 1454 of them overwritten
    fifo = drain_accel(acc)
    assert sim.accel.frames_dropped > 255
    assert abs(sim.accel.frames_dropped - (1600 - 146)) <= 1
    assert fifo.skipped_before == [(0, 0xFF)]
    assert len(fifo.accel) == 146


def test_fifo_mode_stops_when_full_and_keeps_the_oldest() -> None:
    sim, clock = make(clock_error=0.0)
    acc = accel_spi_ready(sim)
    start_accel_fifo(acc, clock)
    acc.write_u8(A.FIFO_CONFIG_0, 0x01)  # FIFO mode; bit 1 reads 1 whatever is written
    assert acc.read_u8(A.FIFO_CONFIG_0) == 0x03
    acc.write_u8(A.ACC_SOFTRESET, R.ACC_FIFO_FLUSH_CMD)
    clock.advance(200 * MS)
    newest = accel_data(acc)
    assert accel_length(acc) == 146 * 7  # no skip frame in FIFO mode
    fifo = drain_accel(acc)
    assert len(fifo.accel) == 146 and fifo.skipped_before == []
    assert fifo.accel[-1].tolist() != newest  # the FIFO stopped 146 frames in
    assert abs(sim.accel.frames_dropped - (320 - 146)) <= 1


def test_over_read_gives_sensortime_then_0x80() -> None:
    sim, clock = make(clock_error=0.0)
    acc = accel_spi_ready(sim)
    start_accel_fifo(acc, clock)
    drain_accel(acc)
    clock.advance(5 * MS)  # 8 frames
    n = accel_length(acc) // 7
    assert n in (7, 8)
    data = acc.read(A.FIFO_DATA, 7 * n + 20)
    assert data[7 * n] == R.AccFifoHeader.SENSORTIME
    assert set(data[7 * n + 4 :]) == {R.AccFifoHeader.OVER_READ}
    fifo = d.decode_accel_fifo(data)
    assert len(fifo.accel) == n and fifo.over_read and fifo.sensortime is not None
    assert fifo.sensortime == int.from_bytes(data[7 * n + 1 : 7 * n + 4], "little")
    # the sensortime frame holds the same counter as SENSORTIME_0..2, read at the same instant
    assert fifo.sensortime == int.from_bytes(acc.read(A.SENSORTIME_0, 3), "little")
    assert accel_length(acc) == 0


@pytest.mark.parametrize("clock_error", [0.01, -0.02])
def test_sensortime_ticks_39_0625_us_on_the_dies_clock(clock_error: float) -> None:
    sim, clock = make(clock_error=clock_error)
    acc = accel_spi_ready(sim)

    def sensortime() -> int:
        data = acc.read(A.FIFO_DATA, 8)  # empty FIFO: sensortime frame, then over-read
        assert data[0] == R.AccFifoHeader.SENSORTIME and data[4:] == bytes([0x80] * 4)
        st = d.decode_accel_fifo(data).sensortime
        assert st is not None
        return st

    t0 = sensortime()
    clock.advance(1_000 * MS)
    ticks = sensortime() - t0
    nominal = 1.0 / 39.0625e-6  # 25600 ticks a second
    assert ticks == pytest.approx(nominal * (1 + clock_error), abs=1)
    assert abs(ticks - nominal) > 200  # counted on the die's oscillator


def test_fifo_flush_empties_the_fifo_and_keeps_the_config() -> None:
    sim, clock = make(clock_error=0.0)
    acc = accel_spi_ready(sim)
    start_accel_fifo(acc, clock)
    clock.advance(200 * MS)  # overflowed: frames and a pending skip frame
    assert accel_length(acc) == 1024
    acc.write_u8(A.ACC_SOFTRESET, R.ACC_FIFO_FLUSH_CMD)
    assert accel_length(acc) == 0
    assert acc.read_u8(A.ACC_CHIP_ID) == 0x1E  # not a reset: still in SPI mode, not busy
    assert acc.read_u8(A.ACC_CONF) == ACC_NORMAL_1600
    assert acc.read_u8(A.FIFO_CONFIG_1) == 0x50
    clock.advance(5 * MS)
    fifo = drain_accel(acc)
    assert fifo.skipped_before == []  # the overflow was flushed with the frames
    assert 7 <= len(fifo.accel) <= 8


def test_partly_read_frame_stays_in_the_fifo() -> None:
    sim, clock = make(clock_error=0.0)
    acc = accel_spi_ready(sim)
    start_accel_fifo(acc, clock)
    drain_accel(acc)
    clock.advance(2 * MS)  # 3 frames at 1600 Hz (0.625 ms)
    assert accel_length(acc) == 21
    first = acc.read(A.FIFO_DATA, 10)  # one frame and 3 bytes of the next
    assert accel_length(acc) == 14
    rest = acc.read(A.FIFO_DATA, 14)
    assert rest[:3] == first[7:10]
    assert len(d.decode_accel_fifo(first[:7] + rest).accel) == 3


# --- accel die: temperature ----------------------------------------------------------------------


@pytest.mark.parametrize("temp_c", [23.0, 25.0, 31.3, 80.0, -10.06, -39.9])
def test_temperature_register_decodes_to_the_set_temperature(temp_c: float) -> None:
    sim, _ = make(temperature_c=temp_c)
    acc = accel_spi_ready(sim)
    msb, lsb = acc.read(A.TEMP_MSB, 2)
    assert lsb & 0x1F == 0  # only bits 7:5 of TEMP_LSB carry data
    assert d.temperature_c(msb, lsb) == pytest.approx(temp_c, abs=0.125)


@pytest.mark.parametrize(
    ("temp_c", "msb", "lsb"),
    [
        (31.25, 0x08, 0x40),  # (31.25 - 23) / 0.125 = 66 = 0b000_0100_0010
        (23.0, 0x00, 0x00),
        (-10.0, 0xDF, 0x00),  # -264 -> 2048 - 264 = 1784 = 0b110_1111_1000
    ],
)
def test_temperature_register_bytes(temp_c: float, msb: int, lsb: int) -> None:
    sim, _ = make(temperature_c=temp_c)
    acc, _ = i2c_dies(sim)
    assert acc.read(A.TEMP_MSB, 2) == bytes([msb, lsb])


@pytest.mark.parametrize(
    ("temp_c", "msb", "lsb"),
    [
        # below what the 11-bit code holds: the lowest reading, -1016 (TEMP_MSB 0x81), never
        # TEMP_MSB 0x80, which the datasheet reserves for "invalid" (DS 5.3.7)
        (-150.0, 0x81, 0x00),
        (-104.0, 0x81, 0x00),  # (-104 - 23) / 0.125 = -1016
        (200.0, 0x7F, 0xE0),  # above: the highest, +1023
    ],
)
def test_temperature_out_of_range_saturates_and_is_never_the_invalid_code(
    temp_c: float, msb: int, lsb: int
) -> None:
    sim, _ = make(temperature_c=temp_c, temperature_limits_c=(-300.0, 300.0))
    acc, _ = i2c_dies(sim)
    assert acc.read(A.TEMP_MSB, 2) == bytes([msb, lsb])
    assert not math.isnan(d.temperature_c(msb, lsb))


def test_temperature_register_updates_every_1_28_s() -> None:
    sim, clock = make(temperature_c=25.0, temperature_ramp_c_per_min=60.0)  # 1 C a second
    acc, _ = i2c_dies(sim)
    t0 = clock.now_ns()
    power_on(acc, clock)

    def temp_at(t_s: float) -> float:
        clock.advance(t0 + int(t_s * 1e9) - clock.now_ns())
        return d.temperature_c(*acc.read(A.TEMP_MSB, 2))

    assert temp_at(1.2) == 25.0  # not updated yet
    assert temp_at(1.35) == pytest.approx(26.28, abs=0.125)  # the sample at 1.28 s
    assert temp_at(2.5) == pytest.approx(26.28, abs=0.125)  # held
    assert temp_at(2.62) == pytest.approx(27.56, abs=0.125)  # the sample at 2.56 s


def test_temperature_after_soft_reset_is_the_current_one() -> None:
    sim, clock = make(temperature_c=25.0, temperature_ramp_c_per_min=60.0)
    acc, _ = i2c_dies(sim)
    power_on(acc, clock)
    clock.advance(12_000 * MS)  # the die is at about 37 C now
    assert d.temperature_c(*acc.read(A.TEMP_MSB, 2)) > 35.0
    acc.write_u8(A.ACC_SOFTRESET, R.SOFTRESET_CMD)
    clock.advance(2 * MS)
    assert d.temperature_c(*acc.read(A.TEMP_MSB, 2)) > 35.0


# --- gyro die ----------------------------------------------------------------------------------


def test_gyro_chip_id() -> None:
    sim, _ = make()
    acc, gyr = i2c_dies(sim)
    assert gyr.read_u8(G.GYRO_CHIP_ID) == 0x0F
    assert acc.read_u8(A.ACC_CHIP_ID) == 0x1E  # the two dies answer on their own addresses


def test_gyro_soft_reset_reads_zeros_for_30ms() -> None:
    sim, clock = make()
    acc, gyr = i2c_dies(sim)
    acc.write_u8(A.ACC_RANGE, 0x02)
    gyr.write_u8(G.GYRO_RANGE, 0x03)
    gyr.write_u8(G.GYRO_BANDWIDTH, 0x02)
    gyr.write_u8(G.FIFO_CONFIG_1, GYR_FIFO_MODE)
    clock.advance(10 * MS)
    assert gyro_status(gyr)[1] > 0
    gyr.write_u8(G.GYRO_SOFTRESET, R.SOFTRESET_CMD)
    clock.advance(10 * MS)
    gyr.write_u8(G.GYRO_RANGE, 0x02)  # ignored while busy
    clock.advance(19_900_000)  # 29.9 ms
    assert gyr.read_u8(G.GYRO_CHIP_ID) == 0x00
    assert gyr.read(G.GYRO_RANGE, 2) == bytes(2)
    clock.advance(100_000)  # 30 ms
    assert gyr.read_u8(G.GYRO_CHIP_ID) == 0x0F
    assert gyr.read_u8(G.GYRO_RANGE) == 0x00
    assert gyr.read_u8(G.GYRO_BANDWIDTH) == 0x80
    assert gyr.read_u8(G.FIFO_CONFIG_1) == 0x00
    assert gyro_status(gyr) == (False, 0)
    assert acc.read_u8(A.ACC_RANGE) == 0x02  # the accel die is not reset


def test_accel_soft_reset_leaves_the_gyro_alone() -> None:
    sim, _ = make()
    acc, gyr = i2c_dies(sim)
    gyr.write_u8(G.GYRO_RANGE, 0x03)
    acc.write_u8(A.ACC_SOFTRESET, R.SOFTRESET_CMD)
    assert gyr.read_u8(G.GYRO_CHIP_ID) == 0x0F  # not busy
    assert gyr.read_u8(G.GYRO_RANGE) == 0x03


@pytest.mark.parametrize("code", sorted(GYR_ODR_CODES))
def test_gyro_bandwidth_reads_back_with_bit7_and_sets_the_odr(code: int) -> None:
    sim, clock = make(clock_error=0.0)
    _, gyr = i2c_dies(sim)
    gyr.write_u8(G.GYRO_BANDWIDTH, code)
    assert gyr.read_u8(G.GYRO_BANDWIDTH) == 0x80 | code
    gyr.write_u8(G.FIFO_CONFIG_1, GYR_FIFO_MODE)
    odr = GYR_ODR_CODES[code]
    clock.advance(int(40 / odr * 1e9))  # 40 periods at the table's ODR
    overrun, n = gyro_status(gyr)
    assert not overrun and n in (39, 40), n
    assert sim.gyro.rate_hz == odr


def test_gyro_bandwidth_code_0x02_gives_1000_hz() -> None:
    sim, clock = make(clock_error=0.0)
    _, gyr = i2c_dies(sim)
    gyr.write_u8(G.FIFO_CONFIG_1, GYR_FIFO_MODE)
    clock.advance(20 * MS)
    assert gyro_status(gyr)[1] in (39, 40)  # reset: 2000 Hz
    gyr.write_u8(G.GYRO_BANDWIDTH, 0x02)
    drain_gyro(gyr)
    clock.advance(20 * MS)
    assert gyro_status(gyr)[1] in (19, 20)  # 1000 Hz


@pytest.mark.parametrize("bad", [0x08, 0x0F, 0x8A])
def test_gyro_invalid_bandwidth_code_ignored(bad: int) -> None:
    sim, _ = make()
    _, gyr = i2c_dies(sim)
    gyr.write_u8(G.GYRO_BANDWIDTH, 0x03)
    gyr.write_u8(G.GYRO_BANDWIDTH, bad)
    assert gyr.read_u8(G.GYRO_BANDWIDTH) == 0x83


def test_gyro_range_codes_above_4_ignored() -> None:
    sim, _ = make()
    _, gyr = i2c_dies(sim)
    gyr.write_u8(G.GYRO_RANGE, 0x03)
    assert gyr.read_u8(G.GYRO_RANGE) == 0x03
    for bad in (0x05, 0x07, 0xFF):
        gyr.write_u8(G.GYRO_RANGE, bad)
        assert gyr.read_u8(G.GYRO_RANGE) == 0x03
    gyr.write_u8(G.GYRO_RANGE, 0x04)
    assert gyr.read_u8(G.GYRO_RANGE) == 0x04


def test_gyro_ignores_writes_to_read_only_and_unknown_registers() -> None:
    sim, _ = make()
    _, gyr = i2c_dies(sim)
    for reg in (G.GYRO_CHIP_ID, G.FIFO_STATUS, 0x20, 0x7F):
        before = gyr.read_u8(reg)
        gyr.write_u8(reg, 0x5A)
        assert gyr.read_u8(reg) == before


def test_gyro_bypass_mode_keeps_no_frames() -> None:
    sim, clock = make()
    _, gyr = i2c_dies(sim)
    assert gyr.read_u8(G.FIFO_CONFIG_1) == 0x00
    clock.advance(100 * MS)
    assert gyro_status(gyr) == (False, 0)
    assert gyro_data(gyr) != [0, 0, 0]  # sampling all the same: the data registers (bias, noise)


def test_gyro_fifo_mode_stops_when_full_with_overrun() -> None:
    sim, clock = make(clock_error=0.0)
    _, gyr = i2c_dies(sim)
    gyr.write_u8(G.FIFO_CONFIG_1, GYR_FIFO_MODE)
    clock.advance(20 * MS)  # 40 frames at 2000 Hz
    overrun, n = gyro_status(gyr)
    assert not overrun and n in (39, 40)
    clock.advance(80 * MS)  # 200 frames in all: 100 kept
    assert gyr.read_u8(G.FIFO_STATUS) == 0x80 | 100
    newest = gyro_data(gyr)
    frames = drain_gyro(gyr)
    assert frames.shape == (100, 3)
    assert frames[-1].tolist() != newest  # stopped when full: the newest were dropped
    assert abs(sim.gyro.frames_dropped - 100) <= 1
    assert gyro_status(gyr) == (True, 0)  # overrun stays until FIFO_CONFIG_1 is written


def test_gyro_stream_mode_keeps_the_newest() -> None:
    sim, clock = make(clock_error=0.0)
    _, gyr = i2c_dies(sim)
    gyr.write_u8(G.FIFO_CONFIG_1, GYR_STREAM_MODE)
    clock.advance(100 * MS)
    assert gyro_status(gyr)[1] == 100
    newest = gyro_data(gyr)
    frames = drain_gyro(gyr)
    assert frames.shape == (100, 3)
    assert frames[-1].tolist() == newest
    assert len({tuple(r) for r in frames.tolist()}) > 50  # real samples, not one repeated
    assert abs(sim.gyro.frames_dropped - 100) <= 1


def test_gyro_fifo_config_0_write_empties_the_fifo_and_clears_overrun() -> None:
    sim, clock = make(clock_error=0.0)
    _, gyr = i2c_dies(sim)
    gyr.write_u8(G.FIFO_CONFIG_1, GYR_FIFO_MODE)
    clock.advance(100 * MS)
    assert gyro_status(gyr) == (True, 100)
    gyr.write_u8(G.FIFO_CONFIG_0, 0x00)
    assert gyro_status(gyr) == (False, 0)
    assert gyr.read_u8(G.FIFO_CONFIG_1) == GYR_FIFO_MODE  # mode kept: it fills again
    clock.advance(5 * MS)
    assert gyro_status(gyr)[1] in (9, 10)


def test_gyro_fifo_config_1_write_clears_overrun_and_keeps_the_frames() -> None:
    sim, clock = make(clock_error=0.0)
    _, gyr = i2c_dies(sim)
    gyr.write_u8(G.FIFO_CONFIG_1, GYR_FIFO_MODE)
    clock.advance(100 * MS)
    assert gyro_status(gyr) == (True, 100)
    gyr.write_u8(G.FIFO_CONFIG_1, GYR_FIFO_MODE)
    assert gyro_status(gyr) == (False, 100)
    assert drain_gyro(gyr).shape == (100, 3)
    clock.advance(5 * MS)
    overrun, n = gyro_status(gyr)
    assert not overrun and n in (9, 10)  # room again: it keeps filling


def test_gyro_fifo_over_read_pads_with_zeros() -> None:
    sim, clock = make(clock_error=0.0)
    _, gyr = i2c_dies(sim)
    gyr.write_u8(G.FIFO_CONFIG_1, GYR_FIFO_MODE)
    clock.advance(5 * MS)
    _, n = gyro_status(gyr)
    data = gyr.read(G.FIFO_DATA, 6 * n + 12)
    assert data[6 * n :] == bytes(12)
    assert gyro_status(gyr) == (False, 0)


# --- physics -----------------------------------------------------------------------------------


@pytest.mark.parametrize("range_code", [0, 4])  # 2000 and 125 dps
def test_tumble_about_z_reads_1_745_rad_s(range_code: int) -> None:
    sim, clock = make(motion={"kind": "tumble", "rate_dps": (0, 0, 100)}, errors={"ideal": True})
    _, gyr = i2c_dies(sim)
    gyr.write_u8(G.GYRO_RANGE, range_code)
    gyr.write_u8(G.GYRO_BANDWIDTH, 0x02)  # 1000 Hz
    gyr.write_u8(G.FIFO_CONFIG_1, GYR_FIFO_MODE)
    clock.advance(90 * MS)
    counts = drain_gyro(gyr)
    assert counts.shape[0] >= 80
    scale = d.gyro_scale_rads(R.GYRO_RANGES_DPS[range_code])
    rate = counts.mean(axis=0) * scale
    assert rate[2] == pytest.approx(math.radians(100), abs=2e-3)  # 1.745 rad/s
    assert np.abs(rate[:2]).max() < 2e-3
    # the counts themselves: 100 dps at 16.384 (2000 dps) or 262.144 (125 dps) LSB per dps
    lsb_per_dps = {0: 16.384, 4: 262.144}[range_code]
    assert counts[:, 2].mean() == pytest.approx(100 * lsb_per_dps, rel=0.01)


@pytest.mark.parametrize("range_code", [0, 1, 2, 3])  # 3, 6, 12, 24 g
def test_accel_at_rest_reads_one_g(range_code: int) -> None:
    sim, clock = make(errors={"ideal": True})
    acc = accel_spi_ready(sim)
    start_accel_fifo(acc, clock)
    acc.write_u8(A.ACC_RANGE, range_code)
    drain_accel(acc)
    clock.advance(60 * MS)
    fifo = drain_accel(acc)
    assert len(fifo.accel) >= 90
    range_g = R.ACCEL_RANGES_G[range_code]
    ms2 = fifo.accel.mean(axis=0) * d.accel_scale_ms2(range_g)
    assert float(np.linalg.norm(ms2)) == pytest.approx(9.81, abs=0.02)
    assert ms2[2] == pytest.approx(GRAVITY, abs=0.02)  # level: +g along body z
    assert fifo.accel[:, 2].mean() == pytest.approx(32768 / range_g, rel=0.005)  # 1 g in LSB


def test_accel_tilted_at_rest_reads_gravity_components() -> None:
    roll, pitch = 30.0, -20.0
    sim, clock = make(
        motion={"kind": "still", "roll_deg": roll, "pitch_deg": pitch}, errors={"ideal": True}
    )
    acc, _ = i2c_dies(sim)
    start_accel_fifo(acc, clock)
    drain_accel(acc)
    clock.advance(60 * MS)
    fifo = drain_accel(acc)  # 96 frames: 672 bytes, past the SMBus block limit
    assert len(fifo.accel) >= 90
    ms2 = fifo.accel.mean(axis=0) * d.accel_scale_ms2(6)  # reset range: 6 g
    r, p = math.radians(roll), math.radians(pitch)
    g = GRAVITY
    expect = [-g * math.sin(p), g * math.cos(p) * math.sin(r), g * math.cos(p) * math.cos(r)]
    assert ms2 == pytest.approx(expect, abs=0.02)
    assert float(np.linalg.norm(ms2)) == pytest.approx(g, abs=0.02)


# --- two oscillators -----------------------------------------------------------------------------


def count_frames(sim: Bmi088Sim, clock: VirtualClock, seconds: float) -> tuple[int, int]:
    """Frames both dies produce in `seconds`, accel at 100 Hz and gyro at 100 Hz (code 0x07)."""
    acc, gyr = i2c_dies(sim)
    start_accel_fifo(acc, clock, conf=0xA8)
    gyr.write_u8(G.GYRO_BANDWIDTH, 0x07)
    gyr.write_u8(G.FIFO_CONFIG_1, GYR_FIFO_MODE)
    drain_accel(acc)
    drain_gyro(gyr)
    n_acc = n_gyr = 0
    for _ in range(round(seconds / 0.5)):
        clock.advance(500 * MS)
        n_acc += len(drain_accel(acc).accel)
        n_gyr += drain_gyro(gyr).shape[0]
    return n_acc, n_gyr


def test_the_dies_have_different_oscillators() -> None:
    sim, clock = make(seed=0)
    ea, eg = sim.accel.clock_error, sim.gyro.clock_error
    assert ea != eg
    assert 0 < abs(ea) <= 0.015 and 0 < abs(eg) <= 0.015
    n_acc, n_gyr = count_frames(sim, clock, 10.0)
    assert abs(n_acc - 1000 * (1 + ea)) <= 1
    assert abs(n_gyr - 1000 * (1 + eg)) <= 1
    assert n_acc != n_gyr  # same nominal rate, different counts


def test_clock_errors_are_drawn_from_the_seed() -> None:
    a, _ = make(seed=7)
    b, _ = make(seed=7)
    c, _ = make(seed=8)
    assert (a.accel.clock_error, a.gyro.clock_error) == (b.accel.clock_error, b.gyro.clock_error)
    assert a.accel.clock_error != c.accel.clock_error
    assert a.gyro.clock_error != c.gyro.clock_error


def test_clock_error_setting_pins_both_dies() -> None:
    sim, clock = make(clock_error=-0.01)
    assert sim.accel.clock_error == sim.gyro.clock_error == -0.01
    n_acc, n_gyr = count_frames(sim, clock, 10.0)
    assert abs(n_acc - 990) <= 1 and abs(n_gyr - 990) <= 1
    ideal, _ = make(errors={"ideal": True})
    assert ideal.accel.clock_error == ideal.gyro.clock_error == 0.0


def test_the_dies_share_one_body() -> None:
    sim, _ = make()
    assert sim.accel.t_origin_ns == sim.gyro.t_origin_ns
    # attached die by die, in the order of the chip's spec
    assert [die.name for die in SPEC.dies] == ["accel", "gyro"]
    assert tuple(sim.dies) == (sim.accel, sim.gyro)
