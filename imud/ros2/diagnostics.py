"""How a ROS 2 user sees imud's health: diagnostic_msgs/msg/DiagnosticArray on `/diagnostics`, once
a second, one DiagnosticStatus per device (the ROS convention: diagnostic_aggregator,
rqt_robot_monitor and Foxglove's diagnostics panels read it).

ROS messages have no sequence number, so a lost sample is invisible in `imu/data_raw`; here
each device's status says how many were lost since the last report and in all (the native
stream's counters, the source of truth), and its level turns WARN for a second in which samples
were lost, ERROR while the device is failing, STALE while it is not running.

The CDR is written here (strings and sequences: XCDR1, little-endian, the 4-byte encapsulation
header), byte-identical to rosbags' (tests/test_ros2_diagnostics.py); rosbags itself would add
four packages the daemon does not otherwise need (apsw, lz4, zstd, ruamel.yaml) and ~150 ms at
start (measured in docs/ros2.md "Diagnostics"), for one small message a second.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from imud.ros2.cdr import ENCAPSULATION
from imud.status import DeviceState

TYPE_NAME = "diagnostic_msgs/msg/DiagnosticArray"
TOPIC = "/diagnostics"  # absolute, as diagnostic_updater publishes it (never namespaced)


class Level(IntEnum):
    """diagnostic_msgs/msg/DiagnosticStatus's levels."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass(frozen=True)
class Status:
    level: Level
    name: str
    message: str
    hardware_id: str
    values: list[tuple[str, str]] = field(default_factory=list)


class _Writer:
    """CDR's alignment: a primitive of size n starts at a multiple of n, counted from the end
    of the encapsulation header."""

    def __init__(self) -> None:
        self.buf = bytearray()

    def _align(self, n: int) -> None:
        self.buf += bytes(-len(self.buf) % n)

    def u8(self, v: int) -> None:
        self.buf.append(v)

    def i32(self, v: int) -> None:
        self._align(4)
        self.buf += struct.pack("<i", v)

    def u32(self, v: int) -> None:
        self._align(4)
        self.buf += struct.pack("<I", v)

    def string(self, s: str) -> None:
        b = s.encode()
        if b"\0" in b:
            b = b.replace(b"\0", b"?")  # CDR strings end at their NUL
        self.u32(len(b) + 1)
        self.buf += b + b"\0"


def encode(t_ns: int, statuses: list[Status], frame_id: str = "") -> bytes:
    """One DiagnosticArray, stamped `t_ns` (ns since the epoch), as ROS 2 serialises it."""
    w = _Writer()
    w.i32(t_ns // 1_000_000_000)
    w.u32(t_ns % 1_000_000_000)
    w.string(frame_id)
    w.u32(len(statuses))
    for s in statuses:
        w.u8(int(s.level))
        w.string(s.name)
        w.string(s.message)
        w.string(s.hardware_id)
        w.u32(len(s.values))
        for k, v in s.values:
            w.string(k)
            w.string(v)
    return ENCAPSULATION + bytes(w.buf)


# the native counters each status carries, and the name it carries them under
_COUNTERS = (
    ("samples", "samples"),
    ("lost_samples", "lost samples"),
    ("invalid_samples", "invalid samples"),
    ("fifo_overflows", "FIFO overflows"),
    ("bus_errors", "bus errors"),
    ("restarts", "restarts"),
    ("resets", "chip resets"),
)


def device_status(dev: dict[str, Any], lost_before: int | None, period_s: float) -> Status:
    """The DiagnosticStatus of one device from its `imud status` JSON; `lost_before` is its
    lost-sample count at the previous report (None: the first report)."""
    try:
        state = DeviceState(dev.get("state", DeviceState.STARTING))
    except ValueError:  # a state this version does not know
        state = DeviceState.STARTING
    lost = int(dev.get("lost_samples", 0))
    new_lost = 0 if lost_before is None else max(0, lost - lost_before)
    rate = float(dev.get("measured_rate_hz", 0.0))
    if state is DeviceState.ERROR:
        level, message = Level.ERROR, str(dev.get("last_error") or "failing; retrying")
    elif state is not DeviceState.RUNNING:
        level, message = Level.STALE, state.value
    elif new_lost:
        level = Level.WARN
        message = f"{new_lost} samples lost in the last {period_s:g} s"
    elif dev.get("calibration_error"):
        level, message = Level.WARN, str(dev["calibration_error"])
    else:
        level, message = Level.OK, f"running at {rate:.1f} Hz"
    values = [
        ("state", state.value),
        ("rate_hz", f"{rate:.3f}"),
        ("configured_rate_hz", f"{float(dev.get('odr_hz', 0.0)):g}"),
        ("lost_since_last_report", str(new_lost)),
    ]
    values += [(label, str(int(dev.get(key, 0)))) for key, label in _COUNTERS]
    temp = dev.get("temperature_c")
    if temp is not None:
        values.append(("temperature_c", f"{float(temp):.2f}"))
    values.append(("calibration", str(dev.get("calibration") or "none")))
    return Status(
        level,
        f"imud: {dev.get('name', '?')}",
        message,
        f"{dev.get('chip', '?')} on {dev.get('bus', '?')}",
        values,
    )
