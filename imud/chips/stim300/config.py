"""The `[[device]]` table of a STIM300: what its configuration makes it send, and whether the
link can carry it.

The daemon does not configure a STIM300 (that is service mode's job, done once): the config says
what the unit was set to send, and the driver checks the stream against it.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, model_validator

from imud.chips.api import DeviceBase
from imud.chips.stim300.datagram import layout
from imud.chips.stim300.registers import (
    BIT_RATE_MAX,
    BIT_RATES,
    SAMPLE_RATES_HZ,
    TX_DELAY_MAX_NS,
    DatagramId,
)

Datagram = Literal[
    "rate",
    "rate_acc",
    "rate_incl",
    "rate_acc_incl",
    "rate_temp",
    "rate_acc_temp",
    "rate_incl_temp",
    "rate_acc_incl_temp",
]
BITS_PER_CHAR = 10  # 8N1: start, 8 data, stop


def datagram_id(name: Datagram) -> DatagramId:
    return DatagramId[name.upper()]


def min_baud(size: int, odr_hz: float) -> int:
    """The slowest bit rate that sends one datagram of `size` bytes per sample period, after the
    unit's transmit delay (ttx_dl): at 921 600 bit/s this allows 38-byte datagrams at 2000
    samples/s and limits 42-byte ones to 1000, as the datasheet's table of rates says."""
    window_ns = 1e9 / odr_hz - TX_DELAY_MAX_NS
    return math.ceil(size * BITS_PER_CHAR * 1e9 / window_ns)


class Stim300Config(DeviceBase):
    """A STIM300 on an RS422 link (a USB adapter, or a UART through an RS422 transceiver)."""

    chip: Literal["stim300"]
    datagram: Datagram = Field(
        "rate_acc_incl_temp", description="the normal-mode datagram the unit is set to send"
    )
    odr_hz: float = Field(
        2000.0, strict=True, description="the unit's sample rate: 125, 250, 500, 1000 or 2000"
    )
    accel_range_g: Literal[5, 10, 30, 80] = Field(
        10, description="accelerometer variant of the part number (sets its scale factor)"
    )
    line_termination: bool = Field(False, description="the unit appends CR LF to each datagram")
    filter_hz: Literal[16, 33, 66, 131, 262] = Field(
        262, description="the unit's low-pass filter (-3 dB): sets the group delay stamps lose"
    )

    @model_validator(mode="after")
    def _link_carries_it(self) -> Stim300Config:
        if self.odr_hz not in SAMPLE_RATES_HZ:
            raise ValueError(
                f"odr_hz = {self.odr_hz:g}: a STIM300 samples at "
                f"{', '.join(str(r) for r in SAMPLE_RATES_HZ)} Hz (or on an external trigger, "
                "which imud does not support)"
            )
        bus = self.bus
        if bus.transport != "serial":
            return self  # the config's transport check says what is wrong
        lay = layout(self.datagram_id, self.line_termination)
        need = min_baud(lay.size, self.odr_hz)
        baud = bus.clock_hz
        if baud < need:
            std = [b for b in BIT_RATES if b >= need]
            fix = (
                f"set the unit and bus.baud to {std[0]} (or slower: a lower odr_hz or a "
                "shorter datagram)"
                if std
                else "no standard bit rate is fast enough: lower odr_hz or send a shorter datagram"
            )
            raise ValueError(
                f"a {lay.size}-byte {self.datagram} datagram (0x{self.datagram_id:02X}) at "
                f"{self.odr_hz:g} samples/s needs at least {need} baud; bus.baud is {baud}: {fix}"
            )
        if baud > BIT_RATE_MAX:
            raise ValueError(f"bus.baud = {baud}: a STIM300 sends at most {BIT_RATE_MAX} bit/s")
        return self

    @property
    def datagram_id(self) -> DatagramId:
        return datagram_id(self.datagram)

    @property
    def counter_step(self) -> int:
        """Sample-counter increment per datagram (it counts the unit's 2000 Hz samples)."""
        from imud.chips.stim300.registers import INTERNAL_RATE_HZ

        return round(INTERNAL_RATE_HZ / self.odr_hz)
