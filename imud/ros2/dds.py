"""The `dds` profile: sensor_msgs straight to DDS-based ROS 2 nodes (rmw_fastrtps, rmw_cyclonedds,
rmw_connextdds), through Cyclone DDS (`pip install 'imud[dds]'`, x86_64 wheels only).

What a ROS 2 node on DDS matches (docs/ros2.md "DDS"): topic `rt/<topic>`; type
`sensor_msgs::msg::dds_::Imu_` (and its members' `…::msg::dds_::…_` types), all final; XCDR1
data representation; a RELIABLE writer (a BEST_EFFORT writer does not match a RELIABLE reader,
a RELIABLE one serves both); `typehash=RIHS01_…;` in the writer's USER_DATA (Iron and later).

The messages are the CDR imud makes for every profile (byte-identical to rosbags); the writer
takes them as they are, without a per-message Python object (cyclonedds' own serializer costs
~24 µs a message). The Cyclone configuration is the library's: `CYCLONEDDS_URI`, as for a ROS 2
node (in the systemd unit: `Environment=CYCLONEDDS_URI=…`).
"""

from __future__ import annotations

import importlib.util
import os
from typing import Any

from imud.ros2 import rmw_zenoh as rz

MISSING = (
    "the dds profile needs Cyclone DDS: pip install 'imud[dds]' (x86_64 wheels; elsewhere build "
    'cyclonedds from source), or drop "dds" from [ros2] profiles'
)


def available() -> bool:
    return importlib.util.find_spec("cyclonedds") is not None


class DdsError(RuntimeError):
    pass


def _types() -> dict[str, Any]:
    """The ROS 2 message types as DDS IDL types, by ROS name."""
    from imud.ros2 import dds_types as t

    return {
        "sensor_msgs/msg/Imu": t.Imu,
        "sensor_msgs/msg/MagneticField": t.MagneticField,
        "sensor_msgs/msg/Temperature": t.Temperature,
        "diagnostic_msgs/msg/DiagnosticArray": t.DiagnosticArray,
    }


class DdsOutput:
    """One domain participant; a writer per topic. Raises `DdsError` when Cyclone DDS is not
    installed or will not start."""

    def __init__(self, domain: int, reliable: bool, depth: int, type_hashes: bool) -> None:
        if not available():
            raise DdsError(MISSING)
        from cyclonedds.core import Policy
        from cyclonedds.domain import DomainParticipant

        self._types = _types()
        try:
            self.participant: Any = DomainParticipant(domain)
        except Exception as e:  # cyclonedds' DDSException: a bad config, no interface
            uri = os.environ.get("CYCLONEDDS_URI")
            fix = f"; check CYCLONEDDS_URI={uri!r}" if uri else ""
            raise DdsError(f"Cyclone DDS did not start on domain {domain}: {e}{fix}") from None
        self._policies = [
            Policy.Reliability.Reliable(max_blocking_time=0)
            if reliable
            else Policy.Reliability.BestEffort,
            Policy.History.KeepLast(depth),
            Policy.Durability.Volatile,
            Policy.DataRepresentation(use_cdrv0_representation=True),
        ]
        self._type_hashes = type_hashes

    def writer(self, topic: str, type_name: str) -> Any:
        """A writer of `type_name` on ROS topic `topic` (`rt/` + its name without the outer
        '/'), taking CDR bytes (`write_cdr`)."""
        from cyclonedds.core import Policy, Qos
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic

        t = self._types[type_name]
        policies = list(self._policies)
        if self._type_hashes:  # what Iron and later rmw implementations put there
            policies.append(Policy.Userdata(f"typehash={rz.TYPE_HASHES[type_name]};".encode()))
        qos = Qos(*policies)
        dds_topic = Topic(self.participant, "rt/" + topic.lstrip("/"), t, qos=qos)
        return _Writer(DataWriter(self.participant, dds_topic, qos=qos))

    def close(self) -> None:
        # Cyclone frees entities with their participant; dropping the references is enough,
        # but deleting explicitly makes the readers see the writers leave now
        self.participant = None


class _Writer:
    """A DataWriter fed the CDR imud made: `write_cdr(payload)`."""

    def __init__(self, writer: Any) -> None:
        from cyclonedds._clayer import ddspy_write

        self._w = writer
        self._write = ddspy_write

    def write_cdr(self, payload: bytes) -> None:
        # the writer's own write() serialises an IDL object and hands the bytes to this call;
        # imud's bytes are already that serialisation (tests compare them with rosbags')
        pad = -len(payload) % 4  # as DataWriter.write pads a serialisation
        ret = self._write(self._w._ref, payload + bytes(pad) if pad else payload)
        if ret < 0:
            raise DdsError(f"DDS write failed ({ret})")
