"""The ADIS16465's `[[device]]` table: rates as 2000 / (dec_rate + 1), the model, the filter,
and the SPI settings the chip can and cannot use, with messages that say what to set."""

from __future__ import annotations

from typing import Any

import pytest

from imud.config import parse_config
from imud.errors import ConfigError

SIM = {"kind": "sim", "transport": "spi"}
SPI = {"kind": "spi", "path": "/dev/spidev0.0"}


def _device(**kw: Any) -> Any:
    d = {"name": "adis", "chip": "adis16465", "model": 3, "bus": SIM, **kw}
    return parse_config({"device": [d]}).device[0]


def _error(**kw: Any) -> str:
    with pytest.raises(ConfigError) as e:
        _device(**kw)
    return str(e.value)


@pytest.mark.parametrize(
    ("given", "dec_rate", "odr"),
    [
        ({}, 1, 1000.0),
        ({"dec_rate": 0, "deltas": False}, 0, 2000.0),
        ({"dec_rate": 3}, 3, 500.0),
        ({"odr_hz": 500}, 3, 500.0),
        ({"odr_hz": 666.667}, 2, 2000 / 3),
        ({"odr_hz": 1, "dec_rate": 1999}, 1999, 1.0),
        ({"odr_hz": 100, "dec_rate": 19}, 19, 100.0),
    ],
)
def test_rate_from_dec_rate_or_odr(given: dict[str, Any], dec_rate: int, odr: float) -> None:
    d = _device(**given)
    assert d.dec_rate == dec_rate and d.odr_hz == pytest.approx(odr, rel=1e-12)


def test_a_rate_the_chip_has_not_names_the_nearest() -> None:
    msg = _error(odr_hz=300)
    assert "2000 / (dec_rate + 1)" in msg
    assert "333.333 Hz (dec_rate = 5)" in msg and "285.714 Hz (dec_rate = 6)" in msg


def test_dec_rate_and_odr_must_agree() -> None:
    msg = _error(odr_hz=500, dec_rate=1)
    assert "dec_rate = 1 gives 1000 Hz" in msg and "dec_rate = 3" in msg


def test_out_of_range_fields() -> None:
    assert "dec_rate" in _error(dec_rate=2000)
    assert "filt_ctrl" in _error(filt_ctrl=7)
    assert "model" in _error(model=4)
    with pytest.raises(ConfigError, match="model"):
        parse_config({"device": [{"name": "a", "chip": "adis16465", "bus": SIM}]})


def test_deltas_at_2000_hz_exceed_the_reads_the_chip_allows() -> None:
    msg = _error(dec_rate=0)
    assert "14 register reads" in msg and "allows 12" in msg
    assert "deltas = false" in msg and "dec_rate >= 1" in msg
    assert _device(dec_rate=0, deltas=False).odr_hz == 2000.0


def test_spi_mode_and_clock() -> None:
    assert "SPI mode 3" in _error(bus={**SPI, "mode": 0})
    assert "0.1 MHz" in _error(bus={**SPI, "speed_hz": 50_000})
    # 200 kHz: a 176-bit burst (880 us) and 14 register frames (96 us each) do not fit 80 % of
    # a 1 ms period; at 500 Hz (dec_rate 3) they do not fit 2 ms either
    msg = _error(bus={**SPI, "speed_hz": 200_000})
    assert "use dec_rate >= 5 (333.333 Hz)" in msg and "deltas = false" in msg
    assert _device(bus={**SPI, "speed_hz": 200_000}, dec_rate=5).odr_hz == pytest.approx(
        333.333, rel=1e-5
    )
    # faster than the chip takes is fine: imud clocks frames at 2 MHz and bursts at 1 MHz
    assert _device(bus={**SPI, "speed_hz": 10_000_000}, dec_rate=0, deltas=False).dec_rate == 0


def test_the_default_bus_speed_carries_the_default_rate() -> None:
    d = _device(bus=SPI)  # spidev's default 1 MHz, mode 3
    assert (d.bus.speed_hz, d.bus.mode, d.odr_hz, d.deltas) == (1_000_000, 3, 1000.0, True)


def test_only_spi() -> None:
    assert "adis16465" in _error(bus={"kind": "i2c", "bus": 1, "address": 0x68}).lower()
