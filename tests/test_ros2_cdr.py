"""imud's batch CDR encoder against rosbags' (a maintained ROS 2 CDR implementation): the same
bytes for every message type, every field and every frame_id length, and rosbags' decoder reads
back every value."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from imud.ros2.cdr import MESSAGE_TYPES, layout, messages, template

pytestmark = pytest.mark.extra  # rosbags (the `dev` extra)
rosbags = pytest.importorskip("rosbags.typesys")

STORE = rosbags.get_typestore(rosbags.Stores.ROS2_JAZZY)
T = STORE.types

# per type: each float64 field and its count, from the message definitions (sensor_msgs)
FIELDS: dict[str, dict[str, int]] = {
    "sensor_msgs/msg/Imu": {
        "orientation": 4,
        "orientation_covariance": 9,
        "angular_velocity": 3,
        "angular_velocity_covariance": 9,
        "linear_acceleration": 3,
        "linear_acceleration_covariance": 9,
    },
    "sensor_msgs/msg/MagneticField": {"magnetic_field": 3, "magnetic_field_covariance": 9},
    "sensor_msgs/msg/Temperature": {"temperature": 1, "variance": 1},
}


def _reference(type_name: str, sec: int, nanosec: int, frame_id: str, v: dict[str, Any]) -> Any:
    """The message built with rosbags' own classes."""
    header = T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id
    )
    vec = T["geometry_msgs/msg/Vector3"]
    kw: dict[str, Any] = {}
    for name, value in v.items():
        if name == "orientation":
            kw[name] = T["geometry_msgs/msg/Quaternion"](*map(float, value))
        elif FIELDS[type_name][name] == 3:
            kw[name] = vec(*map(float, value))
        elif FIELDS[type_name][name] == 1:
            kw[name] = float(value)
        else:
            kw[name] = np.asarray(value, dtype=np.float64)
    return T[type_name](header=header, **kw)


def _values(type_name: str, rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    out = {}
    for name, count in FIELDS[type_name].items():
        shape = (n, count) if count > 1 else (n,)
        out[name] = rng.normal(size=shape) * 10.0 ** rng.integers(-9, 4)
    return out


@pytest.mark.parametrize("type_name", MESSAGE_TYPES)
@pytest.mark.parametrize(
    "frame_id", ["", "a", "imu", "imu_link", "base_imu_lnk", "x" * 20, "ä" * 5]
)
def test_every_message_is_rosbags_bytes_and_reads_back(type_name: str, frame_id: str) -> None:
    rng = np.random.default_rng(len(frame_id))
    n = 5
    # stamps at the edges of sec/nanosec
    t_ns = np.array(
        [0, 999_999_999, 1_000_000_000, 1_764_000_000_123_456_789, 2**31 * 10**9 - 1],
        dtype=np.int64,
    )
    v = _values(type_name, rng, n)
    lay = layout(type_name, frame_id)
    # covariances as one (9,) array for the batch, as the output sends them
    given: dict[str, Any] = {k: (a[0] if k.endswith("covariance") else a) for k, a in v.items()}
    out = messages(lay, t_ns, given)
    assert out.dtype.itemsize == lay.size
    # the constant fields written once into a template, the rest per message: the same bytes
    fixed = {k: a for k, a in given.items() if k.endswith("covariance")}
    varying = {k: a for k, a in given.items() if k not in fixed}
    assert messages(lay, t_ns, varying, template(lay, fixed)).tobytes() == out.tobytes()
    for i in range(n):
        sec, nanosec = divmod(int(t_ns[i]), 10**9)
        per = {k: (a[0] if k.endswith("covariance") else a[i]) for k, a in v.items()}
        ref = bytes(
            STORE.serialize_cdr(_reference(type_name, sec, nanosec, frame_id, per), type_name)
        )
        assert out[i].tobytes() == ref, (i, out[i].tobytes().hex(), ref.hex())
        back = STORE.deserialize_cdr(out[i].tobytes(), type_name)
        assert (back.header.stamp.sec, back.header.stamp.nanosec) == (sec, nanosec)
        assert back.header.frame_id == frame_id
        for name, want in per.items():
            got = getattr(back, name)
            if name == "orientation":
                got = [got.x, got.y, got.z, got.w]
            elif FIELDS[type_name][name] == 3:
                got = [got.x, got.y, got.z]
            np.testing.assert_array_equal(np.asarray(got, dtype=np.float64), want, err_msg=name)


def test_a_frame_id_with_a_nul_is_refused() -> None:
    with pytest.raises(ValueError, match="NUL"):
        layout("sensor_msgs/msg/Imu", "imu\0link")
