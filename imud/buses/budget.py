"""What a chip's stream costs its bus: the one check of whether the configured clock carries it.

Bytes on the wire cost 9 clocks on I2C (8 bits and the acknowledge), 8 on SPI and 10 on a serial
link (start and stop bits); addressing, status and count reads and the gaps between transfers
add about a quarter (`OVERHEAD`). A chip names what it moves per second; `problem` says, naming
the bus's `speed_hz` (or `baud`) and the fix, when the bus cannot carry it.
"""

from __future__ import annotations

from imud.buses.models import Transport

BITS_PER_BYTE: dict[Transport, int] = {"i2c": 9, "spi": 8, "serial": 10}
OVERHEAD = 1.25  # addressing, status/count reads, gaps between transfers
_KIND = {"i2c": "I2C", "spi": "SPI", "serial": "the serial link"}
_FIELD = {"i2c": "bus.speed_hz", "spi": "bus.speed_hz", "serial": "bus.baud"}


def bits_per_second(transport: Transport, bytes_per_second: float) -> float:
    """The bus clock a stream of `bytes_per_second` needs on `transport`."""
    return bytes_per_second * BITS_PER_BYTE[transport] * OVERHEAD


def problem(
    transport: Transport, clock_hz: int, bytes_per_second: float, what: str, fix: str
) -> str | None:
    """Why a bus at `clock_hz` cannot carry `what` (`bytes_per_second` of transfers), ending in
    `fix`; None when it can."""
    need = bits_per_second(transport, bytes_per_second)
    if need <= clock_hz:
        return None
    return (
        f"{what} needs about {_si(need, 'bit/s')} on {_KIND[transport]} "
        f"({BITS_PER_BYTE[transport]} bits a byte, {OVERHEAD - 1:.0%} transfer overhead) but "
        f"the bus runs at {_si(clock_hz, 'Hz')} ({_FIELD[transport]}): {fix}"
    )


def _si(x: float, unit: str) -> str:
    if x >= 1e6:
        return f"{x / 1e6:.3g} M{unit}"
    return f"{x / 1e3:.3g} k{unit}"
