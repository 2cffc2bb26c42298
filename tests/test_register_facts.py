"""Register facts, tested independently of the code that uses them.

For each chip, every register address, bit, field mask, code table, size, command and delay of
its register map (imud/chips/<chip>/registers.py) is written here as a literal copied from the
chip's facts sheet (docs/chips/<chip>.md), with the citation the sheet gives: document, revision,
section (or page), then the drivers the sheet quotes as agreeing. Where the sheet says the
datasheet section was not verified, the citation says so and names the sheet and the drivers.
Nothing here is computed from imud's constants.

Then:
- register bytes composed from the map's fields (mask positions and codes together) against the
  reset values and written values the sheets state;
- completeness: every register-map name the driver-side modules (driver, decode, config, ...)
  reference, and every member of the map's enum classes, has a fact here;
- the simulators import nothing driver-side (scales, decoding, config) of any chip, directly or
  through the modules they import: they may share only the register map.

A disagreement between the sheet and the map is a failing test: the literal stays the sheet's.
"""

from __future__ import annotations

import ast
import enum
import importlib
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

from imud.chips.bits import BitField
from imud.chips.bmi088 import registers as bmi
from imud.chips.icm42688p import registers as icm
from imud.chips.mpu6050 import registers as mpu
from tests.regfacts import ROWS, F, Fact

ROOT = Path(__file__).resolve().parents[1]
CHIPS_DIR = ROOT / "imud" / "chips"


# =================================================================================================
# MPU6050 (docs/chips/mpu6050.md)
# RM = register map document, PS = product specification. Neither numbers its tables: a table is
# cited by its section. "derived" = section number counted from the section order (per the sheet).
# =================================================================================================
RM = "RM-MPU-6000A-00 rev 4.2"
PS = "PS-MPU-6000A-00 rev 3.4"
RM3 = f"{RM} §3 (register map table, pp. 6-8)"

MPU6050_FACTS = [
    # --- register addresses
    F("Register.SMPLRT_DIV", 0x19, f"{RM3}; §4.2 (p. 12) · LX-MPU, AP-INV"),
    F("Register.CONFIG", 0x1A, f"{RM3}; §4.3 (table not retrieved) · LX-MPU, AP-INV, PX-MPU"),
    F("Register.GYRO_CONFIG", 0x1B, f"{RM3}; §4.4 (p. 14) · PX-MPU, LX-MPU"),
    F("Register.ACCEL_CONFIG", 0x1C, f"{RM3}; §4.5 (not retrieved) · PX-MPU, LX-MPU"),
    F("Register.FIFO_EN", 0x23, f"{RM3}; §4.6 (title from contents) · AP-INV, LX-MPU"),
    F("Register.INT_ENABLE", 0x38, f"{RM3}; §4.15 (derived) · LX-MPU, AP-INV"),
    F("Register.INT_STATUS", 0x3A, f"{RM3}; §4.16 (derived) · LX-MPU"),
    F("Register.ACCEL_XOUT_H", 0x3B, f"{RM3}; §4.17 (derived) · LX-MPU REG_RAW_ACCEL"),
    F("Register.TEMP_OUT_H", 0x41, f"{RM} §4.18 (p. 30) · LX-MPU REG_TEMPERATURE"),
    F("Register.GYRO_XOUT_H", 0x43, f"{RM} §4.19 (p. 31) · LX-MPU REG_RAW_GYRO"),
    F("Register.SIGNAL_PATH_RESET", 0x68, f"{RM3} p. 8 row; §4.26 (derived) · LX-MPU, PX-MPU"),
    F("Register.USER_CTRL", 0x6A, f"{RM3} p. 8 row; §4.27 (derived) · LX-MPU, AP-INV"),
    F("Register.PWR_MGMT_1", 0x6B, f"{RM3} p. 8 row; §4.28 (derived) · PX-MPU, LX-MPU"),
    F("Register.PWR_MGMT_2", 0x6C, f"{RM3} p. 8 row; §4.29 (derived) · LX-MPU"),
    F("Register.FIFO_COUNT_H", 0x72, f"{RM} §4.30 (p. 43) · LX-MPU, PX-MPU"),
    F("Register.FIFO_R_W", 0x74, f"{RM} §4.31 (p. 44) · LX-MPU, PX-MPU"),
    F("Register.WHO_AM_I", 0x75, f"{RM} §4.32 (p. 45) · LX-MPU, PX-MPU"),
    # --- PWR_MGMT_1 (0x6B): bit7 DEVICE_RESET, bit6 SLEEP, bit5 CYCLE, bit3 TEMP_DIS, [2:0] CLKSEL
    F("PwrMgmt1.DEVICE_RESET", 0x80, f"{RM3} p. 8 row; §4.28 (derived) · LX-MPU, PX-MPU"),
    F("PwrMgmt1.SLEEP", 0x40, f"{RM3} p. 8 row and reset note; §4.28 (derived) · PX-MPU"),
    F("PwrMgmt1.CYCLE", 0x20, f"{RM3} p. 8 row; §4.28 (derived) · LX-MPU, AP-INV"),
    F("PwrMgmt1.TEMP_DIS", 0x08, f"{RM3} p. 8 row; §4.28 (derived) · LX-MPU, AP-INV"),
    F("PWR1_CLKSEL", 0x07, f"{RM3} p. 8 row; §4.28 (derived) · LX-MPU, AP-INV"),
    F("CLKSEL_PLL_XGYRO", 1, f"{RM} §4.28 (derived): 1 = PLL, X gyro ref · LX-MPU, PX-MPU"),
    # --- CONFIG (0x1A): [5:3] EXT_SYNC_SET, [2:0] DLPF_CFG
    F("CONFIG_DLPF_CFG", 0x07, f"{RM} §4.3 (table not retrieved) · LX-MPU, AP-INV, PX-MPU"),
    F("CONFIG_EXT_SYNC_SET", 0x38, f"{RM} §4.3 (table not retrieved) · LX-MPU, AP-INV"),
    # --- GYRO_CONFIG (0x1B) / ACCEL_CONFIG (0x1C): [7:5] self-test, [4:3] full-scale select
    F("GYRO_FS_SEL", 0x18, f"{RM} §4.4 (p. 14) · PX-MPU, LX-MPU"),
    F("ACCEL_AFS_SEL", 0x18, f"{RM} §4.5 (not retrieved); codes PS §6.2 · PX-MPU, LX-MPU"),
    F("SELF_TEST_BITS", 0xE0, f"{RM} §4.4 (p. 14) XG/YG/ZG_ST; §4.5 XA/YA/ZA_ST · PX-MPU"),
    # --- FIFO_EN (0x23): bits not retrieved from RM §4.6; sheet's drivers agree
    F("FifoEn.TEMP", 0x80, f"{RM} §4.6 (bits not retrieved) · AP-INV, LX-MPU"),
    F("FifoEn.XG", 0x40, f"{RM} §4.6 (bits not retrieved) · AP-INV, LX-MPU"),
    F("FifoEn.YG", 0x20, f"{RM} §4.6 (bits not retrieved) · AP-INV, LX-MPU"),
    F("FifoEn.ZG", 0x10, f"{RM} §4.6 (bits not retrieved) · AP-INV, LX-MPU"),
    F("FifoEn.ACCEL", 0x08, f"{RM} §4.6 (bits not retrieved) · AP-INV, LX-MPU"),
    F("FifoEn.SLV2", 0x04, f"{RM} §4.6 (bits not retrieved) · AP-INV, LX-MPU"),
    F("FifoEn.SLV1", 0x02, f"{RM} §4.6 (bits not retrieved) · AP-INV, LX-MPU"),
    F("FifoEn.SLV0", 0x01, f"{RM} §4.6 (bits not retrieved) · AP-INV, LX-MPU"),
    # --- INT_ENABLE (0x38) / INT_STATUS (0x3A)
    F("IntEnable.FIFO_OFLOW_EN", 0x10, f"{RM} §4.15 (derived, table n.r.) · LX-MPU, AP-INV"),
    F("IntEnable.I2C_MST_INT_EN", 0x08, f"{RM} §4.15 (derived, table n.r.) · LX-MPU, AP-INV"),
    F("IntEnable.DATA_RDY_EN", 0x01, f"{RM} §4.15 (derived) · LX-MPU BIT_DATA_RDY_EN 0x01"),
    F("IntStatus.FIFO_OFLOW_INT", 0x10, f"{RM} §4.16 (derived); §4.31 · LX-MPU 0x10"),
    F("IntStatus.I2C_MST_INT", 0x08, f"{RM} §4.16 (derived) · LX-MPU, AP-INV"),
    F("IntStatus.DATA_RDY_INT", 0x01, f"{RM} §4.16 (derived) · LX-MPU BIT_RAW_DATA_RDY_INT"),
    # --- USER_CTRL (0x6A)
    F("UserCtrl.FIFO_EN", 0x40, f"{RM3} p. 8 row; §4.27 (derived) · LX-MPU, AP-INV"),
    F("UserCtrl.I2C_MST_EN", 0x20, f"{RM3} p. 8 row; §4.27 (derived) · LX-MPU, AP-INV"),
    F("UserCtrl.I2C_IF_DIS", 0x10, f"{RM3} p. 8 row; §4.27 (derived) · LX-MPU, AP-INV"),
    F("UserCtrl.FIFO_RESET", 0x04, f"{RM3} p. 8 row; §4.27 (derived) · LX-MPU BIT_FIFO_RST"),
    F("UserCtrl.I2C_MST_RESET", 0x02, f"{RM3} p. 8 row; §4.27 (derived) · LX-MPU, AP-INV"),
    F("UserCtrl.SIG_COND_RESET", 0x01, f"{RM3} p. 8 row; §4.27 (derived) · LX-MPU, AP-INV"),
    # --- identity, codes, rates
    F("WHO_AM_I_VALUE", 0x68, f"{RM} §4.32 (p. 45); §3 reset note · LX-MPU, PX-MPU"),
    F("GYRO_RANGES_DPS", (250, 500, 1000, 2000), f"{RM} §4.4 (p. 14); {PS} §6.1 (p. 12)"),
    F("ACCEL_RANGES_G", (2, 4, 8, 16), f"{PS} §6.2 (p. 13); {RM} §4.5 (not retrieved)"),
    F(
        "DLPF_BANDWIDTHS_HZ",
        (256, 188, 98, 42, 20, 10, 5),
        f"{RM} §4.3 (table not retrieved; 7 = reserved per §4.2) · LX-MPU, AP-INV, PX-MPU",
    ),
    F("GYRO_RATE_DLPF_OFF_HZ", 8000, f"{RM} §4.2 (p. 12): 8 kHz with DLPF_CFG = 0 or 7"),
    F("GYRO_RATE_DLPF_ON_HZ", 1000, f"{RM} §4.2 (p. 12): 1 kHz otherwise"),
    F("FIFO_SIZE", 1024, f"{PS} §7.17 (quoted) · LX-MPU fifo_size, PX-MPU FIFO::SIZE"),
    # --- delays (minimum waits): driver constants, no datasheet number (sheet: not verified)
    F(
        "RESET_WAIT_NS",
        100_000_000,
        "not in RM/PS (not verified) · LX-MPU INV_MPU6050_POWER_UP_TIME 100 ms, PX-MPU",
        at_least=True,
    ),
    F(
        "WAKE_WAIT_NS",
        5_000_000,
        "not in RM/PS (not verified) · LX-MPU REG_UP_TIME 5-10 ms",
        at_least=True,
    ),
]

# =================================================================================================
# ICM-42688-P (docs/chips/icm42688p.md)
# DS = DS-000347 rev 1.7. The register-map chapters were not readable: except for §4.10, §5.3,
# §5.5, §12.9 and §14.36 (quoted by others), the sheet says "section not verified" (NV below) and
# cites drivers; the citations then name the sheet's section and those drivers.
# =================================================================================================
DS = "DS-000347 v1.7"
NV = "DS section not verified; icm42688p.md"
A1 = f"{NV} §A.1"
AAF = f"{DS} §5.3 Anti-Alias Filter (p. 28; table number not verified); icm42688p.md"

# GYRO_CONFIG0[3:0] / ACCEL_CONFIG0[3:0]: ODR (Hz) -> code. icm42688p.md §A.2 (DS section not
# verified) · LX, PX-ICM, TDK-DEFS, ZREG. Codes 12-14 (accel low-power only) are not used by imud.
ICM_ODR_CODES = {
    32000: 1, 16000: 2, 8000: 3, 4000: 4, 2000: 5, 1000: 6,
    200: 7, 100: 8, 50: 9, 25: 10, 12.5: 11, 500: 15,
}  # fmt: skip
# GYRO_ACCEL_CONFIG0 UI filter bandwidth codes (low-noise mode), both nibbles. DS §5.5 (per-ODR
# tables not retrieved); icm42688p.md §2.1 · ZREG names, TDK-DEFS divisors. 8-13 reserved.
ICM_UI_FILTER_CODES = {
    "odr/2": 0, "odr/4": 1, "odr/5": 2, "odr/8": 3, "odr/10": 4, "odr/16": 5,
    "odr/20": 6, "odr/40": 7, "low_latency": 14, "low_latency_8x": 15,
}  # fmt: skip

ICM42688P_FACTS = [
    # --- bank 0 addresses
    F("Bank0.DEVICE_CONFIG", 0x11, f"{A1} · PX-ICM, LX, TDK-HL"),
    F("Bank0.FIFO_CONFIG", 0x16, f"{A1} · LX, PX-ICM, AP"),
    F("Bank0.TEMP_DATA1", 0x1D, f"{A1} · LX (temp.c), PX-ICM"),
    F("Bank0.ACCEL_DATA_X1", 0x1F, f"{A1} · LX"),
    F("Bank0.GYRO_DATA_X1", 0x25, f"{A1} · LX"),
    F("Bank0.INT_STATUS", 0x2D, f"{A1} · PX-ICM, TDK-DEFS, LX"),
    F("Bank0.FIFO_COUNTH", 0x2E, f"{A1} · LX, PX-ICM"),
    F("Bank0.FIFO_COUNTL", 0x2F, f"{A1} · LX, PX-ICM"),
    F("Bank0.FIFO_DATA", 0x30, f"{A1} · PX-ICM (one burst from 0x2D), LX"),
    F("Bank0.SIGNAL_PATH_RESET", 0x4B, f"{A1} · PX-ICM, LX, AP"),
    F("Bank0.INTF_CONFIG0", 0x4C, f"{A1}, §4.1 · XIO, RUST42605, ZDEC, LX"),
    F("Bank0.INTF_CONFIG1", 0x4D, f"{A1}, §4.2 · XIO, RUST42605, ZCOM"),
    F("Bank0.PWR_MGMT0", 0x4E, f"{DS} §14.36 (cited by Zephyr, not read) · LX, PX-ICM"),
    F("Bank0.GYRO_CONFIG0", 0x4F, f"{A1} · PX-ICM, LX, TDK-DEFS"),
    F("Bank0.ACCEL_CONFIG0", 0x50, f"{A1} · PX-ICM, LX, TDK-DEFS"),
    F("Bank0.GYRO_ACCEL_CONFIG0", 0x52, f"{A1}, §2.1 · ZREG, TDK-DEFS"),
    F("Bank0.TMST_CONFIG", 0x54, f"{A1}, §3.1 · PX-ICM, TDK-DEFS, ZREG"),
    F("Bank0.FIFO_CONFIG1", 0x5F, f"{A1}, §4.3 · PX-ICM, LX, TDK-DEFS"),
    F("Bank0.WHO_AM_I", 0x75, f"{A1} · LX, PX-ICM, AP"),
    F("Bank0.REG_BANK_SEL", 0x76, f"{A1} (in every bank) · PX-ICM, LX"),
    # --- bank 1 and bank 2 (anti-alias filter registers)
    F("Bank1.GYRO_CONFIG_STATIC2", 0x0B, f"{A1}, §1.1 · PX-ICM, XIO, ZREG"),
    F("Bank1.GYRO_CONFIG_STATIC3", 0x0C, f"{A1}, §1.1 · PX-ICM, XIO, ZREG"),
    F("Bank1.GYRO_CONFIG_STATIC4", 0x0D, f"{A1}, §1.1 · PX-ICM, XIO, ZREG"),
    F("Bank1.GYRO_CONFIG_STATIC5", 0x0E, f"{A1}, §1.1 · PX-ICM, XIO, ZREG"),
    F("Bank2.ACCEL_CONFIG_STATIC2", 0x03, f"{A1}, §1.1 · PX-ICM, XIO, ZREG"),
    F("Bank2.ACCEL_CONFIG_STATIC3", 0x04, f"{A1}, §1.1 · PX-ICM, XIO, ZREG"),
    F("Bank2.ACCEL_CONFIG_STATIC4", 0x05, f"{A1}, §1.1 · PX-ICM, XIO, ZREG"),
    # --- DEVICE_CONFIG (0x11), FIFO_CONFIG (0x16)
    F("DeviceConfig.SOFT_RESET_CONFIG", 0x01, f"{A1}, §A.6 · PX-ICM, LX, TDK-HL"),
    F("FIFO_MODE", 0xC0, f"{A1}, §4.3: FIFO_CONFIG[7:6] · LX, PX-ICM, AP"),
    F("FIFO_MODE_BYPASS", 0, f"{NV} §4.3 · TDK-HL, PX-ICM, AP, RUST42605"),
    F("FIFO_MODE_STREAM", 1, f"{NV} §4.3 · TDK-HL, PX-ICM, AP, RUST42605"),
    F("FIFO_MODE_STOP_ON_FULL", 2, f"{NV} §4.3 (2 and 3 stop on full) · AP, PX-ICM"),
    # --- INT_STATUS (0x2D)
    F("IntStatus.UI_FSYNC_INT", 0x40, f"{A1} · PX-ICM, TDK-DEFS, LX"),
    F("IntStatus.PLL_RDY_INT", 0x20, f"{A1} · PX-ICM, TDK-DEFS, LX"),
    F("IntStatus.RESET_DONE_INT", 0x10, f"{A1}, §4.5 · PX-ICM, TDK-DEFS, LX"),
    F("IntStatus.DATA_RDY_INT", 0x08, f"{A1} · PX-ICM, TDK-DEFS, LX"),
    F("IntStatus.FIFO_THS_INT", 0x04, f"{A1} · PX-ICM, TDK-DEFS, LX"),
    F("IntStatus.FIFO_FULL_INT", 0x02, f"{A1} · PX-ICM, TDK-DEFS, LX"),
    F("IntStatus.AGC_RDY_INT", 0x01, f"{A1} · PX-ICM, TDK-DEFS, LX"),
    # --- SIGNAL_PATH_RESET (0x4B)
    F("SignalPathReset.ABORT_AND_RESET", 0x08, f"{A1} · PX-ICM, LX"),
    F("SignalPathReset.TMST_STROBE", 0x04, f"{A1}, §3.1 · PX-ICM, LX, TDK-HL"),
    F("SignalPathReset.FIFO_FLUSH", 0x02, f"{A1}, §A.5 · PX-ICM, LX, AP (writes 2)"),
    # --- INTF_CONFIG0 (0x4C), INTF_CONFIG1 (0x4D)
    F("IntfConfig0.FIFO_HOLD_LAST_DATA_EN", 0x80, f"{NV} §4.1 · ZDEC, TDK-DEFS, AP"),
    F("IntfConfig0.FIFO_COUNT_REC", 0x40, f"{NV} §4.1 · XIO, RUST42605, ZDEC, LX"),
    F("IntfConfig0.FIFO_COUNT_ENDIAN", 0x20, f"{NV} §4.1 · XIO, RUST42605, ZDEC, LX"),
    F("IntfConfig0.SENSOR_DATA_ENDIAN", 0x10, f"{NV} §4.1 · XIO, RUST42605, ZDEC, LX"),
    F("INTF_CONFIG1_AFSR", 0xC0, f"undocumented in DS; {NV} §4.2 · AP PR #25332, BF, iNav"),
    F("AFSR_OFF", 0b01, f"undocumented in DS; {NV} §4.2 · AP PR #25332, BF, iNav"),
    # --- PWR_MGMT0 (0x4E)
    F("PwrMgmt0.TEMP_DIS", 0x20, f"{DS} §14.36 (cited by Zephyr) · LX, PX-ICM"),
    F("PwrMgmt0.IDLE", 0x10, f"{DS} §14.36 (cited by Zephyr) · LX, PX-ICM"),
    F("GYRO_MODE", 0x0C, f"{DS} §14.36 (cited by Zephyr): [3:2] · LX, PX-ICM"),
    F("ACCEL_MODE", 0x03, f"{DS} §14.36 (cited by Zephyr): [1:0] · LX, PX-ICM"),
    F("MODE_LOW_NOISE", 3, f"{DS} §14.36 (cited by Zephyr): 3 = low-noise · LX, PX-ICM"),
    # --- GYRO_CONFIG0 (0x4F), ACCEL_CONFIG0 (0x50), GYRO_ACCEL_CONFIG0 (0x52)
    F("GYRO_FS_SEL", 0xE0, f"{A1}: [7:5] · PX-ICM, LX, TDK-DEFS"),
    F("GYRO_ODR", 0x0F, f"{A1}: [3:0] · PX-ICM, LX, TDK-DEFS"),
    F("ACCEL_FS_SEL", 0xE0, f"{A1}: [7:5] · PX-ICM, LX, TDK-DEFS"),
    F("ACCEL_ODR", 0x0F, f"{A1}: [3:0] · PX-ICM, LX, TDK-DEFS"),
    F("ACCEL_UI_FILT_BW", 0xF0, f"{NV} §2.1: [7:4] · ZREG, TDK-DEFS"),
    F("GYRO_UI_FILT_BW", 0x0F, f"{NV} §2.1: [3:0] · ZREG, TDK-DEFS"),
    # --- TMST_CONFIG (0x54)
    F("TmstConfig.TMST_TO_REGS_EN", 0x10, f"{NV} §3.1 · ZREG, TDK-DEFS, LX, PX4PR"),
    F("TmstConfig.TMST_RES", 0x08, f"{NV} §3.1 · ZREG, TDK-DEFS, LX, PX4PR"),
    F("TmstConfig.TMST_DELTA_EN", 0x04, f"{NV} §3.1 · ZREG, TDK-DEFS, LX, PX4PR"),
    F("TmstConfig.TMST_FSYNC_EN", 0x02, f"{NV} §3.1 · ZREG, TDK-DEFS, LX, PX4PR"),
    F("TmstConfig.TMST_EN", 0x01, f"{NV} §3.1 · ZREG, TDK-DEFS, LX, PX4PR"),
    # --- FIFO_CONFIG1 (0x5F)
    F("FifoConfig1.RESUME_PARTIAL_RD", 0x40, f"{NV} §4.3 · ZREG, TDK-DEFS, LX"),
    F("FifoConfig1.WM_GT_TH", 0x20, f"{NV} §4.3 · ZREG, TDK-DEFS, LX"),
    F("FifoConfig1.HIRES_EN", 0x10, f"{NV} §4.3 · ZREG, TDK-DEFS, LX"),
    F("FifoConfig1.TMST_FSYNC_EN", 0x08, f"{NV} §4.3 · ZREG, TDK-DEFS, LX"),
    F("FifoConfig1.TEMP_EN", 0x04, f"{NV} §4.3 · ZREG, TDK-DEFS, LX"),
    F("FifoConfig1.GYRO_EN", 0x02, f"{NV} §4.3 · ZREG, TDK-DEFS, LX"),
    F("FifoConfig1.ACCEL_EN", 0x01, f"{NV} §4.3 · ZREG, TDK-DEFS, LX"),
    # --- FIFO packet header (first byte of every packet)
    F("Header.MSG", 0x80, f"{NV} §A.5 header table · LX, PX-ICM, TDK-DEFS"),
    F("Header.ACCEL", 0x40, f"{NV} §A.5 header table · LX, PX-ICM, TDK-DEFS"),
    F("Header.GYRO", 0x20, f"{NV} §A.5 header table · LX, PX-ICM, TDK-DEFS"),
    F("Header.HIRES_20", 0x10, f"{NV} §A.5 header table · LX, PX-ICM, TDK-DEFS"),
    F("Header.ODR_ACCEL", 0x02, f"{NV} §A.5 header table · LX, PX-ICM, TDK-DEFS"),
    F("Header.ODR_GYRO", 0x01, f"{NV} §A.5 header table · LX, PX-ICM, TDK-DEFS"),
    F("HEADER_TMST_FSYNC", 0x0C, f"{NV} §A.5 header [3:2], §3.1 · TDK-DEFS"),
    F("TMST_FSYNC_ODR", 0b10, f"{NV} §A.5: 0b10 = ODR timestamp · TDK-DEFS"),
    # --- GYRO_CONFIG_STATIC2..5 (B1), ACCEL_CONFIG_STATIC2..4 (B2): anti-alias filter fields
    F("GyroConfigStatic2.GYRO_AAF_DIS", 0x02, f"{AAF} §1.1 · ZREG, XIO, TDK-IIM, BF, AP"),
    F("GyroConfigStatic2.GYRO_NF_DIS", 0x01, f"{AAF} §1.1 · ZREG, XIO, TDK-IIM, BF, AP"),
    F("GYRO_AAF_DELT", 0x3F, f"{AAF} §1.1: STATIC3[5:0] · ZREG, XIO"),
    F("GYRO_AAF_DELTSQR_LO", 0xFF, f"{AAF} §1.1: STATIC4[7:0] · ZREG, XIO"),
    F("GYRO_AAF_BITSHIFT", 0xF0, f"{AAF} §1.1: STATIC5[7:4] · ZREG, XIO"),
    F("GYRO_AAF_DELTSQR_HI", 0x0F, f"{AAF} §1.1: STATIC5[3:0] · ZREG, XIO"),
    F("ACCEL_AAF_DELT", 0x7E, f"{AAF} §1.1: A-STATIC2[6:1] · ZREG, XIO"),
    F("ACCEL_AAF_DIS", 0x01, f"{AAF} §1.1: A-STATIC2[0] · ZREG, XIO"),
    F("ACCEL_AAF_DELTSQR_LO", 0xFF, f"{AAF} §1.1: A-STATIC3[7:0] · ZREG, XIO"),
    F("ACCEL_AAF_BITSHIFT", 0xF0, f"{AAF} §1.1: A-STATIC4[7:4] · ZREG, XIO"),
    F("ACCEL_AAF_DELTSQR_HI", 0x0F, f"{AAF} §1.1: A-STATIC4[3:0] · ZREG, XIO"),
    # --- identity, code tables
    F("WHO_AM_I_VALUE", 0x47, f"{A1} · LX, PX-ICM, AP"),
    F(
        "GYRO_RANGES_DPS",
        (2000, 1000, 500, 250, 125, 62.5, 31.25, 15.625),
        f"{A1}: GYRO_FS_SEL 0..7 · PX-ICM, LX, TDK-DEFS",
    ),
    F("ACCEL_RANGES_G", (16, 8, 4, 2), f"{A1}: ACCEL_FS_SEL 0..3 · PX-ICM, LX, TDK-DEFS"),
    F(
        "ODR_CODES",
        ICM_ODR_CODES,
        f"{NV} §A.2 (GYRO_/ACCEL_CONFIG0[3:0]) · LX, PX-ICM, TDK-DEFS, ZREG",
    ),
    F(
        "UI_FILTER_CODES",
        ICM_UI_FILTER_CODES,
        f"{DS} §5.5 UI Filter Block (tables not retrieved); icm42688p.md §2.1 · ZREG, TDK-DEFS",
    ),
    F("AAF_DEFAULT_GYRO_HZ", 585, f"{AAF} §1.1 reset defaults (DELT 13/170/8) · XIO"),
    F("AAF_DEFAULT_ACCEL_HZ", 1163, f"{AAF} §1.1 reset defaults (DELT 24/576/6) · XIO"),
    # --- FIFO and packets
    F("FIFO_SIZE", 2048, f"{DS} front page ('2 kB FIFO') · LX, PX-ICM FIFO::SIZE"),
    F("PACKET3_BYTES", 16, f"{NV} §A.5 packet layouts (type 3) · LX, AP"),
    F("PACKET4_BYTES", 20, f"{NV} §A.5 packet layouts (type 4) · PX-ICM, TDK-HL"),
    F("INVALID_16", -32768, f"{NV} §A.7 (a), Status (verified) · LX, TDK-HL, PX-ICM"),
    F("INVALID_20", -524288, f"{NV} Status: 20-bit marker · LX/PX4 reading; TDK bits [19:4]"),
    F("INVALID_TEMP_8", -128, f"{NV} §A.7 (a): packet 3 int8 · TDK-HL INVALID_VALUE_FIFO_1B"),
    F("TIMESTAMP_MODULO", 1 << 16, f"{NV} §3.1-3.2: 16-bit field, mod 2^16 · TDK-CAL, LX"),
    F("TICK_NS", 1000.0 * 32 / 30, f"{NV} §3.2-3.3, 3.5: 1 us tick x 32/30 on the PLL · TDK-CAL"),
    # --- delays (minimum waits) and bus limit
    F("RESET_WAIT_NS", 1_000_000, f"{NV} §A.6, §4.5: 1 ms · TDK-HL, LX", at_least=True),
    F(
        "POWER_ON_WAIT_NS",
        200_000,
        f"{DS} §14.36 via Zephyr; {NV} §A.6: 200 us after PWR_MGMT0 · TDK-HL",
        at_least=True,
    ),
    F(
        "STARTUP_WAIT_NS",
        60_000_000,
        f"{NV} §A.6, §4.5: gyro start-up 60 ms (DS table not retrieved) · TDK-HLH, LX",
        at_least=True,
    ),
    F("MAX_SPI_HZ", 24_000_000, f"{NV} §4.4: SPI 24 MHz max · BF, AP PR #16241, SUS"),
]

# The anti-alias programming table, all 63 rows: 3 dB bandwidth (Hz) -> (DELT, DELTSQR, BITSHIFT).
# DS-000347 v1.7 §5.3 (table number not verified; newer Zephyr cites "Table 17");
# icm42688p.md §1.2: ZAAF and XIO agree on every row; spot rows BF, AP, Rust, CN drivers.
ICM_AAF_ROWS = {
    42: (1, 1, 15), 84: (2, 4, 13), 126: (3, 9, 12), 170: (4, 16, 11), 213: (5, 25, 10),
    258: (6, 36, 10), 303: (7, 49, 9), 348: (8, 64, 9), 394: (9, 81, 9), 441: (10, 100, 8),
    488: (11, 122, 8), 536: (12, 144, 8), 585: (13, 170, 8), 634: (14, 196, 7),
    684: (15, 224, 7), 734: (16, 256, 7), 785: (17, 288, 7), 837: (18, 324, 7),
    890: (19, 360, 6), 943: (20, 400, 6), 997: (21, 440, 6), 1051: (22, 488, 6),
    1107: (23, 528, 6), 1163: (24, 576, 6), 1220: (25, 624, 6), 1277: (26, 680, 6),
    1336: (27, 736, 5), 1395: (28, 784, 5), 1454: (29, 848, 5), 1515: (30, 896, 5),
    1577: (31, 960, 5), 1639: (32, 1024, 5), 1702: (33, 1088, 5), 1766: (34, 1152, 5),
    1830: (35, 1232, 5), 1896: (36, 1296, 5), 1962: (37, 1376, 4), 2029: (38, 1440, 4),
    2097: (39, 1536, 4), 2166: (40, 1600, 4), 2235: (41, 1696, 4), 2306: (42, 1760, 4),
    2377: (43, 1856, 4), 2449: (44, 1952, 4), 2522: (45, 2016, 4), 2596: (46, 2112, 4),
    2671: (47, 2208, 4), 2746: (48, 2304, 4), 2823: (49, 2400, 4), 2900: (50, 2496, 4),
    2978: (51, 2592, 4), 3057: (52, 2720, 4), 3137: (53, 2816, 3), 3217: (54, 2944, 3),
    3299: (55, 3008, 3), 3381: (56, 3136, 3), 3464: (57, 3264, 3), 3548: (58, 3392, 3),
    3633: (59, 3456, 3), 3718: (60, 3584, 3), 3805: (61, 3712, 3), 3892: (62, 3840, 3),
    3979: (63, 3968, 3),
}  # fmt: skip
ICM42688P_FACTS += [F("AAF_TABLE", row, f"{AAF} §1.2", key=bw) for bw, row in ICM_AAF_ROWS.items()]
ICM42688P_FACTS.append(F("AAF_TABLE", tuple(ICM_AAF_ROWS), f"{AAF} §1.2: 63 rows", key=ROWS))

# =================================================================================================
# BMI088 (docs/chips/bmi088.md)
# DS = data sheet BST-BMI088-DS001-13 rev 1.3 (the only revision read). Accel register
# descriptions DS §5.3, gyro §5.5; map tables §5.2 / §5.4 (table numbers not verified).
# "NV" = the sheet says the section was not verified; the gyro FIFO registers are not in rev 1.3.
# =================================================================================================
BDS = "BST-BMI088-DS001-13 rev 1.3"
BNV = "DS section not verified; bmi088.md"
NOT13 = "not in DS rev 1.3 (later revisions not read); bmi088.md"

# GYRO_BANDWIDTH[3:0] code -> (output data rate Hz, filter bandwidth Hz). DS §5.5.5 (derived;
# table not retrieved); bmi088.md gyro table and open question (b) · BOSCH, LX-BMG
BMI_GYRO_BANDWIDTH_CODES = {
    0: (2000, 532), 1: (2000, 230), 2: (1000, 116), 3: (400, 47),
    4: (200, 23), 5: (100, 12), 6: (200, 64), 7: (100, 32),
}  # fmt: skip

BMI088_FACTS = [
    # --- accelerometer die addresses
    F("AccelRegister.ACC_CHIP_ID", 0x00, f"{BDS} §5.3.1 · BOSCH, PX-BMI"),
    # ACC_ERR_REG: the sheet cites DS §5.3.2 for its error code but lists no address; 0x02 is
    # BOSCH bmi08_defs.h BMI08_REG_ACCEL_ERR (checked in the stored copy), between §5.3.1 (0x00)
    # and §5.3.3 (0x03)
    F("AccelRegister.ACC_ERR_REG", 0x02, f"{BDS} §5.3.2 (address not in the sheet) · BOSCH"),
    F("AccelRegister.ACC_STATUS", 0x03, f"{BDS} §5.3.3 · BOSCH"),
    F("AccelRegister.ACC_X_LSB", 0x12, f"{BDS} §5.3.4 · BOSCH"),
    F("AccelRegister.SENSORTIME_0", 0x18, f"{BDS} §5.3.5 · BOSCH"),
    F("AccelRegister.TEMP_MSB", 0x22, f"{BDS} §5.3.7 · PX-BMI, LX-BMIa"),
    F("AccelRegister.TEMP_LSB", 0x23, f"{BDS} §5.3.7 · PX-BMI, LX-BMIa"),
    F("AccelRegister.FIFO_LENGTH_0", 0x24, f"{BNV} accel table · BOSCH, PX-BMI"),
    F("AccelRegister.FIFO_LENGTH_1", 0x25, f"{BNV} accel table · BOSCH, PX-BMI"),
    F("AccelRegister.FIFO_DATA", 0x26, f"{BNV} accel table · BOSCH, PX-BMI"),
    F("AccelRegister.ACC_CONF", 0x40, f"{BDS} §5.3.2 (error code); field table NV · BOSCH, PX-BMI"),
    F("AccelRegister.ACC_RANGE", 0x41, f"{BNV} accel table · PX-BMI, LX-BMIa, BOSCH"),
    F("AccelRegister.FIFO_DOWNS", 0x45, f"{BNV} accel table · BOSCH FIFO_DOWNS_ADDR"),
    F("AccelRegister.FIFO_WTM_0", 0x46, f"{BNV} accel table · BOSCH, PX-BMI"),
    F("AccelRegister.FIFO_WTM_1", 0x47, f"{BNV} accel table · BOSCH, PX-BMI"),
    F("AccelRegister.FIFO_CONFIG_0", 0x48, f"{BNV} accel table · BOSCH, PX-BMI"),
    F("AccelRegister.FIFO_CONFIG_1", 0x49, f"{BNV} accel table · BOSCH, PX-BMI"),
    F("AccelRegister.INT1_IO_CONF", 0x53, f"{BNV} accel table · BOSCH, PX-BMI"),
    F("AccelRegister.INT2_IO_CONF", 0x54, f"{BNV} accel table · BOSCH, PX-BMI"),
    F("AccelRegister.INT1_INT2_MAP_DATA", 0x58, f"{BNV} accel table · BOSCH, PX-BMI"),
    F("AccelRegister.ACC_PWR_CONF", 0x7C, f"{BNV} accel table · BOSCH, PX-BMI"),
    F("AccelRegister.ACC_PWR_CTRL", 0x7D, f"{BNV} accel table · BOSCH, PX-BMI"),
    F("AccelRegister.ACC_SOFTRESET", 0x7E, f"{BNV} accel table · BOSCH, PX-BMI"),
    # --- gyroscope die addresses
    F("GyroRegister.GYRO_CHIP_ID", 0x00, f"{BDS} §5.5.1 · BOSCH, PX-BMI"),
    F("GyroRegister.RATE_X_LSB", 0x02, f"{BDS} §5.5.2 · BOSCH"),
    F("GyroRegister.FIFO_STATUS", 0x0E, f"{NOT13} gyro table · BOSCH, PX-BMI"),
    F("GyroRegister.GYRO_RANGE", 0x0F, f"{BDS} §5.5.4 (from the §5.5.2 cross-reference) · BOSCH"),
    F("GyroRegister.GYRO_BANDWIDTH", 0x10, f"{BDS} §5.5.5 (derived) · BOSCH, LX-BMG"),
    F("GyroRegister.GYRO_LPM1", 0x11, f"{BDS} §5.5.6 (derived) · BOSCH"),
    F("GyroRegister.GYRO_SOFTRESET", 0x14, f"{BDS} §5.5.7 (derived) · BOSCH"),
    F("GyroRegister.GYRO_INT_CTRL", 0x15, f"{BDS} §5.5.8 (derived) · BOSCH, PX-BMI"),
    F("GyroRegister.INT3_INT4_IO_CONF", 0x16, f"{BDS} §5.5.9 (contents) · BOSCH, PX-BMI"),
    F("GyroRegister.INT3_INT4_IO_MAP", 0x18, f"{BDS} §5.5.10 (contents) · BOSCH, PX-BMI"),
    F("GyroRegister.FIFO_WM_ENABLE", 0x1E, f"{NOT13} gyro table · BOSCH, PX-BMI"),
    F("GyroRegister.FIFO_CONFIG_0", 0x3D, f"{NOT13} gyro table · BOSCH, PX-BMI"),
    F("GyroRegister.FIFO_CONFIG_1", 0x3E, f"{NOT13} gyro table · BOSCH, PX-BMI"),
    F("GyroRegister.FIFO_DATA", 0x3F, f"{NOT13} gyro table · BOSCH, PX-BMI"),
    # --- identity and commands
    F("ACC_CHIP_ID_VALUE", 0x1E, f"{BDS} §5.3.1 · BOSCH, PX-BMI ID_088"),
    F("GYRO_CHIP_ID_VALUE", 0x0F, f"{BDS} §5.5.1 · BOSCH, PX-BMI"),
    F("SOFTRESET_CMD", 0xB6, f"{BNV} ACC_SOFTRESET/GYRO_SOFTRESET · BOSCH SOFT_RESET_CMD"),
    F("ACC_FIFO_FLUSH_CMD", 0xB0, f"{BNV} ACC_SOFTRESET row · PX-BMI FIFOReset"),
    # --- ACC_STATUS (0x03), temperature, ACC_CONF (0x40), ACC_RANGE (0x41), power
    F("AccStatus.ACC_DRDY", 0x80, f"{BDS} §5.3.3 · BOSCH ACCEL_STATUS_MASK 0x80"),
    F("TEMP_INVALID_MSB", 0x80, f"{BDS} §5.3.7 (worked example: 0x80 = Invalid)"),
    F("ACC_CONF_BWP", 0xF0, f"{BNV} ACC_CONF row: [7:4] acc_bwp · BOSCH, PX-BMI"),
    F("ACC_CONF_ODR", 0x0F, f"{BNV} ACC_CONF row: [3:0] acc_odr · BOSCH, PX-BMI"),
    F("ACC_RANGE_FIELD", 0x03, f"{BNV} ACC_RANGE row: [1:0] · PX-BMI, LX-BMIa"),
    F("ACC_PWR_CONF_ACTIVE", 0x00, f"{BNV} ACC_PWR_CONF row · BOSCH ACCEL_PM_ACTIVE, PX-BMI"),
    F("ACC_PWR_CONF_SUSPEND", 0x03, f"{BNV} ACC_PWR_CONF row · BOSCH ACCEL_PM_SUSPEND"),
    F("ACC_PWR_CTRL_ON", 0x04, f"{BNV} ACC_PWR_CTRL row · BOSCH ACCEL_POWER_ENABLE 0x04"),
    F("ACC_PWR_CTRL_OFF", 0x00, f"{BNV} ACC_PWR_CTRL row · BOSCH, PX-BMI"),
    # --- accel FIFO_CONFIG_0 (0x48), FIFO_CONFIG_1 (0x49), FIFO_LENGTH (0x24-0x25)
    F("AccFifoConfig0.MUST_BE_ONE", 0x02, f"{BNV} FIFO_CONFIG_0 row · PX-BMI BIT1_ALWAYS"),
    F("AccFifoConfig0.FIFO_MODE", 0x01, f"{BNV} FIFO_CONFIG_0 row · BOSCH, PX-BMI FIFO_mode"),
    F("AccFifoConfig1.ACC_EN", 0x40, f"{BNV} FIFO_CONFIG_1 row · BOSCH ACCEL_EN_MASK 0x40"),
    F("AccFifoConfig1.MUST_BE_ONE", 0x10, f"{BNV} FIFO_CONFIG_1 row · PX-BMI BIT4_ALWAYS"),
    F("AccFifoConfig1.INT1_INPUT_EN", 0x08, f"{BNV} FIFO_CONFIG_1 row: bit3 · BOSCH, PX-BMI"),
    F("AccFifoConfig1.INT2_INPUT_EN", 0x04, f"{BNV} FIFO_CONFIG_1 row: bit2 · BOSCH, PX-BMI"),
    F("FIFO_LENGTH_1_BITS", 0x3F, f"{BNV} FIFO_LENGTH row · BOSCH BYTE_COUNTER_MSB_MASK 0x3F"),
    F("FIFO_LENGTH_EMPTY", 0x8000, "bmi088.md accel FIFO: bit 15 set = empty · AP-BMI"),
    # --- accel FIFO frame headers and sizes
    F("AccFifoHeader.ACCEL", 0x84, "bmi088.md accel FIFO · BOSCH FIFO_HEADER_ACC_FRM, PX-BMI"),
    F("AccFifoHeader.SKIP", 0x40, "bmi088.md accel FIFO · BOSCH, PX-BMI"),
    F("AccFifoHeader.SENSORTIME", 0x44, "bmi088.md accel FIFO · BOSCH, PX-BMI"),
    F("AccFifoHeader.INPUT_CONFIG", 0x48, "bmi088.md accel FIFO · BOSCH, PX-BMI"),
    F("AccFifoHeader.SAMPLE_DROP", 0x50, "bmi088.md accel FIFO · BOSCH, PX-BMI"),
    F("AccFifoHeader.OVER_READ", 0x80, "bmi088.md accel FIFO · BOSCH FIFO_HEAD_OVER_READ_MSB"),
    F(
        "ACC_FIFO_FRAME_BYTES",
        {0x84: 7, 0x40: 2, 0x44: 4, 0x48: 2, 0x50: 2},
        "bmi088.md accel FIFO frame sizes · BOSCH, PX-BMI",
    ),
    F("ACC_FIFO_HEADER_MASK", 0xFC, "bmi088.md accel FIFO: bits 1:0 are INT tags · PX-BMI, AP"),
    F("SKIP_UNKNOWN", 0xFF, "bmi088.md accel FIFO: skip payload 0xFF = >255 · BOSCH, PX-BMI"),
    # --- gyro GYRO_RANGE (0x0F), GYRO_BANDWIDTH (0x10), GYRO_LPM1 (0x11)
    F("GYRO_RANGE_FIELD", 0x07, f"{BDS} §5.5.4 (table not retrieved): [2:0] · BOSCH, LX-BMG"),
    F("GYRO_BANDWIDTH_FIELD", 0x0F, f"{BDS} §5.5.5 (derived): [3:0] · BOSCH GYRO_BW_MASK"),
    F("GYRO_BANDWIDTH_READS_ONE", 0x80, f"{BDS} §5.5.5 (derived) · BOSCH GYRO_ODR_RESET_VAL"),
    F("GYRO_LPM1_NORMAL", 0x00, f"{BDS} §5.5.6 (derived) · BOSCH"),
    F("GYRO_LPM1_SUSPEND", 0x80, f"{BDS} §5.5.6 (derived) · BOSCH"),
    F("GYRO_LPM1_DEEP_SUSPEND", 0x20, f"{BDS} §5.5.6 (derived) · BOSCH"),
    # --- gyro FIFO_STATUS (0x0E), FIFO_CONFIG_1 (0x3E)
    F("GyroFifoStatus.OVERRUN", 0x80, f"{NOT13} · BOSCH GYRO_FIFO_OVERRUN_MASK, PX-BMI"),
    F("GYRO_FIFO_FRAME_COUNT", 0x7F, f"{NOT13} · BOSCH GYRO_FIFO_FRAME_COUNT_MASK, PX-BMI"),
    F("GYRO_FIFO_MODE", 0xC0, f"{NOT13} FIFO_CONFIG_1[7:6] · BOSCH MODE_MASK 0xC0"),
    F("GYRO_FIFO_MODE_BYPASS", 0, f"{NOT13} FIFO_CONFIG_1 row · BOSCH, PX-BMI"),
    F("GYRO_FIFO_MODE_FIFO", 1, f"{NOT13} FIFO_CONFIG_1 row · BOSCH GYRO_FIFO_MODE 0x01"),
    F("GYRO_FIFO_MODE_STREAM", 2, f"{NOT13} FIFO_CONFIG_1 row · BOSCH GYRO_FIFO_STREAM"),
    F("GYRO_FIFO_DATA_SELECT", 0x03, f"{NOT13} FIFO_CONFIG_1[1:0] · BOSCH, PX-BMI"),
    # --- code tables
    F("ACCEL_RANGES_G", (3, 6, 12, 24), f"{BNV} ACC_RANGE row · PX-BMI, LX-BMIa, BOSCH"),
    F(
        "ACCEL_ODR_CODES",
        {12.5: 0x5, 25: 0x6, 50: 0x7, 100: 0x8, 200: 0x9, 400: 0xA, 800: 0xB, 1600: 0xC},
        f"{BNV} ACC_CONF row: acc_odr · BOSCH, PX-BMI",
    ),
    F(
        "ACCEL_BWP_CODES",
        {"osr4": 0x8, "osr2": 0x9, "normal": 0xA},
        f"{BNV} ACC_CONF row: acc_bwp · BOSCH, PX-BMI",
    ),
    F(
        "GYRO_RANGES_DPS",
        (2000, 1000, 500, 250, 125),
        f"{BDS} §5.5.4 (table not retrieved) · BOSCH, LX-BMG (PX-BMI header wrong)",
    ),
    F(
        "GYRO_BANDWIDTH_CODES",
        BMI_GYRO_BANDWIDTH_CODES,
        f"{BDS} §5.5.5 (derived; table not retrieved) · BOSCH GYRO_BW_*_ODR_*, LX-BMG",
    ),
    # --- FIFO sizes, sensortime
    F("ACC_FIFO_BYTES", 1024, "bmi088.md accel FIFO size · PX-BMI FIFO::SIZE"),
    F("ACC_FRAME_BYTES", 7, "bmi088.md accel FIFO: 0x84 frame, 7 bytes · BOSCH, PX-BMI"),
    F("GYRO_FIFO_FRAMES", 100, "bmi088.md gyro FIFO capacity · PX-BMI, BOSCH-EX"),
    F("GYRO_FRAME_BYTES", 6, "bmi088.md gyro FIFO frame · PX-BMI FIFO::DATA, BOSCH, FORUM"),
    F("SENSORTIME_S_PER_LSB", 39.0625e-6, f"{BDS} §5.3.5 · BOSCH SENSORTIME_RESOLUTION"),
    # --- delays (minimum waits) and bus limit
    F(
        "ACC_RESET_WAIT_NS",
        1_000_000,
        "bmi088.md reset table · BOSCH ACCEL_SOFTRESET_DELAY_MS 1",
        at_least=True,
    ),
    F(
        "GYRO_RESET_WAIT_NS",
        30_000_000,
        "bmi088.md reset table · BOSCH GYRO_SOFTRESET_DELAY 30, BOSCH-G",
        at_least=True,
    ),
    F(
        "ACC_POWER_WAIT_NS",
        5_000_000,
        "DS value not verified; bmi088.md · BOSCH POWER_CONFIG_DELAY 5, LX-BMIa",
        at_least=True,
    ),
    F("MAX_SPI_HZ", 10_000_000, f"{BNV} interface · PX-BMI SPI_SPEED 10 MHz"),
]

CHIPS: dict[str, tuple[ModuleType, list[Fact]]] = {
    "mpu6050": (mpu, MPU6050_FACTS),
    "icm42688p": (icm, ICM42688P_FACTS),
    "bmi088": (bmi, BMI088_FACTS),
}
# every other chip keeps its facts in tests/facts_<chip>.py (FACTS, cited the same way)
for _regs in sorted(CHIPS_DIR.glob("*/registers.py")):
    _chip = _regs.parent.name
    if _chip not in CHIPS and (ROOT / "tests" / f"facts_{_chip}.py").is_file():
        _facts = importlib.import_module(f"tests.facts_{_chip}")
        CHIPS[_chip] = (importlib.import_module(f"imud.chips.{_chip}.registers"), _facts.FACTS)


# -------------------------------------------------------------------------------------------------
# each fact against the register map
# -------------------------------------------------------------------------------------------------
def _lookup(module: ModuleType, fact: Fact) -> object:
    obj: object = module
    for part in fact.name.split("."):
        obj = getattr(obj, part)
    if fact.key == ROWS:
        return tuple(sorted(obj))  # type: ignore[call-overload]
    if fact.key is not None:
        obj = obj[fact.key]  # type: ignore[index]
    return obj.mask if isinstance(obj, BitField) else obj


def _show(v: object) -> str:
    if isinstance(v, int) and not isinstance(v, bool) and -0x10000 < v < 0x10000:
        return f"0x{int(v):02X} ({int(v)})" if v >= 0 else str(int(v))
    if isinstance(v, int) and not isinstance(v, bool):
        return f"{int(v):_}"
    return repr(v)


@pytest.mark.parametrize(
    ("chip", "fact"),
    [pytest.param(c, f, id=f"{c}:{f.id}") for c, (_, facts) in CHIPS.items() for f in facts],
)
def test_register_fact(chip: str, fact: Fact) -> None:
    module = CHIPS[chip][0]
    code = _lookup(module, fact)
    where = f"{module.__name__}.{fact.id}"
    if fact.at_least:
        assert code >= fact.value, (  # type: ignore[operator]
            f"{where} = {_show(code)}, datasheet minimum {_show(fact.value)} ({fact.cite})"
        )
    else:
        assert code == fact.value, (
            f"{where} = {_show(code)}, datasheet {_show(fact.value)} ({fact.cite})"
        )


@pytest.mark.parametrize("chip", list(CHIPS))
def test_fact_table_has_no_duplicates(chip: str) -> None:
    ids = [f.id for f in CHIPS[chip][1]]
    assert sorted({i for i in ids if ids.count(i) > 1}) == []


# -------------------------------------------------------------------------------------------------
# Register bytes composed from the map's fields, against bytes the sheets state (reset values
# and what imud writes): this checks the masks' positions together with the codes.
# -------------------------------------------------------------------------------------------------
ICM_LN = icm.MODE_LOW_NOISE


def _default_aaf(register: int) -> int:
    """The bits the ICM driver's plan sets in an anti-alias register for the default (reset)
    filter rows: they must be the chip's reset bytes."""
    from imud.chips.icm42688p.config import Icm42688pConfig
    from imud.chips.icm42688p.driver import register_plan

    cfg = Icm42688pConfig.model_validate(
        {"chip": "icm42688p", "name": "x", "bus": {"kind": "sim", "transport": "spi"}}
    )
    (setting,) = [s for s in register_plan(cfg) if s.bank and s.register == register]
    return setting.set_bits


COMPOSED: list[tuple[str, Callable[[], int], int, str]] = [
    # MPU6050
    (
        "mpu6050:PWR_MGMT_1 wake (CLKSEL = PLL X gyro)",
        lambda: mpu.PWR1_CLKSEL.bits(mpu.CLKSEL_PLL_XGYRO),
        0x01,
        "mpu6050.md PWR_MGMT_1 row: imud writes 0x01",
    ),
    (
        "mpu6050:FIFO_EN XG|YG|ZG|ACCEL",
        lambda: mpu.FifoEn.XG | mpu.FifoEn.YG | mpu.FifoEn.ZG | mpu.FifoEn.ACCEL,
        0x78,
        "mpu6050.md FIFO_EN row: imud writes 0x78",
    ),
    (
        "mpu6050:GYRO_CONFIG FS_SEL 3 (2000 dps)",
        lambda: mpu.GYRO_FS_SEL.bits(mpu.GYRO_RANGES_DPS.index(2000)),
        0x18,
        f"{RM} §4.4 (p. 14): FS_SEL [4:3] = 3",
    ),
    (
        "mpu6050:ACCEL_CONFIG AFS_SEL 3 (16 g)",
        lambda: mpu.ACCEL_AFS_SEL.bits(mpu.ACCEL_RANGES_G.index(16)),
        0x18,
        f"{RM} §4.5 (not retrieved); {PS} §6.2",
    ),
    (
        "mpu6050:CONFIG DLPF_CFG 1 (188 Hz)",
        lambda: mpu.CONFIG_DLPF_CFG.bits(mpu.DLPF_BANDWIDTHS_HZ.index(188)),
        0x01,
        f"{RM} §4.3 (table not retrieved) · LX-MPU, AP-INV, PX-MPU",
    ),
    # ICM-42688-P
    (
        "icm42688p:INTF_CONFIG0 big-endian, count in bytes (from reset 0x30)",
        lambda: (
            (0x30 | icm.IntfConfig0.FIFO_COUNT_ENDIAN | icm.IntfConfig0.SENSOR_DATA_ENDIAN)
            & ~(icm.IntfConfig0.FIFO_COUNT_REC | icm.IntfConfig0.FIFO_HOLD_LAST_DATA_EN)
        ),
        0x30,
        f"{NV} §A.1, §4.1: reset 0x30, imud 0x30",
    ),
    (
        "icm42688p:INTF_CONFIG1 AFSR off (from reset 0x91)",
        lambda: (0x91 & ~icm.INTF_CONFIG1_AFSR.mask) | icm.INTF_CONFIG1_AFSR.bits(icm.AFSR_OFF),
        0x51,
        f"{NV} §A.1, §4.2: reset 0x91, result 0x51 · AP PR #25332, #32040",
    ),
    (
        "icm42688p:FIFO_CONFIG stop-on-full",
        lambda: icm.FIFO_MODE.bits(icm.FIFO_MODE_STOP_ON_FULL),
        0x80,
        f"{A1}: imud writes mode 2 (0x80) · AP (0x80)",
    ),
    (
        "icm42688p:PWR_MGMT0 gyro and accel low-noise",
        lambda: icm.GYRO_MODE.bits(ICM_LN) | icm.ACCEL_MODE.bits(ICM_LN),
        0x0F,
        f"{DS} §14.36 (cited by Zephyr); {A1}: imud 0x0F",
    ),
    (
        "icm42688p:FIFO_CONFIG1 accel|gyro|temp",
        lambda: icm.FifoConfig1.ACCEL_EN | icm.FifoConfig1.GYRO_EN | icm.FifoConfig1.TEMP_EN,
        0x07,
        f"{A1}: imud 0x07 or 0x17",
    ),
    (
        "icm42688p:FIFO_CONFIG1 accel|gyro|temp|hires",
        lambda: (
            icm.FifoConfig1.ACCEL_EN
            | icm.FifoConfig1.GYRO_EN
            | icm.FifoConfig1.TEMP_EN
            | icm.FifoConfig1.HIRES_EN
        ),
        0x17,
        f"{A1}: imud 0x07 or 0x17",
    ),
    (
        "icm42688p:GYRO_CONFIG0 reset (2000 dps, 1 kHz)",
        lambda: (
            icm.GYRO_FS_SEL.bits(icm.GYRO_RANGES_DPS.index(2000))
            | icm.GYRO_ODR.bits(icm.ODR_CODES[1000])
        ),
        0x06,
        f"{A1}: reset 0x06 · PX-ICM",
    ),
    (
        "icm42688p:ACCEL_CONFIG0 reset (16 g, 1 kHz)",
        lambda: (
            icm.ACCEL_FS_SEL.bits(icm.ACCEL_RANGES_G.index(16))
            | icm.ACCEL_ODR.bits(icm.ODR_CODES[1000])
        ),
        0x06,
        f"{A1}: reset 0x06 · PX-ICM",
    ),
    (
        "icm42688p:GYRO_ACCEL_CONFIG0 reset (odr/4 both)",
        lambda: (
            icm.ACCEL_UI_FILT_BW.bits(icm.UI_FILTER_CODES["odr/4"])
            | icm.GYRO_UI_FILT_BW.bits(icm.UI_FILTER_CODES["odr/4"])
        ),
        0x11,
        f"{NV} §2.1: reset 0x11 (inferred; RUST42605 sibling, TDK-HL)",
    ),
    (
        "icm42688p:GYRO_CONFIG_STATIC3 reset (585 Hz row)",
        lambda: _default_aaf(icm.Bank1.GYRO_CONFIG_STATIC3),
        0x0D,
        f"{AAF} §1.1: reset 0x0D · XIO",
    ),
    (
        "icm42688p:GYRO_CONFIG_STATIC4 reset (585 Hz row)",
        lambda: _default_aaf(icm.Bank1.GYRO_CONFIG_STATIC4),
        0xAA,
        f"{AAF} §1.1: reset 0xAA · XIO",
    ),
    (
        "icm42688p:GYRO_CONFIG_STATIC5 reset (585 Hz row)",
        lambda: _default_aaf(icm.Bank1.GYRO_CONFIG_STATIC5),
        0x80,
        f"{AAF} §1.1: reset 0x80 · XIO",
    ),
    (
        "icm42688p:ACCEL_CONFIG_STATIC2 reset (1163 Hz row, AAF on)",
        lambda: _default_aaf(icm.Bank2.ACCEL_CONFIG_STATIC2),
        0x30,
        f"{AAF} §1.1: reset 0x30 · XIO",
    ),
    (
        "icm42688p:ACCEL_CONFIG_STATIC3 reset (1163 Hz row)",
        lambda: _default_aaf(icm.Bank2.ACCEL_CONFIG_STATIC3),
        0x40,
        f"{AAF} §1.1: reset 0x40 · XIO",
    ),
    (
        "icm42688p:ACCEL_CONFIG_STATIC4 reset (1163 Hz row)",
        lambda: _default_aaf(icm.Bank2.ACCEL_CONFIG_STATIC4),
        0x62,
        f"{AAF} §1.1: reset 0x62 · XIO",
    ),
    # BMI088
    (
        "bmi088:accel FIFO_CONFIG_0 stream mode",
        lambda: bmi.AccFifoConfig0.MUST_BE_ONE & ~bmi.AccFifoConfig0.FIFO_MODE,
        0x02,
        f"{BNV} FIFO_CONFIG_0 row: imud writes 0x02",
    ),
    (
        "bmi088:accel FIFO_CONFIG_1 acc_en",
        lambda: bmi.AccFifoConfig1.ACC_EN | bmi.AccFifoConfig1.MUST_BE_ONE,
        0x50,
        f"{BNV} FIFO_CONFIG_1 row: imud writes 0x50",
    ),
    (
        "bmi088:ACC_CONF normal, 1600 Hz",
        lambda: (
            bmi.ACC_CONF_BWP.bits(bmi.ACCEL_BWP_CODES["normal"])
            | bmi.ACC_CONF_ODR.bits(bmi.ACCEL_ODR_CODES[1600])
        ),
        0xAC,
        f"{BNV} ACC_CONF row: bwp 0xA normal, odr 0xC 1600 Hz · PX-BMI",
    ),
    (
        "bmi088:gyro FIFO_CONFIG_1 FIFO mode, X/Y/Z",
        lambda: (
            bmi.GYRO_FIFO_MODE.bits(bmi.GYRO_FIFO_MODE_FIFO) | bmi.GYRO_FIFO_DATA_SELECT.bits(0)
        ),
        0x40,
        f"{NOT13} FIFO_CONFIG_1 row: imud writes 0x40",
    ),
    (
        "bmi088:GYRO_BANDWIDTH reset (code 0, bit 7 reads 1)",
        lambda: bmi.GYRO_BANDWIDTH_READS_ONE | bmi.GYRO_BANDWIDTH_FIELD.bits(0),
        0x80,
        f"{BDS} §5.5.5 (derived): reset 0x80 · BOSCH GYRO_ODR_RESET_VAL",
    ),
]


@pytest.mark.parametrize(
    ("compose", "literal", "cite"), [pytest.param(*c[1:], id=c[0]) for c in COMPOSED]
)
def test_composed_register_byte(compose: Callable[[], int], literal: int, cite: str) -> None:
    code = int(compose())
    assert code == literal, f"composed from the map: {_show(code)}, sheet {_show(literal)} ({cite})"


def test_mpu6050_fifo_record_held_by_the_driver() -> None:
    """The MPU6050's FIFO record layout lives in its driver, not in the map."""
    from imud.chips.mpu6050 import driver

    # RM rev 4.2 §4.31 (p. 44): enabled sensors in register order, accel xyz then gyro xyz;
    # mpu6050.md FIFO: 12 bytes, FIFO_EN = 0x78 · PX-MPU FIFO::DATA (12 B)
    assert driver.SAMPLE_BYTES == 12
    assert driver.FIFO_SENSORS == 0x78


# -------------------------------------------------------------------------------------------------
# completeness: what the driver side uses, and every member of the map's enums, has a fact
# -------------------------------------------------------------------------------------------------
# a chip's datasheet facts the simulator shares besides its register map: its noise figures
# (noise.py), the one source of the noise it draws and of the ROS 2 covariances
SHARED_FACTS = ("registers", "noise")


def _driver_side_files(chip: str) -> list[Path]:
    """Every module of the chip's package except its shared facts and its simulator."""
    return sorted(
        p for p in (CHIPS_DIR / chip).glob("*.py") if p.stem not in (*SHARED_FACTS, "sim")
    )


def _is_class(regs: ModuleType, path: tuple[str, ...] | None) -> bool:
    """Whether `path` names one of the map's enum classes (only those get local aliases)."""
    return path is not None and len(path) == 1 and isinstance(getattr(regs, path[0], None), type)


def _map_refs(source: str, chip: str, regs: ModuleType) -> set[str]:
    """Register-map names a module references: "Class.MEMBER" for enum members, else "NAME"."""
    pkg, regmod = f"imud.chips.{chip}", f"imud.chips.{chip}.registers"
    tree = ast.parse(source)
    alias: dict[str, tuple[str, ...]] = {}  # local name -> path in the registers module
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name == regmod and a.asname:
                    alias[a.asname] = ()
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative, within the chip's package
                base = f"{pkg}.{base}" if base else pkg
            for a in node.names:
                if base == pkg and a.name == "registers":
                    alias[a.asname or a.name] = ()
                elif base == regmod:
                    alias[a.asname or a.name] = (a.name,)

    def resolve(n: ast.AST) -> tuple[str, ...] | None:
        if isinstance(n, ast.Name):
            return alias.get(n.id)
        if isinstance(n, ast.Attribute):
            base = resolve(n.value)
            return None if base is None else (*base, n.attr)
        return None

    changed = True  # local aliases: A, G = R.AccelRegister, R.GyroRegister; P1 = R.PwrMgmt1
    while changed:
        changed = False
        for node in ast.walk(tree):
            if not isinstance(node, ast.Assign):
                continue
            for target in node.targets:
                pairs = [(target, node.value)]
                if isinstance(target, ast.Tuple) and isinstance(node.value, ast.Tuple):
                    pairs = list(zip(target.elts, node.value.elts, strict=False))
                for t, v in pairs:
                    path = resolve(v)
                    if (
                        isinstance(t, ast.Name)
                        and path is not None
                        and t.id not in alias
                        and _is_class(regs, path)
                    ):
                        alias[t.id] = path
                        changed = True

    refs: set[str] = set()
    for node in ast.walk(tree):
        path = resolve(node)
        if not path:
            continue
        obj: object = regs
        names: list[str] = []
        found = True  # False: a name the map lacks, kept so that it has no fact either
        for part in path:  # down through the module and enum classes; stop at a value
            if not (obj is regs or isinstance(obj, enum.EnumMeta)):
                break
            names.append(part)
            if not hasattr(obj, part):
                found = False
                break
            obj = getattr(obj, part)
        if found and isinstance(obj, enum.EnumMeta):
            continue  # a class itself: its members are all checked below
        refs.add(".".join(names))
    for a_path in alias.values():  # names imported from the map count even if only re-exported
        if a_path and not isinstance(getattr(regs, a_path[0], None), enum.EnumMeta):
            refs.add(a_path[0])
    return refs


def _fact_names(chip: str) -> set[str]:
    return {f.name for f in CHIPS[chip][1]}


@pytest.mark.parametrize("chip", list(CHIPS))
def test_every_map_name_the_driver_uses_has_a_fact(chip: str) -> None:
    regs = CHIPS[chip][0]
    used: dict[str, set[str]] = {}
    for path in _driver_side_files(chip):
        for ref in _map_refs(path.read_text(), chip, regs):
            used.setdefault(ref, set()).add(path.name)
    assert used, f"{chip}: no register-map use found in the driver modules (scanner broken?)"
    missing = {r: sorted(files) for r, files in used.items() if r not in _fact_names(chip)}
    assert missing == {}, f"{chip}: used by the driver side without a datasheet fact here"


@pytest.mark.parametrize("chip", list(CHIPS))
def test_every_register_and_bit_of_the_map_has_a_fact(chip: str) -> None:
    regs = CHIPS[chip][0]
    members = {
        f"{name}.{member}"
        for name, cls in vars(regs).items()
        if isinstance(cls, enum.EnumMeta) and cls.__module__ == regs.__name__
        for member in cls.__members__
    }
    assert members, f"{chip}: no enum classes found in the register map"
    assert sorted(members - _fact_names(chip)) == []


def test_the_scanner_sees_every_way_of_naming_the_map() -> None:
    source = (
        "from imud.chips.bmi088 import registers as R\n"
        "from imud.chips.bmi088.registers import FIFO_LENGTH_1_BITS, AccFifoHeader as H\n"
        "A, G = R.AccelRegister, R.GyroRegister\n"
        "x = (A.ACC_CONF, G.FIFO_STATUS, R.GYRO_FIFO_FRAME_COUNT.get(3), H.SKIP,\n"
        "     R.AccFifoConfig1.ACC_EN, R.ACCEL_ODR_CODES[1600.0], R.NOT_A_NAME, G.NOT_A_REG,\n"
        "     R.GyroRegister.GYRO_RANGE.value)\n"
    )
    assert _map_refs(source, "bmi088", bmi) == {
        "AccelRegister.ACC_CONF",
        "GyroRegister.FIFO_STATUS",
        "GYRO_FIFO_FRAME_COUNT",
        "AccFifoHeader.SKIP",
        "AccFifoConfig1.ACC_EN",
        "ACCEL_ODR_CODES",
        "FIFO_LENGTH_1_BITS",
        "NOT_A_NAME",
        "GyroRegister.NOT_A_REG",
        "GyroRegister.GYRO_RANGE",
    }


# -------------------------------------------------------------------------------------------------
# simulators share the register map only: never the driver's scales, decoding or config
# -------------------------------------------------------------------------------------------------
# physical constants and rotation maths are facts, not a driver's arithmetic
GENERIC_SIM_IMPORTS = {
    "imud.chips.api", "imud.clock", "imud.channels", "imud.chips.bits",
    "imud.units", "imud.rotations",
}  # fmt: skip


def _module_file(name: str) -> Path | None:
    p = ROOT.joinpath(*name.split("."))
    for candidate in (p.with_suffix(".py"), p / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _imud_imports(path: Path, modname: str) -> set[str]:
    """Modules of imud a file imports (anywhere in it), as dotted names."""
    is_pkg = path.name == "__init__.py"
    package = modname if is_pkg else modname.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{parent}.{base}" if base else parent
            for a in node.names:
                sub = f"{base}.{a.name}"
                out.add(sub if _module_file(sub) else base)
    return {m for m in out if m == "imud" or m.startswith("imud.")}


def _driver_side_modules() -> set[str]:
    return {
        f"imud.chips.{chip}.{p.stem}"
        for chip in CHIPS
        for p in _driver_side_files(chip)
        if p.stem != "__init__"
    }


SIMS = sorted(p.parent.name for p in CHIPS_DIR.glob("*/sim.py"))


def test_every_chip_has_a_fact_section_and_a_simulator() -> None:
    with_map = {p.parent.name for p in CHIPS_DIR.glob("*/registers.py")}
    assert with_map == set(CHIPS)
    assert set(SIMS) >= set(CHIPS)


@pytest.mark.parametrize("chip", SIMS)
def test_simulator_imports_only_its_register_map(chip: str) -> None:
    modname = f"imud.chips.{chip}.sim"
    imported = _imud_imports(CHIPS_DIR / chip / "sim.py", modname)
    allowed = GENERIC_SIM_IMPORTS | {f"imud.chips.{chip}.{m}" for m in SHARED_FACTS}
    bad = sorted(m for m in imported if m not in allowed and not m.startswith("imud.sim"))
    assert bad == [], f"{modname} imports beyond its register map, noise figures and generics"
    assert f"imud.chips.{chip}.registers" in imported


@pytest.mark.parametrize("chip", SIMS)
def test_simulator_reaches_no_driver_module(chip: str) -> None:
    """Nothing the simulator loads, through any chain of imud imports (package __init__s
    included), is a driver, decoder or config model of any chip."""
    forbidden = _driver_side_modules()
    start = f"imud.chips.{chip}.sim"
    seen: dict[str, str] = {}  # module -> the module that imported it
    todo = [(start, "")]
    while todo:
        mod, via = todo.pop()
        if mod in seen:
            continue
        seen[mod] = via
        parts = mod.split(".")
        todo += [(".".join(parts[:i]), mod) for i in range(1, len(parts))]  # package __init__s
        path = _module_file(mod)
        if path is not None:
            todo += [(m, mod) for m in _imud_imports(path, mod)]
    reached = {m: seen[m] for m in sorted(forbidden & set(seen))}
    assert reached == {}, f"{start} reaches driver-side modules (module: imported by)"
