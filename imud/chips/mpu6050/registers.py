"""MPU6050 register map: addresses, bits and field codes (docs/chips/mpu6050.md).

Shared by the driver and the simulator; tests check every value against the register map
document's literals. Scales and decoding are not here: the driver and the simulator each do their
own arithmetic, so a test of one against the other can catch a wrong one.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag

from imud.chips.bits import BitField


class Register(IntEnum):
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


class PwrMgmt1(IntFlag):
    DEVICE_RESET = 0x80
    SLEEP = 0x40
    CYCLE = 0x20
    TEMP_DIS = 0x08


PWR1_CLKSEL = BitField(0x07)
CLKSEL_PLL_XGYRO = 1  # PLL with the X gyro as reference (0 would be the 8 MHz oscillator)

CONFIG_DLPF_CFG = BitField(0x07)
CONFIG_EXT_SYNC_SET = BitField(0x38)  # 0: FSYNC not sampled into the data LSBs

GYRO_FS_SEL = BitField(0x18)
ACCEL_AFS_SEL = BitField(0x18)
SELF_TEST_BITS = 0xE0  # XG_ST/YG_ST/ZG_ST, XA_ST/YA_ST/ZA_ST in GYRO_CONFIG/ACCEL_CONFIG


class FifoEn(IntFlag):
    TEMP = 0x80
    XG = 0x40
    YG = 0x20
    ZG = 0x10
    ACCEL = 0x08
    SLV2 = 0x04
    SLV1 = 0x02
    SLV0 = 0x01


class IntEnable(IntFlag):
    FIFO_OFLOW_EN = 0x10
    I2C_MST_INT_EN = 0x08
    DATA_RDY_EN = 0x01


class IntStatus(IntFlag):
    FIFO_OFLOW_INT = 0x10
    I2C_MST_INT = 0x08
    DATA_RDY_INT = 0x01


class UserCtrl(IntFlag):
    FIFO_EN = 0x40
    I2C_MST_EN = 0x20
    I2C_IF_DIS = 0x10
    FIFO_RESET = 0x04
    I2C_MST_RESET = 0x02
    SIG_COND_RESET = 0x01


WHO_AM_I_VALUE = 0x68
GYRO_RANGES_DPS = (250, 500, 1000, 2000)  # FS_SEL 0..3
ACCEL_RANGES_G = (2, 4, 8, 16)  # AFS_SEL 0..3
DLPF_BANDWIDTHS_HZ = (256, 188, 98, 42, 20, 10, 5)  # DLPF_CFG 0..6, gyro bandwidth; 0: off
GYRO_RATE_DLPF_OFF_HZ = 8000.0  # gyro output rate with DLPF_CFG = 0 (the accel stays at 1 kHz)
GYRO_RATE_DLPF_ON_HZ = 1000.0
FIFO_SIZE = 1024  # bytes
RESET_WAIT_NS = 100_000_000  # after DEVICE_RESET
WAKE_WAIT_NS = 10_000_000  # after clearing SLEEP
