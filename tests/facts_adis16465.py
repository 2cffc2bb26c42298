"""ADIS16465 register facts (docs/chips/adis16465.md), checked by tests/test_register_facts.py.

DS = ADIS16465 data sheet Rev. B (Analog Devices). Its register map is Table 8; register
details follow in their own tables. The drivers the sheet quotes as agreeing: LX-475 (Linux
drivers/iio/imu/adis16475.c), NOOS (ADI no-OS drivers/imu/adis1646x.c), PX4-470 (PX4
ADIS16470 driver), AP-47x (ArduPilot AP_InertialSensor_ADIS1647x.cpp). Every literal here is the
sheet's, copied, never computed from imud's constants.
"""

from __future__ import annotations

from tests.regfacts import ROWS, F, Fact

DS = "ADIS16465 DS Rev. B"
MAP = f"{DS} Table 8 (register map) · LX-475, NOOS"
DIAG = f"{DS} Table 10 (DIAG_STAT) · LX-475 adis16475_status_error_msgs, NOOS, PX4-470"
GLOB = f"{DS} GLOB_CMD bit table (number not verified) · LX-475, NOOS, PX4-470"
MSC = f"{DS} Table 105 (MSC_CTRL) · LX-475, PX4-470, AP-47x"
SPI = f"{DS} Tables 1, 2, 7 (SPI timing) · LX-475, PX4-470"

FACTS: list[Fact] = [
    # --- register addresses (the low byte's address of each 16-bit register)
    F("Register.DIAG_STAT", 0x02, MAP),
    F("Register.X_GYRO_LOW", 0x04, MAP),
    F("Register.X_GYRO_OUT", 0x06, MAP),
    F("Register.Y_GYRO_LOW", 0x08, MAP),
    F("Register.Y_GYRO_OUT", 0x0A, MAP),
    F("Register.Z_GYRO_LOW", 0x0C, MAP),
    F("Register.Z_GYRO_OUT", 0x0E, MAP),
    F("Register.X_ACCL_LOW", 0x10, MAP),
    F("Register.X_ACCL_OUT", 0x12, MAP),
    F("Register.Y_ACCL_LOW", 0x14, MAP),
    F("Register.Y_ACCL_OUT", 0x16, MAP),
    F("Register.Z_ACCL_LOW", 0x18, MAP),
    F("Register.Z_ACCL_OUT", 0x1A, MAP),
    F("Register.TEMP_OUT", 0x1C, MAP),
    F("Register.TIME_STAMP", 0x1E, MAP),
    F("Register.DATA_CNTR", 0x22, f"{MAP}; {DS} Table 46"),
    F("Register.X_DELTANG_LOW", 0x24, MAP),
    F("Register.X_DELTANG_OUT", 0x26, MAP),
    F("Register.Y_DELTANG_LOW", 0x28, MAP),
    F("Register.Y_DELTANG_OUT", 0x2A, MAP),
    F("Register.Z_DELTANG_LOW", 0x2C, MAP),
    F("Register.Z_DELTANG_OUT", 0x2E, MAP),
    F("Register.X_DELTVEL_LOW", 0x30, MAP),
    F("Register.X_DELTVEL_OUT", 0x32, MAP),
    F("Register.Y_DELTVEL_LOW", 0x34, MAP),
    F("Register.Y_DELTVEL_OUT", 0x36, MAP),
    F("Register.Z_DELTVEL_LOW", 0x38, MAP),
    F("Register.Z_DELTVEL_OUT", 0x3A, MAP),
    F("Register.FILT_CTRL", 0x5C, f"{MAP}; {DS} Table 101"),
    F("Register.RANG_MDL", 0x5E, f"{MAP}; {DS} Table 103"),
    F("Register.MSC_CTRL", 0x60, f"{MAP}; {DS} Table 105"),
    F("Register.UP_SCALE", 0x62, MAP),
    F("Register.DEC_RATE", 0x64, f"{MAP}; {DS} Table 109"),
    F("Register.NULL_CNFG", 0x66, f"{MAP}; {DS} Table 111"),
    F("Register.GLOB_CMD", 0x68, f"{MAP} (write only)"),
    F("Register.FIRM_REV", 0x6C, MAP),
    F("Register.FIRM_DM", 0x6E, MAP),
    F("Register.FIRM_Y", 0x70, MAP),
    F("Register.PROD_ID", 0x72, f"{MAP}; {DS} Tables 120-121"),
    F("Register.SERIAL_NUM", 0x74, MAP),
    # --- DIAG_STAT (0x02): sticky, cleared by a read; bit 0 and [15:8] reserved
    F("DiagStat.DATAPATH_OVERRUN", 0x0002, DIAG),
    F("DiagStat.FLASH_UPDATE_FAILURE", 0x0004, DIAG),
    F("DiagStat.SPI_COMMUNICATION_ERROR", 0x0008, f"{DIAG}; DS 'Serial Port SCLK Underrun'"),
    F("DiagStat.STANDBY", 0x0010, DIAG),
    F("DiagStat.SENSOR_FAILURE", 0x0020, DIAG),
    F("DiagStat.MEMORY_FAILURE", 0x0040, DIAG),
    F("DiagStat.CLOCK_ERROR", 0x0080, DIAG),
    # --- GLOB_CMD (0x68): DIN sequences 0xE8xx, 0xE900
    F("GlobCmd.BIAS_CORRECTION_UPDATE", 0x01, GLOB),
    F("GlobCmd.FACTORY_CALIBRATION_RESTORE", 0x02, GLOB),
    F("GlobCmd.SENSOR_SELF_TEST", 0x04, f"{GLOB}; LX-475 self_test_mask BIT(2)"),
    F("GlobCmd.FLASH_MEMORY_UPDATE", 0x08, GLOB),
    F("GlobCmd.FLASH_MEMORY_TEST", 0x10, GLOB),
    F("GlobCmd.SOFTWARE_RESET", 0x80, f"{GLOB}: DIN 0xE880, 0xE900"),
    # --- MSC_CTRL (0x60)
    F("MscCtrl.LINEAR_G_COMPENSATION", 0x0080, MSC),
    F("MscCtrl.POINT_OF_PERCUSSION", 0x0040, MSC),
    F("MscCtrl.SYNC_POLARITY", 0x0002, MSC),
    F("MscCtrl.DR_POLARITY", 0x0001, f"{MSC}; LX-475 DR_POL BIT(0)"),
    F("MSC_CTRL_SYNC_MODE", 0x001C, f"{MSC}: [4:2]; LX-475 SYNC_MODE GENMASK(4, 2)"),
    F("SYNC_MODE_INTERNAL", 0, f"{MSC}: 000 internal clock"),
    F("MSC_CTRL_DEFAULT", 0x00C1, MSC),
    # --- FILT_CTRL (0x5C), DEC_RATE (0x64)
    F("FILT_CTRL_SIZE", 0x0007, f"{DS} Table 101: [2:0] · LX-475 FILT_CTRL_MASK GENMASK(2, 0)"),
    F("FILT_CTRL_MAX", 6, f"{DS} Table 101: B = 0 ... 6 · LX-475 adis16475_3db_freqs"),
    F("DEC_RATE_FIELD", 0x07FF, f"{DS} Table 109: [10:0]"),
    F("DEC_RATE_MAX", 1999, f"{DS} Table 109 · LX-475 max_dec 1999"),
    F("INTERNAL_RATE_HZ", 2000, f"{DS} Table 1 and Table 109 · LX-475 int_clk 2000"),
    # --- RANG_MDL (0x5E): model identifier
    F("RANG_MDL_RANGE", 0x000C, f"{DS} Table 103: [3:2] · AP-47x, PX4-507"),
    F("RANG_MDL_READS_ONE", 0x0003, f"{DS} Table 103: [1:0] read 11"),
    F(
        "RANG_MDL_CODES",
        {1: 0b00, 2: 0b01, 3: 0b11},
        f"{DS} Table 103: 00 +-125, 01 +-500, 11 +-2000 deg/s",
    ),
    F("GYRO_RANGES_DPS", {1: 125, 2: 500, 3: 2000}, f"{DS} Table 1 (ADIS16465-1/-2/-3)"),
    # --- identity
    F("PROD_ID_VALUE", 0x4051, f"{DS} Tables 120-121: 0x4051 = 16465 · LX-475, PX4-470"),
    F("FAMILY_PROD_IDS", "ADIS16467", "LX-475 ADIS16475_DATA(16467, ...)", key=16467),
    F(
        "FAMILY_PROD_IDS",
        "ADIS16470",
        "LX-475 ADIS16475_DATA(16470, ...) · AP-47x, PX4-470",
        key=16470,
    ),
    F("FAMILY_PROD_IDS", "ADIS16475", "LX-475 ADIS16475_DATA(16475, ...)", key=16475),
    F("FAMILY_PROD_IDS", "ADIS16477", "LX-475 ADIS16475_DATA(16477, ...) · AP-47x", key=16477),
    F("FAMILY_PROD_IDS", "ADIS16500", "LX-475 ADIS16475_DATA(16500, ...)", key=16500),
    F("FAMILY_PROD_IDS", "ADIS16505", "LX-475 ADIS16475_DATA(16505, ...)", key=16505),
    F("FAMILY_PROD_IDS", "ADIS16507", "LX-475 ADIS16475_DATA(16507, ...) · PX4-507", key=16507),
    F(
        "FAMILY_PROD_IDS",
        (16467, 16470, 16475, 16477, 16500, 16505, 16507),
        "LX-475 adis16475_chip_info: PROD_ID is the part number (16465 = 0x4051, DS)",
        key=ROWS,
    ),
    # --- SPI protocol
    F("WRITE", 0x80, f"{DS} 'Device Configuration' · LX-ADIS ADIS_WRITE_REG(r) 0x80 | r"),
    F("BURST_CMD", 0x6800, f"{DS} 'Burst Read Function' · LX-475 burst_reg_cmd GLOB_CMD"),
    F("BURST_FRAME_BYTES", 22, f"{DS} 'Burst Read Function': 176 bits · PX4-470 11 words"),
    F("BURST_CHECKSUM_BYTES", 18, f"{DS} burst checksum formula · LX-475 validate_crc"),
    F("DATA_CNTR_MODULO", 65536, f"{DS} Table 46: wraps 0xFFFF -> 0"),
    F("READS_PER_DR", 12, f"{DS} 'Maximum Throughput' (DEC_RATE = 0)"),
    F("SPI_MODE", 3, f"{SPI} · LX-DT spi-cpol + spi-cpha; PX4-470 SPIDEV_MODE3"),
    F("MAX_SCLK_HZ", 2_000_000, f"{SPI} · LX-DT 2 MHz, PX4-470 SPI_SPEED"),
    F("MAX_BURST_SCLK_HZ", 1_000_000, f"{SPI} · LX-475 BURST_MAX_SPEED, PX4-470"),
    F("MIN_SCLK_HZ", 100_000, f"{SPI}: 0.1 MHz minimum"),
    F("STALL_NS", 16_000, f"{SPI}: tSTALL · LX-475 cs_change_delay 16, PX4-470", at_least=True),
    F("READ_RATE_NS", 24_000, f"{SPI}: tREADRATE", at_least=True),
    # --- delays (minimum waits)
    F("SW_RESET_TIME_NS", 198_000_000, f"{DS} Table 1/113 · LX-475 200 ms, PX4-470 193 ms"),
    F("MSC_CTRL_WAIT_NS", 200_000, f"{MSC} · NOOS 200 us, LX-475 250 us", at_least=True),
]
