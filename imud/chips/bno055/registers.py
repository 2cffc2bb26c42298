"""BNO055 register map (pages 0 and 1), bits, field codes, scales, delays and the UART protocol's
bytes (docs/chips/bno055.md). Shared by the driver and the simulator; decoding is not here."""

from __future__ import annotations

from enum import IntEnum, IntFlag

from imud.chips.bits import BitField


class Page0(IntEnum):
    CHIP_ID = 0x00
    ACC_ID = 0x01
    MAG_ID = 0x02
    GYR_ID = 0x03
    SW_REV_ID_LSB = 0x04
    SW_REV_ID_MSB = 0x05
    BL_REV_ID = 0x06
    PAGE_ID = 0x07  # in both pages
    ACC_DATA_X_LSB = 0x08  # int16 LE x, y, z: 0x08-0x0D
    MAG_DATA_X_LSB = 0x0E  # 0x0E-0x13
    GYR_DATA_X_LSB = 0x14  # 0x14-0x19
    EUL_HEADING_LSB = 0x1A  # heading, roll, pitch: 0x1A-0x1F
    QUA_DATA_W_LSB = 0x20  # w, x, y, z: 0x20-0x27
    LIA_DATA_X_LSB = 0x28  # 0x28-0x2D
    GRV_DATA_X_LSB = 0x2E  # 0x2E-0x33
    TEMP = 0x34  # int8
    CALIB_STAT = 0x35
    SYS_STATUS = 0x39
    SYS_ERR = 0x3A
    UNIT_SEL = 0x3B
    OPR_MODE = 0x3D
    PWR_MODE = 0x3E
    SYS_TRIGGER = 0x3F
    AXIS_MAP_CONFIG = 0x41
    AXIS_MAP_SIGN = 0x42
    ACC_OFFSET_X_LSB = 0x55  # the 22-byte calibration profile: 0x55-0x6A
    MAG_OFFSET_X_LSB = 0x5B
    GYR_OFFSET_X_LSB = 0x61
    ACC_RADIUS_LSB = 0x67
    MAG_RADIUS_LSB = 0x69


class Page1(IntEnum):
    GYR_CONFIG_0 = 0x0A
    UNIQUE_ID = 0x50  # 16 bytes, 0x50-0x5F


class OprMode(IntEnum):
    """OPR_MODE[3:0]."""

    CONFIG = 0x00
    ACCONLY = 0x01
    MAGONLY = 0x02
    GYROONLY = 0x03
    ACCMAG = 0x04
    ACCGYRO = 0x05
    MAGGYRO = 0x06
    AMG = 0x07
    IMU = 0x08
    COMPASS = 0x09
    M4G = 0x0A
    NDOF_FMC_OFF = 0x0B
    NDOF = 0x0C


OPR_MODE_FIELD = BitField(0x0F)
FUSION_MODES = (OprMode.IMU, OprMode.COMPASS, OprMode.M4G, OprMode.NDOF_FMC_OFF, OprMode.NDOF)


class PwrMode(IntEnum):
    """PWR_MODE[1:0]."""

    NORMAL = 0
    LOW_POWER = 1
    SUSPEND = 2


PWR_MODE_FIELD = BitField(0x03)


class SysTrigger(IntFlag):
    CLK_SEL = 0x80  # 1: external 32 kHz crystal
    RST_SYS = 0x20  # power-on reset; on UART the chip resets without an answer


class UnitSel(IntFlag):
    ORI_ANDROID = 0x80  # fusion data output format: 1 Android, 0 Windows (Euler pitch sign)
    TEMP_F = 0x10  # 1: Fahrenheit, 0: Celsius
    EUL_RAD = 0x04  # 1: radians, 0: degrees
    GYR_RPS = 0x02  # 1: rad/s, 0: deg/s
    ACC_MG = 0x01  # 1: mg, 0: m/s^2


# CALIB_STAT (0x35): each 0 (uncalibrated) ... 3 (fully calibrated)
CALIB_SYS = BitField(0xC0)
CALIB_GYR = BitField(0x30)
CALIB_ACC = BitField(0x0C)
CALIB_MAG = BitField(0x03)
CALIB_FULL = 0xFF  # all four at 3

# AXIS_MAP_CONFIG: which chip axis (0 x, 1 y, 2 z) each remapped axis takes
AXIS_REMAP_X = BitField(0x03)
AXIS_REMAP_Y = BitField(0x0C)
AXIS_REMAP_Z = BitField(0x30)
AXIS_MAP_CONFIG_DEFAULT = 0x24  # x = x, y = y, z = z


class AxisSign(IntFlag):
    """AXIS_MAP_SIGN: 1 = the remapped axis is negated."""

    X = 0x04
    Y = 0x02
    Z = 0x01


GYR_RANGE = BitField(0x07)  # GYR_CONFIG_0[2:0]: 0 = 2000 ... 4 = 125 deg/s
GYRO_RANGES_DPS = (2000, 1000, 500, 250, 125)

# --- identity ----------------------------------------------------------------------------------
CHIP_ID_VALUE = 0xA0
ACC_ID_VALUE = 0xFB
MAG_ID_VALUE = 0x32
GYR_ID_VALUE = 0x0F
I2C_ADDRESSES = (0x28, 0x29)  # COM3 low / high

# --- data: one burst covers ACC ... GRV, TEMP and CALIB_STAT (0x08-0x35) ------------------------
DATA_BURST_LEN = 46
OFFSETS_LEN = 22  # 0x55-0x6A
UID_LEN = 16

# --- scales (UNIT_SEL m/s^2, rad/s, deg C) ------------------------------------------------------
ACC_LSB_PER_MS2 = 100  # also linear acceleration and gravity; 1 LSB = 1 mg with ACC_MG
GYR_LSB_PER_RPS = 900  # fusion modes; 16 LSB per deg/s in deg/s units
GYR_LSB_PER_DPS = 16
MAG_LSB_PER_UT = 16
QUA_LSB_PER_UNIT = 1 << 14
TEMP_LSB_PER_C = 1
# Non-fusion modes, firmware 3.11 (Linux's reading of a Bosch forum report): the gyro scale is
# the range over 2^15, not 1/900 rad/s
GYR_RAW_FULL_SCALE_COUNTS = 1 << 15
ACCEL_FUSION_RANGE_G = 4  # fusion modes lock the accel range (and the AMG reset default)
GYRO_DEFAULT_RANGE_DPS = 2000

FUSION_RATE_HZ = 100.0  # fusion and accel/gyro data output rate in IMU, NDOF_FMC_OFF, NDOF
FUSION_MAG_RATE_HZ = 20.0  # magnetometer data output rate in NDOF_FMC_OFF and NDOF

# --- delays (minimum waits) ---------------------------------------------------------------------
RESET_WAIT_NS = 700_000_000  # after RST_SYS: 650 ms
CONFIG_TO_MODE_WAIT_NS = 20_000_000  # CONFIGMODE -> any operation mode: 7 ms
MODE_TO_CONFIG_WAIT_NS = 20_000_000  # any operation mode -> CONFIGMODE: 19 ms


# --- UART protocol ------------------------------------------------------------------------------
class Uart(IntEnum):
    START = 0xAA  # first byte of every request
    WRITE = 0x00
    READ = 0x01
    READ_RESPONSE = 0xBB  # followed by length and data
    STATUS_RESPONSE = 0xEE  # followed by one status byte


class UartStatus(IntEnum):
    WRITE_SUCCESS = 0x01
    READ_FAIL = 0x02
    WRITE_FAIL = 0x03
    REGMAP_INVALID_ADDRESS = 0x04
    REGMAP_WRITE_DISABLED = 0x05
    WRONG_START_BYTE = 0x06
    BUS_OVER_RUN_ERROR = 0x07
    MAX_LENGTH_ERROR = 0x08
    MIN_LENGTH_ERROR = 0x09
    RECEIVE_CHARACTER_TIMEOUT = 0x0A


UART_BAUD = 115_200  # 8N1, no flow control
UART_MAX_LENGTH = 128  # bytes per read or write
UART_RX_TIMEOUT_NS = 30_000_000  # a longer gap between request bytes resets the chip's receiver
