"""A device's status: one record, filled by its runner in the bus worker, relayed by the daemon
(which adds up the counters of a bus process's earlier lives), served as JSON and shown by the CLI.

Every field says how it combines across the lives of a bus process (`TOTAL`: summed; anything
else: the newest life's value), so the daemon never lists counters by name.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from enum import StrEnum
from typing import Any

from imud.errors import BUS_ERROR_KEYS


class DeviceState(StrEnum):
    STARTING = "starting"  # the start sequence is running (or the bus is being opened)
    RUNNING = "running"
    ERROR = "error"  # failed; retrying with backoff (`last_error` says why)
    STOPPED = "stopped"


TOTAL = "total"  # field metadata: the counter adds up over the lives of the bus process
LABEL = "label"  # field metadata: how `imud status` names a nonzero counter below its table


def _counter(label: str | None = None) -> Any:
    """A counter; `label`: `imud status` names it below its table when it is not zero (the
    ones without are part of normal running, shown in --json)."""
    return field(default=0, metadata={TOTAL: True, LABEL: label})


@dataclass(slots=True)
class DeviceStatus:
    # --- what the device is (from its config and its chip's spec) ---
    name: str
    chip: str
    bus: str
    odr_hz: float
    channels: list[str]
    truth: bool
    state: DeviceState = DeviceState.STARTING
    # --- rates ---
    measured_rate_hz: float = 0.0  # delivered samples per second over the last ~5 s
    chip_rate_hz: float | None = None  # the chip's output rate, from its fitted sample clock
    poll_late_max_ms: float = 0.0  # how late the worker came to a poll, worst of ~10 s
    # --- counters ---
    samples: int = _counter()
    lost_samples: int = _counter("lost")
    # gaps whose length the host's timing could not pin to one count (FLAG_GAP_UNCERTAIN)
    uncertain_gaps: int = _counter("gaps counted as estimates")
    invalid_samples: int = _counter("invalid samples")
    fifo_overflows: int = _counter("FIFO overflows")
    fifo_resets: int = _counter()  # the driver emptied the FIFO (each start, each overflow)
    soft_resets: int = _counter()  # the driver reset the chip (each start)
    bus_errors: int = _counter("bus errors")  # transfers that failed, all kinds; then per kind
    bus_errors_nak: int = _counter("nak")
    bus_errors_eio: int = _counter("eio")
    bus_errors_timeout: int = _counter("timeout")
    bus_errors_other: int = _counter("other")
    garbled_transfers: int = _counter("garbled transfers")  # read whole, found corrupt
    bad_registers: int = _counter("bad registers")
    restarts: int = _counter("restarts")
    resets: int = _counter("chip resets")  # detected by the register re-check: re-initialised
    unexpected_errors: int = _counter("unexpected errors")
    publish_dropped: int = _counter("publish drops")
    calibration_outside_span: int = _counter("samples outside the calibration's temperature span")
    # counters the chip's spec declares (`ChipSpec.counters`), e.g. frames whose CRC failed
    chip_counters: dict[str, int] = field(default_factory=dict, metadata={TOTAL: True})
    # --- the rest ---
    temperature_c: float | None = None
    calibration: str | None = None  # the file being applied; None: uncalibrated
    calibration_error: str | None = None  # why the configured file is not applied
    raw_subscribed: bool = False
    # None: off; else {state, bias_rad_s, windows, learned_windows} (imud.calib.track)
    gyro_bias_tracking: dict[str, Any] | None = None
    # None: off; else {state, bias_rad_s, heading, counters} (imud.orient.stage)
    orientation: dict[str, Any] | None = None
    last_error: str | None = None
    last_error_at: float | None = None  # wall-clock seconds
    chip_status: dict[str, Any] = field(default_factory=dict)  # the driver's own health

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, body: dict[str, Any]) -> DeviceStatus:
        """A snapshot sent as JSON; keys this version does not know are left out."""
        known = {k: v for k, v in body.items() if k in _NAMES}
        out = cls(**known)
        out.state = DeviceState(out.state)
        return out

    def plus(self, earlier: DeviceStatus) -> DeviceStatus:
        """This life's status with the counters of `earlier` lives added."""
        mine, theirs = self.to_json(), earlier.to_json()
        for name in TOTALS:
            a, b = mine[name], theirs[name]
            mine[name] = (
                {k: a.get(k, 0) + b.get(k, 0) for k in a | b} if isinstance(a, dict) else a + b
            )
        return DeviceStatus.from_json(mine)


_NAMES = frozenset(f.name for f in fields(DeviceStatus))
TOTALS = tuple(f.name for f in fields(DeviceStatus) if f.metadata.get(TOTAL))
# the counters `imud status` names below its table when they are not zero, with their labels
LABELS: dict[str, str] = {
    f.name: f.metadata[LABEL] for f in fields(DeviceStatus) if f.metadata.get(LABEL)
}
assert set(BUS_ERROR_KEYS.values()) <= _NAMES, "every kind of bus error has a counter"
