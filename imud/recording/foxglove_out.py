"""`imud view`'s output: a Foxglove WebSocket server (foxglove-sdk, the `view` extra; it speaks
`foxglove.sdk.v1`) on 127.0.0.1, carrying the messages the recorder makes (the ROS 2 topics,
CDR with their ros2msg schemas, which Foxglove decodes and plots) and, on `/imud/status`, the
daemon's status as JSON once a second (each device's rate, lost samples, calibration state).

`layout()` writes a Foxglove layout for a set of devices: per device its accelerometer, its gyro,
its temperature, its rate and lost samples, each a Plot panel.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import numpy.typing as npt

from imud.recording.schemas import definition

STATUS_TOPIC = "/imud/status"
# enough of the status's shape for Foxglove's message paths (the rest passes through)
STATUS_SCHEMA = {
    "type": "object",
    "properties": {
        "devices": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "name": {"type": "string"},
                    "state": {"type": "string"},
                    "measured_rate_hz": {"type": "number"},
                    "samples": {"type": "integer"},
                    "lost_samples": {"type": "integer"},
                    "temperature_c": {"type": ["number", "null"]},
                    "calibration": {"type": ["string", "null"]},
                    "calibration_error": {"type": ["string", "null"]},
                },
            },
        }
    },
}


class FoxgloveOut:
    """The recorder's sink (`add`, `flush`, `close`) onto a Foxglove WebSocket server."""

    def __init__(self) -> None:
        """Channels only: `serve` starts the server once the channels a client should see at
        once exist. foxglove-sdk (0.30) can advertise a channel made while a client connects
        and then refuse that client's subscription to it ("Unknown channel ID")."""
        import foxglove

        self._fox = foxglove
        self.server: Any = None
        self.port = 0
        self._channels: dict[str, Any] = {}
        self._status = foxglove.Channel(
            STATUS_TOPIC,
            message_encoding="json",
            schema=foxglove.Schema(
                name="imud.Status", encoding="jsonschema", data=json.dumps(STATUS_SCHEMA).encode()
            ),
        )
        self.paths: list[Any] = []  # what a recorder's summary lists: nothing written
        self.messages = 0

    def add(self, topic: str, type_name: str, log_ns: int, payload: bytes) -> None:
        self._channel(topic, type_name).log(payload, log_time=log_ns)
        self.messages += 1

    def add_many(
        self, topic: str, type_name: str, log_ns: npt.NDArray[np.int64], data: bytes, size: int
    ) -> None:
        ch = self._channel(topic, type_name)
        for i, t in enumerate(log_ns.tolist()):
            ch.log(data[i * size : (i + 1) * size], log_time=t)
        self.messages += len(log_ns)

    def _channel(self, topic: str, type_name: str) -> Any:
        ch = self._channels.get(topic)
        if ch is None:
            schema = self._fox.Schema(
                name=type_name, encoding="ros2msg", data=definition(type_name).encode()
            )
            ch = self._channels[topic] = self._fox.Channel(
                topic, message_encoding="cdr", schema=schema
            )
        return ch

    def serve(self, port: int, name: str = "imud", host: str = "127.0.0.1") -> None:
        """Start the WebSocket server (raises if the port is taken)."""
        self.server = self._fox.start_server(name=name, host=host, port=port)
        self.port = self.server.port

    def subscribed(self) -> bool:
        """Whether a client has subscribed to any channel (a viewer is watching)."""
        return any(ch.has_sinks() for ch in (*self._channels.values(), self._status))

    def announce(self, topics: list[tuple[str, str]]) -> None:
        """Channels for (topic, message type) before their first message, so a client can
        subscribe to them before anything plays."""
        for topic, type_name in topics:
            self._channel(topic, type_name)

    def status(self, body: dict[str, Any], log_ns: int) -> None:
        self._status.log(json.dumps(body), log_time=log_ns)

    def flush(self) -> None:
        pass

    def bytes_written(self) -> int:
        return 0

    def close(self) -> None:
        if self.server is not None:
            self.server.stop()


def layout(devices: list[dict[str, Any]], namespace: str = "") -> dict[str, Any]:
    """A Foxglove layout: a row a device (accel, gyro, temperature, rate and lost samples), each
    a Plot panel of the device's ROS 2 topics and its entry in /imud/status. devices: each
    device's status JSON (name, channels)."""
    panels: dict[str, Any] = {}
    rows: list[Any] = []
    ns = namespace.strip("/")
    for d in devices:
        name = d["name"]
        raw = "/" + "/".join(p for p in (ns, name, "imu/data_raw") if p)
        status = f'{STATUS_TOPIC}.devices[:]{{name=="{name}"}}'
        plots = {
            f"Plot!{name}-accel": (f"{name} accel [m/s²]", [
                f"{raw}.linear_acceleration.{a}" for a in "xyz"]),
            f"Plot!{name}-gyro": (f"{name} gyro [rad/s]", [
                f"{raw}.angular_velocity.{a}" for a in "xyz"]),
            f"Plot!{name}-health": (f"{name} rate [Hz], lost samples", [
                f"{status}.measured_rate_hz", f"{status}.lost_samples"]),
        }  # fmt: skip
        if "temperature_c" in d.get("channels", []):
            plots[f"Plot!{name}-temp"] = (f"{name} temperature [°C]", [f"{status}.temperature_c"])
        for pid, (title, paths) in plots.items():
            panels[pid] = {
                "title": title,
                "paths": [
                    {"value": p, "enabled": True, "timestampMethod": "receiveTime"} for p in paths
                ],
                "showLegend": True,
                "followingViewWidth": 30,
            }
        rows.append(_split(list(plots), "row"))
    return {
        "configById": panels,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": _split(rows, "column") if rows else None,
    }


def _split(items: list[Any], direction: str) -> Any:
    """Foxglove's mosaic: a binary tree of splits, the items in equal shares."""
    if len(items) == 1:
        return items[0]
    half = len(items) // 2
    return {
        "direction": direction,
        "first": _split(items[:half], direction),
        "second": _split(items[half:], direction),
        "splitPercentage": 100 * half / len(items),
    }
