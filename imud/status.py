"""Device states and the shape of a device's status, shared by the runner (which fills it), the
bus process proxy (which relays it), the daemon and the CLI (which show it)."""

from __future__ import annotations

from enum import StrEnum
from typing import Any

from imud import registry
from imud.buses.models import describe
from imud.calib.track import GyroBiasTracker
from imud.channels import CHANNELS, channels_in
from imud.chips.api import DeviceBase
from imud.errors import BUS_ERROR_KEYS


class DeviceState(StrEnum):
    STARTING = "starting"  # the start sequence is running (or the bus is being opened)
    RUNNING = "running"
    ERROR = "error"  # failed; retrying with backoff (`last_error` says why)
    STOPPED = "stopped"


def initial_status(cfg: DeviceBase) -> dict[str, Any]:
    """A device's status before anything has run: every key the runner reports, zeroed."""
    spec = registry.CHIPS[cfg.chip]
    return {
        "name": cfg.name,
        "chip": cfg.chip,
        "bus": " + ".join(describe(b) for b in cfg.die_buses()),
        "state": DeviceState.STARTING,
        "odr_hz": float(cfg.odr_hz),
        "channels": [CHANNELS[c].key for c in channels_in(spec.channels)],
        "truth": bool(cfg.sim is not None and cfg.sim.truth),
        "measured_rate_hz": 0.0,
        "chip_rate_hz": None,
        "samples": 0,
        "lost_samples": 0,
        "invalid_samples": 0,
        "fifo_overflows": 0,
        "bus_errors": 0,  # transfers that failed, all kinds; then per kind (imud.errors)
        **dict.fromkeys(BUS_ERROR_KEYS.values(), 0),
        "garbled_transfers": 0,  # read whole, found corrupt by the driver (CRC, checksum)
        "crc_errors": 0,  # of those, a CRC failed
        "checksum_errors": 0,  # of those, a checksum failed
        "bad_registers": 0,
        "restarts": 0,
        "resets": 0,  # chip resets detected by the register re-check (re-initialised)
        "unexpected_errors": 0,
        "poll_late_max_ms": 0.0,
        "publish_dropped": 0,
        "temperature_c": None,
        "calibration": None,  # the file being applied; None: uncalibrated
        "calibration_error": None,  # why the configured file is not applied
        "calibration_outside_span": 0,
        "raw_subscribed": False,
        # None: off; else {state, bias_rad_s, windows, still_windows} (imud.calib.track)
        "gyro_bias_tracking": (
            GyroBiasTracker(cfg.gyro_bias_tracking).status()
            if cfg.gyro_bias_tracking.enabled
            else None
        ),
        "last_error": None,
        "last_error_at": None,
        "chip_status": {},
    }
