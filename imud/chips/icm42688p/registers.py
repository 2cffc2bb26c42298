"""ICM-42688-P register map: banks 0-2, bits, field codes, FIFO packet header (docs/chips/
icm42688p.md). Shared by the driver and the simulator; scales and decoding are not here."""

from __future__ import annotations

from enum import IntEnum, IntFlag

from imud.chips.bits import BitField


class Bank0(IntEnum):
    DEVICE_CONFIG = 0x11
    FIFO_CONFIG = 0x16
    TEMP_DATA1 = 0x1D
    ACCEL_DATA_X1 = 0x1F
    GYRO_DATA_X1 = 0x25
    INT_STATUS = 0x2D
    FIFO_COUNTH = 0x2E
    FIFO_COUNTL = 0x2F
    FIFO_DATA = 0x30
    SIGNAL_PATH_RESET = 0x4B
    INTF_CONFIG0 = 0x4C
    INTF_CONFIG1 = 0x4D
    PWR_MGMT0 = 0x4E
    GYRO_CONFIG0 = 0x4F
    ACCEL_CONFIG0 = 0x50
    GYRO_ACCEL_CONFIG0 = 0x52
    TMST_CONFIG = 0x54
    FIFO_CONFIG1 = 0x5F
    WHO_AM_I = 0x75
    REG_BANK_SEL = 0x76  # in every bank


class Bank1(IntEnum):
    GYRO_CONFIG_STATIC2 = 0x0B
    GYRO_CONFIG_STATIC3 = 0x0C
    GYRO_CONFIG_STATIC4 = 0x0D
    GYRO_CONFIG_STATIC5 = 0x0E


class Bank2(IntEnum):
    ACCEL_CONFIG_STATIC2 = 0x03
    ACCEL_CONFIG_STATIC3 = 0x04
    ACCEL_CONFIG_STATIC4 = 0x05


class DeviceConfig(IntFlag):
    SOFT_RESET_CONFIG = 0x01


FIFO_MODE = BitField(0xC0)  # FIFO_CONFIG[7:6]
FIFO_MODE_BYPASS = 0
FIFO_MODE_STREAM = 1
FIFO_MODE_STOP_ON_FULL = 2  # 3 also stops on full


class IntStatus(IntFlag):
    UI_FSYNC_INT = 0x40
    PLL_RDY_INT = 0x20
    RESET_DONE_INT = 0x10
    DATA_RDY_INT = 0x08
    FIFO_THS_INT = 0x04
    FIFO_FULL_INT = 0x02
    AGC_RDY_INT = 0x01


class SignalPathReset(IntFlag):
    ABORT_AND_RESET = 0x08
    TMST_STROBE = 0x04
    FIFO_FLUSH = 0x02


class IntfConfig0(IntFlag):
    FIFO_HOLD_LAST_DATA_EN = 0x80
    FIFO_COUNT_REC = 0x40  # 1: count in records (packets), 0: in bytes
    FIFO_COUNT_ENDIAN = 0x20  # 1: big-endian
    SENSOR_DATA_ENDIAN = 0x10  # 1: big-endian


INTF_CONFIG1_AFSR = BitField(0xC0)  # undocumented auto-ranging; 0b01 turns it off (ArduPilot)
AFSR_OFF = 1


class PwrMgmt0(IntFlag):
    TEMP_DIS = 0x20
    IDLE = 0x10


GYRO_MODE = BitField(0x0C)
ACCEL_MODE = BitField(0x03)
MODE_LOW_NOISE = 3

GYRO_FS_SEL = BitField(0xE0)  # GYRO_CONFIG0[7:5]
GYRO_ODR = BitField(0x0F)  # GYRO_CONFIG0[3:0]
ACCEL_FS_SEL = BitField(0xE0)  # ACCEL_CONFIG0[7:5]
ACCEL_ODR = BitField(0x0F)
ACCEL_UI_FILT_BW = BitField(0xF0)  # GYRO_ACCEL_CONFIG0[7:4]
GYRO_UI_FILT_BW = BitField(0x0F)  # GYRO_ACCEL_CONFIG0[3:0]


class TmstConfig(IntFlag):
    TMST_TO_REGS_EN = 0x10
    TMST_RES = 0x08  # 1: 16 us, 0: 1 us
    TMST_DELTA_EN = 0x04
    TMST_FSYNC_EN = 0x02
    TMST_EN = 0x01


class FifoConfig1(IntFlag):
    RESUME_PARTIAL_RD = 0x40
    WM_GT_TH = 0x20
    HIRES_EN = 0x10
    TMST_FSYNC_EN = 0x08
    TEMP_EN = 0x04
    GYRO_EN = 0x02
    ACCEL_EN = 0x01


class Header(IntFlag):
    """First byte of every FIFO packet."""

    MSG = 0x80  # FIFO empty: no packet
    ACCEL = 0x40
    GYRO = 0x20
    HIRES_20 = 0x10  # new valid 20-bit data (packet 4)
    ODR_ACCEL = 0x02
    ODR_GYRO = 0x01


HEADER_TMST_FSYNC = BitField(0x0C)
TMST_FSYNC_ODR = 0b10  # the timestamp field holds the ODR timestamp


class GyroConfigStatic2(IntFlag):
    GYRO_AAF_DIS = 0x02
    GYRO_NF_DIS = 0x01


GYRO_AAF_DELT = BitField(0x3F)  # GYRO_CONFIG_STATIC3
GYRO_AAF_DELTSQR_LO = BitField(0xFF)  # GYRO_CONFIG_STATIC4
GYRO_AAF_BITSHIFT = BitField(0xF0)  # GYRO_CONFIG_STATIC5[7:4]
GYRO_AAF_DELTSQR_HI = BitField(0x0F)  # GYRO_CONFIG_STATIC5[3:0]
ACCEL_AAF_DELT = BitField(0x7E)  # ACCEL_CONFIG_STATIC2[6:1]
ACCEL_AAF_DIS = 0x01  # ACCEL_CONFIG_STATIC2[0]
ACCEL_AAF_DELTSQR_LO = BitField(0xFF)  # ACCEL_CONFIG_STATIC3
ACCEL_AAF_BITSHIFT = BitField(0xF0)  # ACCEL_CONFIG_STATIC4[7:4]
ACCEL_AAF_DELTSQR_HI = BitField(0x0F)  # ACCEL_CONFIG_STATIC4[3:0]

WHO_AM_I_VALUE = 0x47
GYRO_RANGES_DPS: tuple[float, ...] = (2000.0, 1000.0, 500.0, 250.0, 125.0, 62.5, 31.25, 15.625)
ACCEL_RANGES_G = (16, 8, 4, 2)  # ACCEL_FS_SEL 0..3
ODR_CODES: dict[float, int] = {
    32000.0: 1, 16000.0: 2, 8000.0: 3, 4000.0: 4, 2000.0: 5, 1000.0: 6,
    500.0: 15, 200.0: 7, 100.0: 8, 50.0: 9, 25.0: 10, 12.5: 11,
}  # fmt: skip
UI_FILTER_CODES: dict[str, int] = {
    "odr/2": 0, "odr/4": 1, "odr/5": 2, "odr/8": 3, "odr/10": 4, "odr/16": 5, "odr/20": 6,
    "odr/40": 7, "low_latency": 14, "low_latency_8x": 15,
}  # fmt: skip
# Anti-alias filter: 3 dB bandwidth (Hz) -> (DELT, DELTSQR, BITSHIFT)
AAF_TABLE: dict[int, tuple[int, int, int]] = {
    42: (1, 1, 15), 84: (2, 4, 13), 126: (3, 9, 12), 170: (4, 16, 11), 213: (5, 25, 10),
    258: (6, 36, 10), 303: (7, 49, 9), 348: (8, 64, 9), 394: (9, 81, 9), 441: (10, 100, 8),
    488: (11, 122, 8), 536: (12, 144, 8), 585: (13, 170, 8), 634: (14, 196, 7), 684: (15, 224, 7),
    734: (16, 256, 7), 785: (17, 288, 7), 837: (18, 324, 7), 890: (19, 360, 6), 943: (20, 400, 6),
    997: (21, 440, 6), 1051: (22, 488, 6), 1107: (23, 528, 6), 1163: (24, 576, 6),
    1220: (25, 624, 6), 1277: (26, 680, 6), 1336: (27, 736, 5), 1395: (28, 784, 5),
    1454: (29, 848, 5), 1515: (30, 896, 5), 1577: (31, 960, 5), 1639: (32, 1024, 5),
    1702: (33, 1088, 5), 1766: (34, 1152, 5), 1830: (35, 1232, 5), 1896: (36, 1296, 5),
    1962: (37, 1376, 4), 2029: (38, 1440, 4), 2097: (39, 1536, 4), 2166: (40, 1600, 4),
    2235: (41, 1696, 4), 2306: (42, 1760, 4), 2377: (43, 1856, 4), 2449: (44, 1952, 4),
    2522: (45, 2016, 4), 2596: (46, 2112, 4), 2671: (47, 2208, 4), 2746: (48, 2304, 4),
    2823: (49, 2400, 4), 2900: (50, 2496, 4), 2978: (51, 2592, 4), 3057: (52, 2720, 4),
    3137: (53, 2816, 3), 3217: (54, 2944, 3), 3299: (55, 3008, 3), 3381: (56, 3136, 3),
    3464: (57, 3264, 3), 3548: (58, 3392, 3), 3633: (59, 3456, 3), 3718: (60, 3584, 3),
    3805: (61, 3712, 3), 3892: (62, 3840, 3), 3979: (63, 3968, 3),
}  # fmt: skip
AAF_DEFAULT_GYRO_HZ = 585  # the reset rows
AAF_DEFAULT_ACCEL_HZ = 1163

FIFO_SIZE = 2048  # bytes
PACKET3_BYTES = 16  # accel + gyro + int8 temperature + 16-bit timestamp
PACKET4_BYTES = 20  # the same with 20-bit data and an int16 temperature
INVALID_16 = -32768  # a sensor's three axes (or the temperature) with no valid data
INVALID_20 = -(2**19)
INVALID_TEMP_8 = -128  # the int8 FIFO temperature's invalid value
TIMESTAMP_MODULO = 1 << 16  # the FIFO timestamp field
# FIFO timestamp tick (TMST_RES = 0) on the internal clock: 1 us x 32/30 (PLL 19.2 MHz; TDK eMD).
# It counts on the oscillator the samples are made on, so ticks per sample do not depend on the
# oscillator's error (an external CLKIN would change the ratio).
TICK_NS = 1000.0 * 32 / 30
RESET_WAIT_NS = 2_000_000  # 1 ms after SOFT_RESET_CONFIG, with margin
POWER_ON_WAIT_NS = 300_000  # no register write within 200 us of a PWR_MGMT0 change
STARTUP_WAIT_NS = 60_000_000  # gyro start-up before its data is valid (TDK, Linux: 60 ms)
MAX_SPI_HZ = 24_000_000
