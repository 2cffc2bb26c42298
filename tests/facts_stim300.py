"""STIM300 facts (docs/chips/stim300.md): the datagram map the driver side and the simulator
share, each literal copied from the facts sheet with its citation. DS = Safran Sensonor STIM300
datasheet TS1524 rev.31 (Feb 2024); VTX = vortexntnu/stim300-driver, ROCK =
rock-drivers/drivers-imu_stim300, PYSTIM = cookednoodle/pystim300."""

from __future__ import annotations

from tests.regfacts import ROWS, F, Fact

DS = "TS1524 rev.31"
IDS = f"{DS} Tables 5-12, 5-21 · VTX stim300_constants.hpp, PYSTIM datagrams.py"
LAYOUT = f"{DS} Table 5-20 · VTX datagram_parser.cpp, PYSTIM"
SCALE = f"{DS} §7.5.2.2 Eq. 1-10 · PYSTIM scaling.py, VTX constants"
STATUS = f"{DS} Table 5-23, §7.6 · VTX driver_stim300.cpp"
CRC = f"{DS} §5.5.7 · VTX/ROCK boost crc_basic<32>(0x04C11DB7, 0xFFFFFFFF, 0, false, false)"

FACTS: list[Fact] = [
    # --- datagram identifiers and what each carries (acc, incl, temperatures)
    F("DatagramId.RATE", 0x90, IDS),
    F("DatagramId.RATE_ACC", 0x91, IDS),
    F("DatagramId.RATE_INCL", 0x92, IDS),
    F("DatagramId.RATE_ACC_INCL", 0x93, IDS),
    F("DatagramId.RATE_TEMP", 0x94, IDS),
    F("DatagramId.RATE_ACC_TEMP", 0xA5, IDS),
    F("DatagramId.RATE_INCL_TEMP", 0xA6, IDS),
    F("DatagramId.RATE_ACC_INCL_TEMP", 0xA7, IDS),
    F("CONTENT", (0x90, 0x91, 0x92, 0x93, 0x94, 0xA5, 0xA6, 0xA7), IDS, key=ROWS),
    F("CONTENT", (False, False, False), IDS, key=0x90),
    F("CONTENT", (True, False, False), IDS, key=0x91),
    F("CONTENT", (False, True, False), IDS, key=0x92),
    F("CONTENT", (True, True, False), IDS, key=0x93),
    F("CONTENT", (False, False, True), IDS, key=0x94),
    F("CONTENT", (True, False, True), IDS, key=0xA5),
    F("CONTENT", (False, True, True), IDS, key=0xA6),
    F("CONTENT", (True, True, True), IDS, key=0xA7),
    # --- field sizes
    F("ID_BYTES", 1, LAYOUT),
    F("AXIS_BYTES", 3, f"{LAYOUT} (24-bit two's complement, MSB first)"),
    F("TEMP_BYTES", 2, f"{LAYOUT} (int16)"),
    F("STATUS_BYTES", 1, LAYOUT),
    F("COUNTER_BYTES", 1, LAYOUT),
    F("LATENCY_BYTES", 2, f"{LAYOUT} (uint16, us)"),
    F("CRC_BYTES", 4, f"{LAYOUT}; {DS} §5.5.7 (MSB first)"),
    F("TERMINATION", b"\r\n", f"{DS} Table 5-20 (optional CR LF, not in the CRC)"),
    # --- STATUS byte
    F("Status.X", 0x01, STATUS),
    F("Status.Y", 0x02, STATUS),
    F("Status.Z", 0x04, STATUS),
    F("Status.CHANNEL_ERROR", 0x08, STATUS),
    F("Status.OVERLOAD", 0x10, STATUS),
    F("Status.OUTSIDE_CONDITIONS", 0x20, STATUS),
    F("Status.STARTUP", 0x40, STATUS),
    F("Status.SYSTEM_INTEGRITY", 0x80, STATUS),
    # --- scale factors
    F("GYRO_LSB_DPS", 2.0**-14, SCALE),
    F("ACCEL_LSB_G", (5, 10, 30, 80), f"{SCALE}; {DS} §12 (variants)", key=ROWS),
    F("ACCEL_LSB_G", 2.0**-20, SCALE, key=5),
    F("ACCEL_LSB_G", 2.0**-19, SCALE, key=10),
    F("ACCEL_LSB_G", 2.0**-18, SCALE, key=30),
    F("ACCEL_LSB_G", 2.0**-16, SCALE, key=80),
    F("INCL_LSB_G", 2.0**-22, SCALE),
    F("TEMP_LSB_C", 2.0**-8, SCALE),
    F("GYRO_RANGE_DPS", 400.0, f"{DS} Table 5-3"),
    F("GYRO_SATURATION_DPS", 480.0, f"{DS} Table 5-3"),
    F("INCL_RANGE_G", 1.7, f"{DS} Table 5-7"),
    # --- CRC
    F("CRC_POLY", 0x04C11DB7, CRC),
    F("CRC_INIT", 0xFFFFFFFF, CRC),
    F("CRC_WORD_BYTES", 4, f"{DS} §5.5.7 (dummy bytes to a multiple of 32 bits)"),
    # --- rates and timing
    F("INTERNAL_RATE_HZ", 2000, f"{DS} Table 5-11; §7.5.2.2.18 (counter)"),
    F("COUNTER_MODULO", 256, f"{DS} §7.5.2.2.18 (uint8, wraps) · ROCK Stim300RevD.cpp"),
    F("SAMPLE_RATES_HZ", (125, 250, 500, 1000, 2000), f"{DS} Table 5-11"),
    F("BIT_RATES", (374_400, 460_800, 921_600, 1_843_200), f"{DS} Table 5-2, 5-11"),
    F("BIT_RATE_MIN", 1_500, f"{DS} Table 5-11 (user-defined)"),
    F("BIT_RATE_MAX", 5_184_000, f"{DS} Table 5-11 (user-defined)"),
    F("LATENCY_MAX_US", 1000, f"{DS} Table 5-2, §7.2 · ROCK Stim300Base.hpp"),
    F("TX_DELAY_MAX_NS", 80_000, f"{DS} §7.3 (ttx_dl <= 80 us)"),
    F("STARTUP_TYP_NS", 700_000_000, f"{DS} Table 5-2, §7.5.2.1 (0.7 s typ)"),
    F("STARTUP_MAX_NS", 1_000_000_000, f"{DS} Table 5-2 (1 s max)"),
    F("FIRST_DATAGRAM_MAX_NS", 300_000_000, f"{DS} Table 5-2 (0.3 s after power-on)"),
]
