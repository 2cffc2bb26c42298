"""The STIM300's config: what the unit sends, and whether the link can carry it (the datasheet's
Table 5-12: at 921 600 bit/s, datagrams of 42 bytes or more reach only 1000 samples/s; at
1 843 200 every datagram reaches 2000)."""

from __future__ import annotations

from typing import Any

import pytest

from imud.config import parse_config
from imud.errors import ConfigError


def load(**kw: Any) -> Any:
    bus = kw.pop("bus", {"kind": "serial", "port": "/dev/ttyUSB0", "baud": 921_600})
    d = {"name": "s", "chip": "stim300", "bus": bus, **kw}
    return parse_config({"device": [d]}).device[0]


@pytest.mark.parametrize(
    ("datagram", "size"),
    [("rate", 18), ("rate_acc", 28), ("rate_incl", 28), ("rate_acc_incl", 38), ("rate_temp", 25)],
)
def test_datagrams_up_to_38_bytes_reach_2000_at_921600(datagram: str, size: int) -> None:
    assert load(datagram=datagram, odr_hz=2000).odr_hz == 2000


@pytest.mark.parametrize("datagram", ["rate_acc_temp", "rate_incl_temp", "rate_acc_incl_temp"])
def test_42_bytes_and_more_are_limited_to_1000_at_921600(datagram: str) -> None:
    assert load(datagram=datagram, odr_hz=1000).odr_hz == 1000
    with pytest.raises(ConfigError) as e:
        load(datagram=datagram, odr_hz=2000)
    msg = str(e.value)
    assert "bus.baud is 921600" in msg and "set the unit and bus.baud to 1843200" in msg


def test_every_datagram_reaches_2000_at_1843200() -> None:
    bus = {"kind": "serial", "port": "/dev/ttyUSB0", "baud": 1_843_200}
    assert load(bus=bus, datagram="rate_acc_incl_temp", odr_hz=2000).odr_hz == 2000


def test_a_slow_link_names_the_baud_it_needs() -> None:
    """0xA7 (59 bytes) at 500/s: 590 bits within 2 ms - 80 us = 307 292 bit/s at least."""
    bus = {"kind": "serial", "port": "/dev/ttyUSB0", "baud": 115_200}
    with pytest.raises(ConfigError) as e:
        load(bus=bus, datagram="rate_acc_incl_temp", odr_hz=500)
    assert "needs at least 307292 baud" in str(e.value)
    assert "374400" in str(e.value)


def test_rates_the_unit_cannot_sample_at_are_rejected() -> None:
    with pytest.raises(ConfigError) as e:
        load(odr_hz=300)
    assert "125, 250, 500, 1000, 2000" in str(e.value)


def test_accel_variant_and_transport() -> None:
    with pytest.raises(ConfigError) as e:
        load(accel_range_g=16)
    assert "accel_range_g" in str(e.value)
    with pytest.raises(ConfigError) as e:
        load(bus={"kind": "i2c", "bus": 1, "address": 0x28})
    assert "serial" in str(e.value)
    sim = load(bus={"kind": "sim", "transport": "serial", "baud": 1_843_200}, odr_hz=2000)
    assert sim.bus.baud == 1_843_200
