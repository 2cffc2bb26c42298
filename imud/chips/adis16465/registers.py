"""ADIS16465 register map: addresses, DIAG_STAT and GLOB_CMD bits, fields, codes, SPI timing
(docs/chips/adis16465.md). Shared by the driver and the simulator; scales and decoding are not
here.

Registers are 16 bits wide at even addresses (the low byte; the high byte is at address + 1).
A 32-bit output is two registers: `_LOW` (low word) and `_OUT` (high word) at `_LOW` + 2.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag

from imud.chips.bits import BitField


class Register(IntEnum):
    DIAG_STAT = 0x02
    X_GYRO_LOW = 0x04
    X_GYRO_OUT = 0x06
    Y_GYRO_LOW = 0x08
    Y_GYRO_OUT = 0x0A
    Z_GYRO_LOW = 0x0C
    Z_GYRO_OUT = 0x0E
    X_ACCL_LOW = 0x10
    X_ACCL_OUT = 0x12
    Y_ACCL_LOW = 0x14
    Y_ACCL_OUT = 0x16
    Z_ACCL_LOW = 0x18
    Z_ACCL_OUT = 0x1A
    TEMP_OUT = 0x1C
    TIME_STAMP = 0x1E
    DATA_CNTR = 0x22
    X_DELTANG_LOW = 0x24
    X_DELTANG_OUT = 0x26
    Y_DELTANG_LOW = 0x28
    Y_DELTANG_OUT = 0x2A
    Z_DELTANG_LOW = 0x2C
    Z_DELTANG_OUT = 0x2E
    X_DELTVEL_LOW = 0x30
    X_DELTVEL_OUT = 0x32
    Y_DELTVEL_LOW = 0x34
    Y_DELTVEL_OUT = 0x36
    Z_DELTVEL_LOW = 0x38
    Z_DELTVEL_OUT = 0x3A
    FILT_CTRL = 0x5C
    RANG_MDL = 0x5E
    MSC_CTRL = 0x60
    UP_SCALE = 0x62
    DEC_RATE = 0x64
    NULL_CNFG = 0x66
    GLOB_CMD = 0x68  # write only
    FIRM_REV = 0x6C
    FIRM_DM = 0x6E
    FIRM_Y = 0x70
    PROD_ID = 0x72
    SERIAL_NUM = 0x74


class DiagStat(IntFlag):
    """Sticky error flags: a read of DIAG_STAT clears them; a lasting condition sets them
    again."""

    DATAPATH_OVERRUN = 0x0002
    FLASH_UPDATE_FAILURE = 0x0004
    SPI_COMMUNICATION_ERROR = 0x0008  # a frame whose SCLK count is not a multiple of 16
    STANDBY = 0x0010  # VDD < 2.8 V
    SENSOR_FAILURE = 0x0020  # self-test result
    MEMORY_FAILURE = 0x0040  # flash-test CRC
    CLOCK_ERROR = 0x0080  # scaled-sync input clock out of range


class GlobCmd(IntFlag):
    """GLOB_CMD (write only): each bit starts a command; data production stops while it runs."""

    BIAS_CORRECTION_UPDATE = 0x01
    FACTORY_CALIBRATION_RESTORE = 0x02
    SENSOR_SELF_TEST = 0x04
    FLASH_MEMORY_UPDATE = 0x08
    FLASH_MEMORY_TEST = 0x10
    SOFTWARE_RESET = 0x80


class MscCtrl(IntFlag):
    LINEAR_G_COMPENSATION = 0x0080
    POINT_OF_PERCUSSION = 0x0040
    SYNC_POLARITY = 0x0002
    DR_POLARITY = 0x0001  # 1: data ready active high


MSC_CTRL_SYNC_MODE = BitField(0x001C)  # [4:2]
SYNC_MODE_INTERNAL = 0  # 0b010 (scaled sync) puts TIME_STAMP where the burst has DATA_CNTR
# the power-on value: linear-g compensation and point of percussion on, data ready active high
MSC_CTRL_DEFAULT = int(
    MscCtrl.LINEAR_G_COMPENSATION | MscCtrl.POINT_OF_PERCUSSION | MscCtrl.DR_POLARITY
)

FILT_CTRL_SIZE = BitField(0x0007)  # [2:0] B: Bartlett window, two stages of 2^B taps
FILT_CTRL_MAX = 6
DEC_RATE_FIELD = BitField(0x07FF)  # [10:0]
DEC_RATE_MAX = 1999
INTERNAL_RATE_HZ = 2000  # ODR = 2000 / (DEC_RATE + 1), internal clock

RANG_MDL_RANGE = BitField(0x000C)  # [3:2] gyro measurement range (model identifier)
RANG_MDL_READS_ONE = 0x0003  # [1:0] read 11
RANG_MDL_CODES = {1: 0b00, 2: 0b01, 3: 0b11}  # ADIS16465-1/-2/-3 -> RANG_MDL[3:2]
GYRO_RANGES_DPS = {1: 125, 2: 500, 3: 2000}  # measurement range of each model, +-deg/s

PROD_ID_VALUE = 0x4051  # 16465
# PROD_ID of the family members sharing this register map and protocol (the part number)
FAMILY_PROD_IDS = {
    0x4053: "ADIS16467", 0x4056: "ADIS16470", 0x405B: "ADIS16475", 0x405D: "ADIS16477",
    0x4074: "ADIS16500", 0x4079: "ADIS16505", 0x407B: "ADIS16507",
}  # fmt: skip

# --- SPI protocol
WRITE = 0x80  # first byte of a write frame: 0x80 | address, then the data byte
BURST_CMD = 0x6800  # a read of GLOB_CMD starts the burst
BURST_FRAME_BYTES = 22  # 176 SCLKs: the command word, then 10 response words
BURST_CHECKSUM_BYTES = 18  # the checksum word sums the bytes of response words 0-8
DATA_CNTR_MODULO = 65536
READS_PER_DR = 12  # 16-bit register reads per data-ready period at DEC_RATE 0, x(DEC_RATE+1)
SPI_MODE = 3
MAX_SCLK_HZ = 2_000_000
MAX_BURST_SCLK_HZ = 1_000_000
MIN_SCLK_HZ = 100_000
STALL_NS = 16_000  # chip select high between 16-bit register frames
READ_RATE_NS = 24_000  # from one register read to the next

# --- delays
SW_RESET_TIME_NS = 198_000_000  # GLOB_CMD software reset; the SPI port does not respond meanwhile
MSC_CTRL_WAIT_NS = 200_000  # after an MSC_CTRL write
