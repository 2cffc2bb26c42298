"""The message definitions an MCAP file carries beside its channels (schema encoding `ros2msg`):
each type's .msg text, then every type it uses once, each after a line of 80 '=' and
`MSG: pkg/Type`, as rosbag2 writes them, so Foxglove, rosbags and `ros2 bag` decode the messages
without the ROS packages installed.

imud's own native batches go in as `imud_msgs/msg/Batch`: the wire bytes the daemon published
(docs/wire-format.md), untouched, so replay sends exactly what was received.
"""

from __future__ import annotations

import re

# each type's own fields (constants first, as the .msg files list them); types by full name
# without the "msg/" part, as .msg files refer to them
_FIELDS: dict[str, str] = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "sensor_msgs/Imu": (
        "std_msgs/Header header\n"
        "geometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\n"
        "geometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\n"
        "geometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance\n"
    ),
    "sensor_msgs/MagneticField": (
        "std_msgs/Header header\ngeometry_msgs/Vector3 magnetic_field\n"
        "float64[9] magnetic_field_covariance\n"
    ),
    "sensor_msgs/Temperature": "std_msgs/Header header\nfloat64 temperature\nfloat64 variance\n",
    "diagnostic_msgs/KeyValue": "string key\nstring value\n",
    "diagnostic_msgs/DiagnosticStatus": (
        "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\n"
        "string message\nstring hardware_id\ndiagnostic_msgs/KeyValue[] values\n"
    ),
    "diagnostic_msgs/DiagnosticArray": (
        "std_msgs/Header header\ndiagnostic_msgs/DiagnosticStatus[] status\n"
    ),
    "imud_msgs/Batch": "uint8[] wire\n",
}
BATCH = "imud_msgs/msg/Batch"
_SEPARATOR = "=" * 80 + "\n"
_TYPE = re.compile(r"^([A-Za-z_]\w*/\w+)(\[\d*\])? ", re.MULTILINE)


def _short(type_name: str) -> str:
    """sensor_msgs/msg/Imu -> sensor_msgs/Imu (how .msg files name types)."""
    pkg, _, name = type_name.rpartition("/")
    return f"{pkg.split('/')[0]}/{name}"


def _uses(short: str) -> list[str]:
    """The types `short` uses, each once, in the order of first use, depth first."""
    out: list[str] = []
    for m in _TYPE.finditer(_FIELDS[short]):
        dep = m.group(1)
        for t in (dep, *_uses(dep)):
            if t not in out:
                out.append(t)
    return out


def definition(type_name: str) -> str:
    """The ros2msg schema text of `type_name` (e.g. "sensor_msgs/msg/Imu")."""
    short = _short(type_name)
    if short not in _FIELDS:
        raise KeyError(f"no message definition for {type_name}")
    parts = [_FIELDS[short]]
    parts += [f"{_SEPARATOR}MSG: {dep}\n{_FIELDS[dep]}" for dep in _uses(short)]
    return "".join(parts)


def batch_cdr(wire: bytes | memoryview) -> bytes:
    """An imud_msgs/msg/Batch in CDR (little-endian): the 4-byte header, the length, the bytes."""
    return b"\x00\x01\x00\x00" + len(wire).to_bytes(4, "little") + bytes(wire)


def batch_wire(cdr: bytes | memoryview) -> bytes:
    """The wire bytes of a CDR imud_msgs/msg/Batch; ValueError for anything else."""
    b = bytes(cdr)
    if len(b) < 8 or b[:2] != b"\x00\x01":
        raise ValueError("not a little-endian CDR imud_msgs/msg/Batch")
    n = int.from_bytes(b[4:8], "little")
    if 8 + n > len(b):
        raise ValueError(f"an imud_msgs/msg/Batch of {n} bytes in {len(b) - 8}")
    return b[8 : 8 + n]
