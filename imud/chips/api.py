"""The typed interface every chip implements, and all that generic modules may know of a chip.

A chip is one folder under `imud/chips/` (register map, config model, driver, simulator) and one
`ChipSpec` in `imud.registry`. What differs between chips is declared here, so that the daemon,
the device runner, the pipeline, the bus processes and the config loader never name a chip nor
probe one with `getattr`:

- `DeviceBase`: the config fields every device has, `odr_hz` (the published rate) among them,
  and `die_buses()` (where each die is wired);
- `ChipSpec`: the config model, the bus kinds, the dies (`Die`: SPI dummy bytes), the channels the
  published stream carries, the driver and simulator factories, and the device's noise at its
  settings (`NoiseFigures`, for the ROS 2 covariances);
- `Driver`: bytes on a bus to a `RawBatch` of raw channels, with either host-time read brackets
  (`FifoRead`: the pipeline fits the chip's sample clock to them) or stamps of its own (`Stamped`:
  a chip of several dies on several clocks stamps each die itself);
- `SimChip`: register-level simulators behind the same bus interfaces as silicon, one die each
  (`SimDie`: byte registers; `SpiFrameDie`: a chip with its own SPI framing; `StreamDie`: a
  serial chip behind a pseudo-terminal).

A driver gets one link per die: a `RegisterDevice` (I2C, or SPI with the InvenSense/Bosch
address-byte convention), the `SpiDevLike` itself when its spec says `raw_spi` (a chip with its own
SPI framing, e.g. 16-bit words), or a `SerialPort` on a serial bus.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

from imud.buses.models import Bus
from imud.channels import Channel
from imud.settings import DeviceRos2, GyroBiasTracking, Orientation
from imud.sim.api import SimChip
from imud.sim.settings import SimSettings

if TYPE_CHECKING:
    from typing import TypeAlias

    from imud.buses.registers import RegisterDevice
    from imud.buses.serial import SerialPort
    from imud.buses.spi import SpiDevLike
    from imud.clock import Clock

    Link: TypeAlias = RegisterDevice | SpiDevLike | SerialPort


class DeviceBase(BaseModel):
    """Fields every `[[device]]` has, whatever its chip."""

    model_config = ConfigDict(extra="forbid")

    chip: str  # each chip's model narrows this to its Literal: the union's discriminator
    name: str = Field(
        pattern=r"^[A-Za-z0-9_-]{1,64}$", description="unique; used in key expressions"
    )
    bus: Bus
    if TYPE_CHECKING:
        # Every chip's model declares `odr_hz`, the published rate in samples per second, as a
        # field of its own (the registry checks): declared here, pydantic would validate it
        # before the chip's own fields, which its checks need.
        odr_hz: float
    calibration: Path | None = Field(None, description="calibration TOML, relative to the config")
    sim: SimSettings | None = Field(None, description="simulator settings (bus kind 'sim' only)")
    gyro_bias_tracking: GyroBiasTracking = Field(
        default_factory=GyroBiasTracking,
        description="re-learn the gyro bias whenever the device is still (off by default)",
    )
    orientation: Orientation = Field(
        default_factory=Orientation,
        description="imud's orientation filter on this device (off by default)",
    )
    ros2: DeviceRos2 = Field(
        default_factory=DeviceRos2, description="its ROS 2 topics, when [ros2] is on"
    )

    @field_validator("calibration")
    @classmethod
    def _relative_to_config(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        base = (info.context or {}).get("base_dir")
        if v is not None and not v.is_absolute() and base is not None:
            return Path(base) / v
        return v

    @property
    def publishes_truth(self) -> bool:
        """A simulated device whose simulator's ground truth is published (`sim.truth`)."""
        return self.sim is not None and self.sim.truth

    def die_buses(self) -> list[Bus]:
        """Where each die of the chip is wired, in the order of its spec's `dies`."""
        return [self.bus]


# --- what a driver returns ---------------------------------------------------------------------
@dataclass(slots=True)
class ChipCounter:
    """A per-sample counter on the chip's own clock (a FIFO timestamp, a data counter), modulo
    `modulo`: it makes the samples lost in a gap countable exactly. `per_sample`: its ticks a
    sample, when the driver knows them (a counter of samples, not of time): gaps are then counted
    by it from the first, where otherwise the ratio is learnt from samples read in a row, and a
    stream read only across gaps (a chip polled more slowly than it samples, at start-up) would
    have its gaps counted from host time meanwhile. `estimated`: the driver's own count, which
    it could not pin up to the first sample (a BNO055's, from read timing alone): the gap before
    it is published as an estimate (FLAG_GAP_UNCERTAIN), not as counted."""

    values: npt.NDArray[np.int64]
    modulo: int
    per_sample: int | None = None
    estimated: bool = False


@dataclass(slots=True)
class Stamped:
    """Stamps of a batch: `seq` of its first sample, chip samples lost right before it, one
    host-clock instant per sample, and the chip's sample period as fitted so far.

    `uncertain`: the batch follows a gap whose length the host's timing could not pin to one
    count (the reads and the FIFO restart were timed too loosely, or the chip restarted): its
    `lost_before`, and so its `first_seq`, are the sample clock's best estimate."""

    first_seq: int
    lost_before: int
    t_ns: npt.NDArray[np.int64]
    period_ns: float = 0.0
    uncertain: bool = False


@dataclass(slots=True)
class FifoRead:
    """Host-time brackets of one FIFO read, for the pipeline's sample-clock fit.

    `t_before_ns`/`t_after_ns` bracket the instant the FIFO count was latched: the newest sample
    was produced no later than `t_after_ns`, the one after it no earlier than `t_before_ns`.
    `resync`: continuity with the previous batch is broken (the FIFO was reset); `restart_ns`,
    when known, brackets the write that re-enabled the FIFO (its first sample is the first the
    chip latched after it). `fifo_full`: a stop-on-full FIFO filled up, so its newest sample is
    older than the read and `restart_ns` brackets the read that made room again."""

    t_before_ns: int
    t_after_ns: int
    resync: bool = False
    restart_ns: tuple[int, int] | None = None
    fifo_full: bool = False
    counter: ChipCounter | None = None


@dataclass(slots=True)
class RawChannel:
    """One channel of a batch before the pipeline: counts and what turns them into SI units."""

    data: npt.NDArray[Any]  # (N, width) or (N,): counts, or SI values with scale 1.0
    scale: float = 1.0  # SI units per count
    full_scale: float | None = None  # |count| at which the converter saturates
    invalid: npt.NDArray[np.bool_] | None = None  # per sample: the chip marked the value invalid


@dataclass(slots=True)
class RawBatch:
    """One read of a chip: N samples of the channels it produced, and how to stamp them."""

    n: int
    channels: dict[Channel, RawChannel]
    timing: FifoRead
    alarm: npt.NDArray[np.bool_] | None = None  # per sample: the chip's status raised an alarm
    # more of the same read, processed after this batch, in order: the samples after a break
    # inside it (a chip counter showed samples missing between two packets), or another die's
    then: RawBatch | None = None
    die: int = 0  # which of the spec's `dies` sampled these (a chip of several clocks)


@dataclass(slots=True)
class DriverCounters:
    """What a driver counts, for status. `chip` holds the counters its spec declares
    (`ChipSpec.counters`), which status shows under their own names."""

    fifo_overflows: int = 0
    fifo_resets: int = 0  # the driver emptied the FIFO (each start, each overflow)
    soft_resets: int = 0  # the driver reset the chip (each start)
    bad_transfers: int = 0  # read whole but found corrupt (CRC, checksum, framing)
    bad_registers: int = 0
    chip: dict[str, int] = field(default_factory=dict)


class Driver(Protocol):
    """A chip driver: bytes on a bus to raw counts. Blocking; runs in its bus's worker."""

    nominal_period_ns: float  # of the published stream
    poll_interval_ns: int
    # an absolute host time (ns) the driver wants its next poll at, set by its last read: a chip
    # without a FIFO is polled just after its next sample is due (phase-locked) instead of many
    # times a period. None: `poll_interval_ns` after the poll plus the runner's phase sweep
    next_poll_ns: int | None
    fifo_capacity: int  # samples the chip buffers (1 without a FIFO): how long a stall it survives
    # the configured low-pass filters' group delay (ns, nominal clock): the pipeline moves every
    # stamp back by it, so a stamp is the instant the motion happened (docs/timestamps.md)
    group_delay_ns: int
    counters: DriverCounters

    def start(self) -> Iterator[int]:
        """Check identity, reset, configure and start the FIFO. Raises on failure.

        A generator: each value it yields is a wait in ns before it may continue (a reset delay),
        during which the bus is free for other devices."""

    def read(self) -> RawBatch:
        """Read whatever whole samples the chip holds."""

    def stop(self) -> None:
        """Put the chip to sleep (best effort)."""

    def chip_status(self) -> dict[str, Any]:
        """Chip-specific health for `imud status` (JSON-serialisable), e.g. invalid packets."""


# --- the registry entry ------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class NoiseFigures:
    """A device's white noise at its configured settings, in SI units: what its ROS 2 messages'
    covariances are made of (imud.ros2.covariance, docs/ros2.md "Covariances").

    Each density is one-sided (a datasheet's: RMS = density * sqrt(noise bandwidth)) and each
    bandwidth the noise-equivalent bandwidth of one published sample at the configured filter and
    rate, so one sample's variance is density^2 * bandwidth. The magnetometer, for a chip that has
    one, is a per-sample standard deviation; `mag_hold` is how many published samples each of its
    readings lasts (a magnetometer slower than the published rate repeats its value)."""

    accel_density: float  # m/s^2/sqrt(Hz)
    accel_bandwidth_hz: float
    gyro_density: float  # rad/s/sqrt(Hz)
    gyro_bandwidth_hz: float
    mag_sigma_t: float | None = None  # tesla, per sample and axis
    mag_hold: int = 1

    def __post_init__(self) -> None:
        # a zero would publish "covariance unknown" for a noise the chip's spec claims to know
        values = [self.accel_density, self.accel_bandwidth_hz, self.gyro_density,
                  self.gyro_bandwidth_hz]  # fmt: skip
        if self.mag_sigma_t is not None:
            values.append(self.mag_sigma_t)
        if not all(math.isfinite(v) and v > 0 for v in values) or self.mag_hold < 1:
            raise ValueError(f"noise figures must be finite and positive: {self}")


@dataclass(frozen=True, slots=True)
class Die:
    """One die of a chip: its name (for messages) and the dummy bytes it clocks out before the
    data of an SPI read (a Bosch accel die sends one)."""

    name: str
    spi_dummy_bytes: int = 0


C = TypeVar("C", bound=DeviceBase)


@dataclass(frozen=True)
class ChipSpec(Generic[C]):
    """Registry entry: everything generic code may know of a chip."""

    name: str  # the config's `chip` value
    config_model: type[C]
    make_driver: Callable[[C, Sequence[Link], Clock], Driver]  # one link per die
    make_sim: Callable[[C, Clock], SimChip]
    transports: tuple[str, ...]  # bus kinds it works over: "i2c", "spi", "serial"
    channels: Channel  # what its published stream carries
    dies: tuple[Die, ...] = field(default=(Die("chip"),))
    raw_spi: bool = False  # its own SPI framing: the driver gets the SpiDevLike, not registers
    # counters of its own (`DriverCounters.chip`), shown by status under these names
    counters: tuple[str, ...] = ()
    # a chip whose dies sample on clocks of their own (each die's batches say which die,
    # `RawBatch.die`): each die's nominal sample period (ns) from its config. The pipeline stamps
    # each die on a sample clock of its own and interpolates the others onto the times of
    # `time_base`'s samples (imud.align). None: one clock for the chip.
    die_periods: Callable[[C], tuple[float, ...]] | None = None
    time_base: int = 0
    # the device's white noise at its configured settings, for its ROS 2 covariances. None: not
    # known, and the covariances say so (all zero, REP-145)
    noise: Callable[[C], NoiseFigures] | None = None
    # the sensor's class, which sets `imud calibrate`'s default tolerances (imud.calib.
    # acceptance.Grade): "consumer", "industrial" or "tactical"
    grade: str = "consumer"


def register_links(links: Sequence[Link]) -> list[RegisterDevice]:
    """The links of a chip that speaks byte registers on every die (a spec's driver factory)."""
    from imud.buses.registers import RegisterDevice

    out = [link for link in links if isinstance(link, RegisterDevice)]
    if len(out) != len(links):
        raise TypeError("this chip needs byte-register links (I2C, or SPI without raw_spi)")
    return out


def start_blocking(driver: Driver, clock: Clock) -> None:
    """Run a driver's start sequence to the end, sleeping on `clock` (tests, tools)."""
    for wait_ns in driver.start():
        clock.sleep_ns(wait_ns)
