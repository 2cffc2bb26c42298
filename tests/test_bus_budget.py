"""The one bandwidth check every chip's config uses (`imud.buses.budget`), against arithmetic done
here: a byte costs 9 clocks on I2C (8 bits and the acknowledge), 8 on SPI and 10 on a UART (start
and stop bits), and a quarter more goes to addressing and gaps."""

from __future__ import annotations

import pytest

from imud.buses import budget
from imud.config import parse_config


@pytest.mark.parametrize(("transport", "clocks"), [("i2c", 9), ("spi", 8), ("serial", 10)])
def test_a_stream_fits_exactly_up_to_its_clock(transport: str, clocks: int) -> None:
    bytes_per_s = 10_000.0
    need = bytes_per_s * clocks * 1.25
    assert budget.problem(transport, int(need), bytes_per_s, "x", "y") is None  # type: ignore[arg-type]
    msg = budget.problem(transport, int(need) - 1, bytes_per_s, "the stream", "slow down")  # type: ignore[arg-type]
    assert (
        msg is not None and msg.startswith("the stream needs about") and msg.endswith("slow down")
    )
    assert ("bus.baud" if transport == "serial" else "bus.speed_hz") in msg


def test_every_bus_kind_says_its_transport_and_clock() -> None:
    devices = parse_config(
        {
            "device": [
                {"name": "a", "chip": "mpu6050", "bus": {"kind": "i2c", "bus": 1, "address": 0x68,
                                                         "speed_hz": 100_000}},
                {"name": "b", "chip": "icm42688p", "bus": {"kind": "spi", "path": "/dev/spidev0.0",
                                                           "speed_hz": 8_000_000}},
                {"name": "c", "chip": "stim300", "bus": {"kind": "serial", "port": "/dev/ttyUSB0",
                                                         "baud": 921_600}, "odr_hz": 500},
                {"name": "d", "chip": "mpu6050", "bus": {"kind": "sim", "bus": "s",
                                                         "address": 0x69}},
                {"name": "e", "chip": "icm42688p", "bus": {"kind": "sim", "bus": "t",
                                                           "transport": "spi"}},
            ]
        }
    ).device  # fmt: skip
    seen = [(d.bus.transport, d.bus.clock_hz, d.bus.simulated) for d in devices]
    assert seen == [
        ("i2c", 100_000, False),
        ("spi", 8_000_000, False),
        ("serial", 921_600, False),
        ("i2c", 400_000, True),  # a simulated bus's defaults: 400 kHz I2C ...
        ("spi", 10_000_000, True),  # ... 10 MHz SPI
    ]
