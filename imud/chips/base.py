"""What every chip module provides: a config model, a driver, a simulator factory."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

from imud.buses.models import Bus
from imud.errors import BusError, DeviceIdentityError, RegisterMismatch
from imud.sim.settings import SimSettings
from imud.timestamps import Stamped

__all__ = ["BusError", "DeviceIdentityError", "RegisterMismatch"]

if TYPE_CHECKING:
    from imud.clock import Clock


class DeviceBase(BaseModel):
    """Fields every `[[device]]` has, whatever its chip."""

    model_config = ConfigDict(extra="forbid")

    chip: str  # each chip's model narrows this to its Literal: the union's discriminator
    name: str = Field(
        pattern=r"^[A-Za-z0-9_-]{1,64}$", description="unique; used in key expressions"
    )
    bus: Bus
    calibration: Path | None = Field(None, description="calibration TOML, relative to the config")
    sim: SimSettings | None = Field(None, description="simulator settings (bus kind 'sim' only)")

    @field_validator("calibration")
    @classmethod
    def _relative_to_config(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        base = (info.context or {}).get("base_dir")
        if v is not None and not v.is_absolute() and base is not None:
            return Path(base) / v
        return v

    def die_buses(self) -> list[Bus]:
        """Where each die of the chip is wired; most chips are one die on `bus`."""
        return [self.bus]


@dataclass(slots=True)
class RawBatch:
    """One FIFO read in raw counts, before any pipeline stage.

    `t_before_ns`/`t_after_ns` bracket the instant the FIFO count was latched (host clock): the
    newest sample was produced no later than `t_after_ns`, and the one after it no earlier than
    `t_before_ns`. `resync` says continuity with the previous batch is broken (FIFO was reset);
    `restart_ns`, when known, brackets the write that re-enabled the FIFO: the first sample after
    a resync is the first one the chip latched after that write. For a stop-on-full FIFO that
    filled up, `fifo_full` is set and `restart_ns` brackets the read that made room again.
    """

    accel: npt.NDArray[Any]  # (N, 3) counts (int32; float64 when interpolated between dies)
    gyro: npt.NDArray[np.int32]  # (N, 3) counts
    temperature_c: npt.NDArray[np.float64]  # (N,)
    accel_scale: float  # m/s^2 per LSB
    gyro_scale: float  # rad/s per LSB
    t_before_ns: int
    t_after_ns: int
    resync: bool = False
    restart_ns: tuple[int, int] | None = None
    # per-sample: False where the chip marked a sample invalid (it becomes a counted hole)
    valid: npt.NDArray[np.bool_] | None = None
    # the FIFO was full: its newest sample is older than the read, and samples after it dropped
    fifo_full: bool = False
    # per-sample chip clock counter (e.g. the ICM-42688-P FIFO timestamp), modulo `ticks_modulo`
    chip_ticks: npt.NDArray[np.int64] | None = None
    ticks_modulo: int = 0
    # set by drivers that stamp their own samples (two dies on two clocks, see imud.pairing):
    # the pipeline then uses these instead of fitting the sample clock itself
    stamps: Stamped | None = None

    @property
    def n(self) -> int:
        return int(self.accel.shape[0])


@dataclass(slots=True)
class DriverCounters:
    fifo_overflows: int = 0
    fifo_resets: int = 0
    bad_transfers: int = 0
    bad_registers: int = 0
    resets: int = 0


class Driver(Protocol):
    """A chip driver: bytes on a bus to raw counts. Blocking; runs in its bus's worker thread."""

    nominal_period_ns: float
    poll_interval_ns: int
    fifo_capacity: int
    counters: DriverCounters

    def start(self) -> Iterator[int]:
        """Check identity, reset, configure and start the FIFO. Raises on failure.

        A generator: each value it yields is a wait in ns before it may continue (a reset delay),
        during which the bus is free for other devices."""

    def read(self) -> RawBatch:
        """Read whatever whole samples the FIFO holds."""

    def stop(self) -> None:
        """Put the chip to sleep (best effort)."""


class ChipSim(Protocol):
    """A register-level simulator of one chip, attached to a simulated bus at an address."""

    def read(self, register: int, length: int) -> bytes: ...

    def write(self, register: int, data: bytes) -> None: ...

    def drain_truth(self) -> dict[str, Any] | None:
        """True sample instants, specific force, rate and temperature since the last call."""


@dataclass(frozen=True)
class ChipSpec:
    """Registry entry: adding a chip is one module plus one line in `imud.chips`."""

    name: str
    config_model: type[DeviceBase]
    make_driver: Callable[[Any, Any, Clock], Driver]  # (config, transport, clock)
    make_sim: Callable[[Any, Clock], ChipSim]  # (config, clock)
    transports: tuple[str, ...]


def start_blocking(driver: Driver, clock: Clock) -> None:
    """Run a driver's start sequence to the end, sleeping on `clock` (tests, tools)."""
    for wait_ns in driver.start():
        clock.sleep_ns(wait_ns)
