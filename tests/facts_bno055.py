"""BNO055 register facts (docs/chips/bno055.md), checked by tests/test_register_facts.py.

DS = Bosch Sensortec BNO055 data sheet BST-BNO055-DS000-14, rev 1.4 (June 2016), read as a
per-page text mirror: sections and tables named here were read on the pages given. The drivers
the sheet quotes as agreeing: LX-BNO (Linux drivers/iio/imu/bno055/bno055.c), LX-SER (Linux
bno055_ser_core.c), ADA (Adafruit_CircuitPython_BNO055), FLY (flynneva/bno055), BOSCH-055 (Bosch
BNO055 API bno055.h). Every literal here is the sheet's, copied, never computed from imud.
"""

from __future__ import annotations

from tests.regfacts import F, Fact

DS = "BST-BNO055-DS000-14 rev 1.4"
MAP = f"{DS} §4.2 register map (pp. 50-54)"
IDS = f"{DS} §4.3.1-4.3.4 (p. 55)"
MODES = f"{DS} Table 3-5 (p. 21) · LX-BNO, ADA, FLY"
UNITS = f"{DS} Table 3-11, Table 3-12 (p. 30) · LX-BNO, BOSCH-055"
PROFILE = f"{DS} §3.6.4 (pp. 31-33) · LX-BNO CALDATA 0x55-0x6A, ADA, FLY"
REMAP = f"{DS} §3.4 (p. 24)"
UART = f"{DS} §4.7 (p. 94) · LX-SER"

FACTS: list[Fact] = [
    # --- page 0 addresses
    F("Page0.CHIP_ID", 0x00, f"{IDS}; {MAP} · LX-BNO, ADA, FLY"),
    F("Page0.ACC_ID", 0x01, f"{IDS} · FLY, BOSCH-055"),
    F("Page0.MAG_ID", 0x02, f"{IDS} · FLY, BOSCH-055"),
    F("Page0.GYR_ID", 0x03, f"{IDS} · FLY, BOSCH-055"),
    F("Page0.SW_REV_ID_LSB", 0x04, f"{MAP} (p. 53) · LX-BNO, FLY"),
    F("Page0.SW_REV_ID_MSB", 0x05, f"{MAP} (p. 53) · LX-BNO, FLY"),
    F("Page0.BL_REV_ID", 0x06, f"{MAP} (p. 53) · FLY"),
    F("Page0.PAGE_ID", 0x07, f"{MAP} (p. 53) · LX-BNO PAGESEL 0x7"),
    F("Page0.ACC_DATA_X_LSB", 0x08, f"{MAP} (p. 53) · LX-BNO"),
    F("Page0.MAG_DATA_X_LSB", 0x0E, f"{MAP} (p. 53); §4.3.17 · LX-BNO"),
    F("Page0.GYR_DATA_X_LSB", 0x14, f"{MAP} (p. 53) · LX-BNO"),
    F("Page0.EUL_HEADING_LSB", 0x1A, f"{MAP} (p. 53) · LX-BNO"),
    F("Page0.QUA_DATA_W_LSB", 0x20, f"{DS} §4.3.33 (p. 63) · LX-BNO"),
    F("Page0.LIA_DATA_X_LSB", 0x28, f"{MAP} · LX-BNO"),
    F("Page0.GRV_DATA_X_LSB", 0x2E, f"{MAP} · LX-BNO"),
    F("Page0.TEMP", 0x34, f"{MAP}; {DS} §3.6.5.8 (p. 37) · LX-BNO"),
    F("Page0.CALIB_STAT", 0x35, f"{MAP} (section not retrieved) · LX-BNO, ADA, FLY"),
    F("Page0.SYS_STATUS", 0x39, f"{MAP} (section not retrieved) · FLY"),
    F("Page0.SYS_ERR", 0x3A, f"{MAP} (section not retrieved) · LX-BNO, FLY"),
    F("Page0.UNIT_SEL", 0x3B, f"{MAP}; {UNITS}"),
    F("Page0.OPR_MODE", 0x3D, f"{MAP}; {MODES}"),
    F("Page0.PWR_MODE", 0x3E, f"{MAP}; {DS} Table 3-1 (p. 19) · LX-BNO, ADA, FLY"),
    F("Page0.SYS_TRIGGER", 0x3F, f"{MAP}; {DS} §3.2 (p. 18) · LX-BNO"),
    F("Page0.AXIS_MAP_CONFIG", 0x41, f"{REMAP}; {MAP} · FLY"),
    F("Page0.AXIS_MAP_SIGN", 0x42, f"{REMAP}; {MAP} · FLY"),
    F("Page0.ACC_OFFSET_X_LSB", 0x55, f"{PROFILE} Table 3-15"),
    F("Page0.MAG_OFFSET_X_LSB", 0x5B, f"{PROFILE} (§3.6.4.2)"),
    F("Page0.GYR_OFFSET_X_LSB", 0x61, f"{PROFILE} (§3.6.4.3)"),
    F("Page0.ACC_RADIUS_LSB", 0x67, f"{PROFILE} Table 3-23"),
    F("Page0.MAG_RADIUS_LSB", 0x69, f"{PROFILE} Table 3-23"),
    # --- page 1
    F("Page1.GYR_CONFIG_0", 0x0A, f"{MAP} (page 1, not retrieved) · LX-BNO PG1(0xA), ADA"),
    F("Page1.UNIQUE_ID", 0x50, f"{MAP} (page 1, not retrieved) · LX-BNO UID 0x50-0x5F"),
    F("UID_LEN", 16, "LX-BNO BNO055_UID_LEN 16 (DS page-1 map not retrieved)"),
    F("GYR_RANGE", 0x07, "DS page-1 map not retrieved · LX-BNO GYR_CONFIG_RANGE_MASK GENMASK(2,0)"),
    F(
        "GYRO_RANGES_DPS",
        (2000, 1000, 500, 250, 125),
        f"{DS} Table 3-21 (p. 33) ranges; codes 0-4 · LX-BNO hw_xlate, ADA",
    ),
    # --- operating and power modes
    F("OprMode.CONFIG", 0x00, MODES),
    F("OprMode.ACCONLY", 0x01, MODES),
    F("OprMode.MAGONLY", 0x02, MODES),
    F("OprMode.GYROONLY", 0x03, MODES),
    F("OprMode.ACCMAG", 0x04, MODES),
    F("OprMode.ACCGYRO", 0x05, MODES),
    F("OprMode.MAGGYRO", 0x06, MODES),
    F("OprMode.AMG", 0x07, MODES),
    F("OprMode.IMU", 0x08, MODES),
    F("OprMode.COMPASS", 0x09, MODES),
    F("OprMode.M4G", 0x0A, MODES),
    F("OprMode.NDOF_FMC_OFF", 0x0B, MODES),
    F("OprMode.NDOF", 0x0C, MODES),
    F("OPR_MODE_FIELD", 0x0F, f"{MODES}: [OPR_MODE] xxxx____b"),
    F("FUSION_MODES", (0x08, 0x09, 0x0A, 0x0B, 0x0C), f"{MODES}: 'Fusion Mode' rows"),
    F("PwrMode.NORMAL", 0, f"{DS} Table 3-1 (p. 19) · LX-BNO"),
    F("PwrMode.LOW_POWER", 1, f"{DS} Table 3-1 (p. 19)"),
    F("PwrMode.SUSPEND", 2, f"{DS} Table 3-1 (p. 19)"),
    F("PWR_MODE_FIELD", 0x03, f"{DS} Table 3-1: [PWR_MODE] xxxxxx__b"),
    # --- SYS_TRIGGER, UNIT_SEL, CALIB_STAT, axis remap
    F("SysTrigger.CLK_SEL", 0x80, f"{DS} §4.3 SYS_TRIGGER (not retrieved) · LX-BNO BIT(7)"),
    F("SysTrigger.RST_SYS", 0x20, f"{DS} §3.2 (p. 18) names RST_SYS · LX-BNO BIT(5)"),
    F("UnitSel.ORI_ANDROID", 0x80, f"{UNITS} Table 3-12: 1xxxxxxxb = Android"),
    F("UnitSel.TEMP_F", 0x10, f"{UNITS} Table 3-11: xxx1xxxxb = °F"),
    F("UnitSel.EUL_RAD", 0x04, f"{UNITS} Table 3-11: xxxxx1xxb = radians"),
    F("UnitSel.GYR_RPS", 0x02, f"{UNITS} Table 3-11: xxxxxx1xb = rad/s · LX-BNO"),
    F("UnitSel.ACC_MG", 0x01, f"{UNITS} Table 3-11: xxxxxxx1b = mg"),
    F("CALIB_SYS", 0xC0, "DS CALIB_STAT section not retrieved · LX-BNO SYS_SHIFT 6, ADA, FLY"),
    F("CALIB_GYR", 0x30, "DS CALIB_STAT section not retrieved · LX-BNO GYRO_SHIFT 4, ADA"),
    F("CALIB_ACC", 0x0C, "DS CALIB_STAT section not retrieved · LX-BNO ACCEL_SHIFT 2, ADA"),
    F("CALIB_MAG", 0x03, "DS CALIB_STAT section not retrieved · LX-BNO MAGN_SHIFT 0, ADA"),
    F("CALIB_FULL", 0xFF, "every status at 3 · Bosch forum 'CALIB_STAT byte at 0x35 holds 0xFF'"),
    F("AXIS_REMAP_X", 0x03, f"{REMAP}: bits 1:0 remapped X"),
    F("AXIS_REMAP_Y", 0x0C, f"{REMAP}: bits 3:2 remapped Y"),
    F("AXIS_REMAP_Z", 0x30, f"{REMAP}: bits 5:4 remapped Z"),
    F("AXIS_MAP_CONFIG_DEFAULT", 0x24, f"{REMAP}: default 0x24 (X=X, Y=Y, Z=Z)"),
    F("AxisSign.X", 0x04, f"{REMAP}: sign byte bit 2 = remapped X"),
    F("AxisSign.Y", 0x02, f"{REMAP}: sign byte bit 1 = remapped Y"),
    F("AxisSign.Z", 0x01, f"{REMAP}: sign byte bit 0 = remapped Z"),
    # --- identity
    F("CHIP_ID_VALUE", 0xA0, f"{IDS}: read-only fixed value 0xA0 · LX-BNO, ADA, FLY"),
    F("ACC_ID_VALUE", 0xFB, f"{IDS}: fixed value 0xFB"),
    F("MAG_ID_VALUE", 0x32, f"{IDS}: fixed value 0x32"),
    F("GYR_ID_VALUE", 0x0F, f"{IDS}: fixed value 0x0F"),
    F("I2C_ADDRESSES", (0x28, 0x29), f"{DS} §4.6 Table 4-7 (p. 91): COM3 low 0x28, high 0x29"),
    # --- sizes
    F("DATA_BURST_LEN", 46, f"{MAP}: 0x08 ACC_DATA_X_LSB ... 0x35 CALIB_STAT"),
    F("OFFSETS_LEN", 22, f"{PROFILE}: 0x55-0x6A · LX-BNO CALDATA_LEN 22"),
    # --- scales
    F("ACC_LSB_PER_MS2", 100, f"{DS} Table 3-17 (p. 32), 3-33, 3-35 (p. 36): 1 m/s^2 = 100 LSB"),
    F("GYR_LSB_PER_RPS", 900, f"{DS} Table 3-22 (p. 33): 1 Rps = 900 LSB"),
    F("GYR_LSB_PER_DPS", 16, f"{DS} Table 3-22 (p. 33): 1 Dps = 16 LSB"),
    F("MAG_LSB_PER_UT", 16, "DS §3.6.4.2 table not retrieved · Bosch forum: 1 uT = 16 LSB"),
    F("QUA_LSB_PER_UNIT", 16384, f"{DS} Table 3-31 (p. 35): 1 quaternion = 2^14 LSB"),
    F("TEMP_LSB_PER_C", 1, f"{DS} Table 3-37 (p. 37): 1 °C = 1 LSB"),
    F("GYR_RAW_FULL_SCALE_COUNTS", 32768, "not in DS (firmware bug) · LX-BNO range/2^15"),
    F("ACCEL_FUSION_RANGE_G", 4, f"{DS} Table 3-4 (p. 21): accel 4G default · LX-BNO"),
    F("GYRO_DEFAULT_RANGE_DPS", 2000, f"{DS} Table 3-4 (p. 21): gyroscope 2000 dps"),
    F("FUSION_RATE_HZ", 100.0, f"{DS} Table 3-14 (p. 31): IMU, NDOF_FMC_OFF, NDOF 100Hz"),
    F("FUSION_MAG_RATE_HZ", 20.0, f"{DS} Table 3-14 (p. 31): NDOF mag output 20Hz"),
    # --- delays (minimum waits)
    F(
        "RESET_WAIT_NS",
        650_000_000,
        "DS start-up table not retrieved · LX-BNO 650-700 ms, ADA 0.7 s",
        at_least=True,
    ),
    F("CONFIG_TO_MODE_WAIT_NS", 7_000_000, f"{DS} Table 3-6 (p. 21): 7ms", at_least=True),
    F("MODE_TO_CONFIG_WAIT_NS", 19_000_000, f"{DS} Table 3-6 (p. 21): 19ms", at_least=True),
    # --- UART protocol
    F("Uart.START", 0xAA, UART),
    F("Uart.WRITE", 0x00, UART),
    F("Uart.READ", 0x01, UART),
    F("Uart.READ_RESPONSE", 0xBB, UART),
    F("Uart.STATUS_RESPONSE", 0xEE, UART),
    F("UartStatus.WRITE_SUCCESS", 0x01, UART),
    F("UartStatus.READ_FAIL", 0x02, UART),
    F("UartStatus.WRITE_FAIL", 0x03, UART),
    F("UartStatus.REGMAP_INVALID_ADDRESS", 0x04, UART),
    F("UartStatus.REGMAP_WRITE_DISABLED", 0x05, UART),
    F("UartStatus.WRONG_START_BYTE", 0x06, UART),
    F("UartStatus.BUS_OVER_RUN_ERROR", 0x07, UART),
    F("UartStatus.MAX_LENGTH_ERROR", 0x08, UART),
    F("UartStatus.MIN_LENGTH_ERROR", 0x09, UART),
    F("UartStatus.RECEIVE_CHARACTER_TIMEOUT", 0x0A, UART),
    F("UART_BAUD", 115_200, f"{UART}: 115200 bps, 8N1"),
    F("UART_MAX_LENGTH", 128, f"{UART}: maximum length for read and write 128 Byte"),
    F("UART_RX_TIMEOUT_NS", 30_000_000, "DS §4.7 names the code only · LX-SER 'timeout is 30mS'"),
]
