"""What a register-level simulator offers the simulated buses and the daemon: one die behind byte
registers (`SimDie`), whole SPI frames (`SpiFrameDie`) or a byte stream (`StreamDie`), and the
truth it sensed (`Truth`). Chips' simulators implement these; the simulated buses take them."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from imud.channels import Channel


@runtime_checkable
class SimDie(Protocol):
    """A register-level simulator of one die, attached to a simulated bus."""

    def read(self, register: int, length: int) -> bytes: ...

    def write(self, register: int, data: bytes) -> None: ...

    def spi_select(self) -> bool:
        """A chip-select edge. False: this transfer only woke the die's SPI interface (a Bosch
        accel die starts in I2C mode), so it is not answered."""


@runtime_checkable
class SpiFrameDie(Protocol):
    """A simulated die with its own SPI framing: it sees whole chip-select frames."""

    def spi_frame(self, tx: bytes, speed_hz: int) -> bytes:
        """One frame (chip select low, `tx` clocked out at `speed_hz`): the bytes on MISO."""


@runtime_checkable
class StreamDie(Protocol):
    """A simulated serial chip: bytes in from the host, bytes out on its own schedule."""

    def receive(self, data: bytes) -> None:
        """Bytes the host sent (in order, possibly split anywhere)."""

    def transmit(self, now_ns: int) -> bytes:
        """Every byte whose last bit has left the chip by `now_ns`, at the link's bit rate."""

    def next_transmit_ns(self) -> int | None:
        """When the next byte will have been sent (None: nothing scheduled)."""


@dataclass(slots=True)
class Truth:
    """What a simulated chip really sensed: true sample instants and values before any error."""

    index: int  # the chip's own sample index of the first sample (counts from its power-on)
    t_ns: npt.NDArray[np.int64]
    channels: dict[Channel, npt.NDArray[np.float64]]


class SimChip(Protocol):
    """All dies of one simulated chip, in the order of its spec's `dies`, and its truth."""

    @property
    def dies(self) -> Sequence[SimDie | SpiFrameDie | StreamDie]: ...

    def drain_truth(self) -> Truth | None:
        """Truth since the last call (None: nothing new, or truth recording is off)."""
