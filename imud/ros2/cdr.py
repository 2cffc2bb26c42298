"""sensor_msgs/msg/Imu, MagneticField and Temperature as ROS 2 serialises them (CDR, XCDR1,
little-endian, with its 4-byte encapsulation header), a batch of messages at a time.

Why not rosbags' `serialize_cdr` (the tests compare against it byte for byte): a device's frame_id
is fixed, so every message of a stream has the same layout, and a whole batch is one NumPy
structured array filled column by column. Measured in `bench/ros2_cdr.py`: docs/performance.md.

Layout (offsets from the end of the encapsulation header, as CDR aligns them): header.stamp
(int32 sec, uint32 nanosec) at 0, frame_id (uint32 length with its NUL, the bytes, NUL) at 8, then
the float64 fields from the next multiple of 8.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR_LE, options 0
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

# the float64 fields after the header, per message type: (name, count)
_BODIES: dict[str, tuple[tuple[str, int], ...]] = {
    "sensor_msgs/msg/Imu": (
        ("orientation", 4),  # x, y, z, w
        ("orientation_covariance", 9),
        ("angular_velocity", 3),
        ("angular_velocity_covariance", 9),
        ("linear_acceleration", 3),
        ("linear_acceleration_covariance", 9),
    ),
    "sensor_msgs/msg/MagneticField": (
        ("magnetic_field", 3),
        ("magnetic_field_covariance", 9),
    ),
    "sensor_msgs/msg/Temperature": (
        ("temperature", 1),
        ("variance", 1),
    ),
}
MESSAGE_TYPES = tuple(_BODIES)


@dataclass(frozen=True)
class Layout:
    """One message type with one frame_id: its size and where each field sits."""

    type_name: str
    frame_id: str
    dtype: np.dtype[np.void]

    @property
    def size(self) -> int:
        return int(self.dtype.itemsize)


def layout(type_name: str, frame_id: str) -> Layout:
    """The byte layout of `type_name` with `frame_id`. Raises `ValueError` for a frame_id CDR
    cannot carry (a NUL inside it)."""
    if type_name not in _BODIES:
        raise ValueError(f"no CDR layout for {type_name!r}; known: {', '.join(_BODIES)}")
    name = frame_id.encode()
    if b"\0" in name:
        raise ValueError("frame_id must not contain a NUL character")
    body = 12 + len(name) + 1  # stamp, length, bytes, NUL
    start = 4 + -(-body // 8) * 8  # the float64s: aligned to 8 from the encapsulation's end
    names = ["encapsulation", "sec", "nanosec", "frame_len", "frame_id"]
    formats: list[object] = ["V4", "<i4", "<u4", "<u4", f"V{len(name) + 1}"]
    offsets = [0, 4, 8, 12, 16]
    at = start
    for field, count in _BODIES[type_name]:
        names.append(field)
        formats.append(("<f8", (count,)) if count > 1 else "<f8")
        offsets.append(at)
        at += 8 * count
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": at})
    return Layout(type_name, frame_id, dtype)


def template(lay: Layout, fixed: dict[str, F64 | float] | None = None) -> npt.NDArray[np.void]:
    """One message of `lay`, stamp 0, its `fixed` fields set and every other float zero: what
    `messages` copies, so a stream's constant fields (covariances) are written once."""
    out = np.zeros(1, dtype=lay.dtype)  # zero: CDR's padding bytes are zero too
    out["encapsulation"] = np.frombuffer(ENCAPSULATION, dtype="V4")[0]
    name = lay.frame_id.encode() + b"\0"
    out["frame_len"] = len(name)
    out["frame_id"] = np.frombuffer(name, dtype=f"V{len(name)}")[0]
    for field, value in (fixed or {}).items():
        out[field] = value
    return out


def messages(
    lay: Layout,
    t_ns: I64,
    fields: dict[str, F64 | float],
    base: npt.NDArray[np.void] | None = None,
) -> npt.NDArray[np.void]:
    """`len(t_ns)` messages of `lay`: one record each, its bytes the message's CDR. `fields`
    gives float64 fields of the type, an (N, count) array or one value for all (a covariance is
    a (9,) array, broadcast); those it leaves out are `base`'s (a `template`), else zero."""
    t = np.asarray(t_ns, dtype=np.int64)
    out = np.repeat(template(lay) if base is None else base, t.shape[0])
    out["sec"] = t // 1_000_000_000
    out["nanosec"] = t % 1_000_000_000
    for field, value in fields.items():
        out[field] = value
    return out
