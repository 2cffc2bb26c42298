"""BMI088 register maps of both dies: addresses, bits, field codes, FIFO frame headers
(docs/chips/bmi088.md). Shared by the driver and the simulators; scales and decoding are not
here."""

from __future__ import annotations

from enum import IntEnum, IntFlag

from imud.chips.bits import BitField


class AccelRegister(IntEnum):
    ACC_CHIP_ID = 0x00
    ACC_ERR_REG = 0x02
    ACC_STATUS = 0x03
    ACC_X_LSB = 0x12  # X LSB .. Z MSB, little-endian int16
    SENSORTIME_0 = 0x18  # 24-bit, little-endian
    TEMP_MSB = 0x22
    TEMP_LSB = 0x23
    FIFO_LENGTH_0 = 0x24
    FIFO_LENGTH_1 = 0x25
    FIFO_DATA = 0x26
    ACC_CONF = 0x40
    ACC_RANGE = 0x41
    FIFO_DOWNS = 0x45
    FIFO_WTM_0 = 0x46
    FIFO_WTM_1 = 0x47
    FIFO_CONFIG_0 = 0x48
    FIFO_CONFIG_1 = 0x49
    INT1_IO_CONF = 0x53
    INT2_IO_CONF = 0x54
    INT1_INT2_MAP_DATA = 0x58
    ACC_PWR_CONF = 0x7C
    ACC_PWR_CTRL = 0x7D
    ACC_SOFTRESET = 0x7E  # commands: soft reset, FIFO flush


class GyroRegister(IntEnum):
    GYRO_CHIP_ID = 0x00
    RATE_X_LSB = 0x02  # X LSB .. Z MSB, little-endian int16
    FIFO_STATUS = 0x0E
    GYRO_RANGE = 0x0F
    GYRO_BANDWIDTH = 0x10
    GYRO_LPM1 = 0x11
    GYRO_SOFTRESET = 0x14
    GYRO_INT_CTRL = 0x15
    INT3_INT4_IO_CONF = 0x16
    INT3_INT4_IO_MAP = 0x18
    FIFO_WM_ENABLE = 0x1E
    FIFO_CONFIG_0 = 0x3D  # watermark; writing it empties the FIFO
    FIFO_CONFIG_1 = 0x3E  # mode; writing it clears the overrun flag
    FIFO_DATA = 0x3F


ACC_CHIP_ID_VALUE = 0x1E
GYRO_CHIP_ID_VALUE = 0x0F
SOFTRESET_CMD = 0xB6  # to ACC_SOFTRESET or GYRO_SOFTRESET
ACC_FIFO_FLUSH_CMD = 0xB0  # to ACC_SOFTRESET

TEMP_INVALID_MSB = 0x80  # TEMP_MSB when there is no valid temperature reading
ACC_CONF_BWP = BitField(0xF0)
ACC_CONF_ODR = BitField(0x0F)
ACC_RANGE_FIELD = BitField(0x03)
ACC_PWR_CONF_ACTIVE = 0x00
ACC_PWR_CONF_SUSPEND = 0x03
ACC_PWR_CTRL_ON = 0x04
ACC_PWR_CTRL_OFF = 0x00


class AccStatus(IntFlag):
    ACC_DRDY = 0x80


class AccFifoConfig0(IntFlag):
    MUST_BE_ONE = 0x02
    FIFO_MODE = 0x01  # 1: stop when full; 0: stream (overwrite the oldest)


class AccFifoConfig1(IntFlag):
    ACC_EN = 0x40
    MUST_BE_ONE = 0x10
    INT1_INPUT_EN = 0x08
    INT2_INPUT_EN = 0x04


FIFO_LENGTH_1_BITS = BitField(0x3F)  # bits 13:8 of the byte count
FIFO_LENGTH_EMPTY = 0x8000  # drivers treat a length with bit 15 set as empty


class AccFifoHeader(IntEnum):
    """Frame headers, matched on `header & 0xFC` (bits 1:0 are interrupt tags)."""

    ACCEL = 0x84
    SKIP = 0x40
    SENSORTIME = 0x44
    INPUT_CONFIG = 0x48
    SAMPLE_DROP = 0x50
    OVER_READ = 0x80


ACC_FIFO_FRAME_BYTES = {
    AccFifoHeader.ACCEL: 7, AccFifoHeader.SKIP: 2, AccFifoHeader.SENSORTIME: 4,
    AccFifoHeader.INPUT_CONFIG: 2, AccFifoHeader.SAMPLE_DROP: 2,
}  # fmt: skip
ACC_FIFO_HEADER_MASK = 0xFC
SKIP_UNKNOWN = 0xFF  # a skip frame's count: more than 255 frames were skipped

GYRO_RANGE_FIELD = BitField(0x07)
GYRO_BANDWIDTH_FIELD = BitField(0x0F)
GYRO_BANDWIDTH_READS_ONE = 0x80  # bit 7 of GYRO_BANDWIDTH reads 1
GYRO_LPM1_NORMAL = 0x00
GYRO_LPM1_SUSPEND = 0x80
GYRO_LPM1_DEEP_SUSPEND = 0x20


class GyroFifoStatus(IntFlag):
    OVERRUN = 0x80


GYRO_FIFO_FRAME_COUNT = BitField(0x7F)
GYRO_FIFO_MODE = BitField(0xC0)  # FIFO_CONFIG_1[7:6]
GYRO_FIFO_MODE_BYPASS = 0
GYRO_FIFO_MODE_FIFO = 1  # stop when full, set overrun
GYRO_FIFO_MODE_STREAM = 2
GYRO_FIFO_DATA_SELECT = BitField(0x03)  # 0: X, Y and Z

ACCEL_RANGES_G = (3, 6, 12, 24)  # ACC_RANGE 0..3
ACCEL_ODR_CODES: dict[float, int] = {
    12.5: 0x5, 25.0: 0x6, 50.0: 0x7, 100.0: 0x8, 200.0: 0x9, 400.0: 0xA, 800.0: 0xB, 1600.0: 0xC,
}  # fmt: skip
ACCEL_BWP_CODES = {"osr4": 0x8, "osr2": 0x9, "normal": 0xA}
GYRO_RANGES_DPS = (2000, 1000, 500, 250, 125)  # GYRO_RANGE 0..4
# GYRO_BANDWIDTH code -> (output data rate Hz, filter bandwidth Hz)
GYRO_BANDWIDTH_CODES: dict[int, tuple[float, int]] = {
    0x0: (2000.0, 532), 0x1: (2000.0, 230), 0x2: (1000.0, 116), 0x3: (400.0, 47),
    0x4: (200.0, 23), 0x5: (100.0, 12), 0x6: (200.0, 64), 0x7: (100.0, 32),
}  # fmt: skip

ACC_FIFO_BYTES = 1024
ACC_FRAME_BYTES = 7
GYRO_FIFO_FRAMES = 100
GYRO_FRAME_BYTES = 6
SENSORTIME_S_PER_LSB = 39.0625e-6
ACC_RESET_WAIT_NS = 1_000_000
GYRO_RESET_WAIT_NS = 30_000_000
ACC_POWER_WAIT_NS = 5_000_000  # after each accel power register write
MAX_SPI_HZ = 10_000_000
