"""The STIM300's wire map: normal-mode datagram identifiers, their layout, STATUS bits, scale
factors, the CRC and the link's rates (docs/chips/stim300.md, with sources).

The STIM300 has no registers a host writes in normal mode: it streams one datagram per sample
from power-on, in the format its configuration (set in service mode or at the factory) selects.
This module is to it what a register map is to the other chips: every number the driver side
and the simulator share.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag


class DatagramId(IntEnum):
    """Normal-mode datagram identifiers (first byte): which clusters follow the gyros."""

    RATE = 0x90
    RATE_ACC = 0x91
    RATE_INCL = 0x92
    RATE_ACC_INCL = 0x93
    RATE_TEMP = 0x94
    RATE_ACC_TEMP = 0xA5
    RATE_INCL_TEMP = 0xA6
    RATE_ACC_INCL_TEMP = 0xA7


# (accelerometers, inclinometers, temperatures) in each datagram
CONTENT: dict[DatagramId, tuple[bool, bool, bool]] = {
    DatagramId.RATE: (False, False, False),
    DatagramId.RATE_ACC: (True, False, False),
    DatagramId.RATE_INCL: (False, True, False),
    DatagramId.RATE_ACC_INCL: (True, True, False),
    DatagramId.RATE_TEMP: (False, False, True),
    DatagramId.RATE_ACC_TEMP: (True, False, True),
    DatagramId.RATE_INCL_TEMP: (False, True, True),
    DatagramId.RATE_ACC_INCL_TEMP: (True, True, True),
}


class Status(IntFlag):
    """A cluster's STATUS byte (gyro, accel, inclinometer, and each temperature cluster). Not
    latched; below 2000 samples/s it accumulates the status of the sub-samples."""

    X = 0x01  # with OVERLOAD or CHANNEL_ERROR: the axes concerned
    Y = 0x02
    Z = 0x04
    CHANNEL_ERROR = 0x08  # error in a measurement channel
    OVERLOAD = 0x10  # an axis beyond its range
    OUTSIDE_CONDITIONS = 0x20  # outside operating conditions
    STARTUP = 0x40  # still starting up: the data are not valid yet
    SYSTEM_INTEGRITY = 0x80  # system integrity error


# --- field sizes (bytes) ----------------------------------------------------------------------
ID_BYTES = 1
AXIS_BYTES = 3  # 24-bit two's complement, MSB first
TEMP_BYTES = 2  # int16, MSB first
STATUS_BYTES = 1
COUNTER_BYTES = 1
LATENCY_BYTES = 2  # uint16, microseconds
CRC_BYTES = 4  # MSB first
TERMINATION = b"\r\n"  # optional, after the CRC; not covered by it

# --- scale factors ----------------------------------------------------------------------------
GYRO_LSB_DPS = 2.0**-14  # angular rate
ACCEL_LSB_G: dict[int, float] = {5: 2.0**-20, 10: 2.0**-19, 30: 2.0**-18, 80: 2.0**-16}
INCL_LSB_G = 2.0**-22
TEMP_LSB_C = 2.0**-8
GYRO_RANGE_DPS = 400.0
GYRO_SATURATION_DPS = 480.0
INCL_RANGE_G = 1.7

# --- CRC: CRC-32/MPEG-2 over the ID and data, zero-padded to a multiple of 4 bytes ------------
CRC_POLY = 0x04C11DB7
CRC_INIT = 0xFFFFFFFF
CRC_WORD_BYTES = 4

# --- timing -----------------------------------------------------------------------------------
INTERNAL_RATE_HZ = 2000  # the sample counter counts these
COUNTER_MODULO = 256
SAMPLE_RATES_HZ = (125, 250, 500, 1000, 2000)
BIT_RATES = (374_400, 460_800, 921_600, 1_843_200)  # standard; user-defined 1500-5184000
BIT_RATE_MIN, BIT_RATE_MAX = 1_500, 5_184_000
LATENCY_MAX_US = 1000
TX_DELAY_MAX_NS = 80_000  # ttx_dl: from the end of the latency to the first bit on the line
STARTUP_TYP_NS = 700_000_000  # STATUS start-up bit set until valid data
STARTUP_MAX_NS = 1_000_000_000
FIRST_DATAGRAM_MAX_NS = 300_000_000  # after power-on
