"""What rmw_zenoh (the ROS 2 RMW on Zenoh) expects of a publisher, so that ROS 2 nodes on it
receive imud's messages and `ros2 topic list` / `ros2 node list` see imud.

Facts from rmw_zenoh's sources (liveliness_utils.cpp, attachment_helpers.cpp, qos.cpp and its
design document; docs/ros2.md says which versions):

- Data key: `<domain>/<topic without its leading '/'>/<pkg>::msg::dds_::<Type>_/<type hash>`;
  the type hash is RIHS01 (Iron and later) or the constant `TypeHashNotSupported` (Humble).
- Every sample carries an attachment: int64 sequence number (from 1, +1 a put, per publisher),
  int64 source time (ns since the epoch, at publishing), then the publisher's 16-byte GID as a
  Zenoh-serialised sequence (LEB128 length 16, the bytes): 33 bytes. rmw_zenoh before Jazzy
  0.2.4 / Humble 0.1.2 / Rolling 0.6.0 wants the older key/value form (77 bytes). Either side
  throws on the other's; a subscriber that throws inside its Zenoh callback takes the whole
  process down, so the format is a setting, not a guess.
- Liveliness tokens announce the node (`NN`) and each publisher (`MP`):
  `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>` and, for a
  publisher, `/<topic>/<type>/<hash>/<qos>`, each name with '/' turned into '%'.
- The GID is XXH3-128 of the publisher's token, its low 64 bits then its high 64 bits, each
  little-endian.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import StrEnum

import xxhash

# RIHS01 type hashes (rosidl's type description hash; the same for Iron, Jazzy, Kilted, Rolling).
# tests/test_ros2_rmw_zenoh.py recomputes them with rosbags.
TYPE_HASHES = {
    "sensor_msgs/msg/Imu": (
        "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b"
    ),
    "sensor_msgs/msg/MagneticField": (
        "RIHS01_e80f32f56a20486c9923008fc1a1db07bbb273cbbf6a5b3bfa00835ee00e4dff"
    ),
    "sensor_msgs/msg/Temperature": (
        "RIHS01_72514a14126ab9f8a9abec974c78e5610a367b59db5da355ff1fb982d5bad4b8"
    ),
    "diagnostic_msgs/msg/DiagnosticArray": (
        "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e"
    ),
}
NO_TYPE_HASH = "TypeHashNotSupported"  # Humble's rmw_zenoh, which has no type hashes
GID_SIZE = 16
_CURRENT = struct.Struct("<qqB")
_KEY_VALUE = (
    (b"sequence_number", struct.Struct("<q")),
    (b"source_timestamp", struct.Struct("<q")),
)


class Attachment(StrEnum):
    """The attachment layout the subscribers' rmw_zenoh reads."""

    CURRENT = "current"  # Jazzy >= 0.2.4, Kilted, Rolling >= 0.6.0, Humble >= 0.1.2: 33 bytes
    KEY_VALUE = "key-value"  # Jazzy 0.2.0-0.2.3, Humble 0.1.0-0.1.1, older Rolling: 77 bytes


def dds_type(type_name: str) -> str:
    """'sensor_msgs/msg/Imu' -> 'sensor_msgs::msg::dds_::Imu_' (rmw's DDS-style type name)."""
    pkg, kind, name = type_name.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def data_key(domain: int, topic: str, type_name: str, type_hash: str) -> str:
    """The key a publisher of `topic` (fully qualified) puts on."""
    stripped = topic[1:] if topic.startswith("/") else topic
    stripped = stripped[:-1] if stripped.endswith("/") else stripped
    return f"{domain}/{stripped}/{dds_type(type_name)}/{type_hash}"


def mangle(name: str) -> str:
    """A name as a liveliness token carries it: every '/' as '%' (the root, '/', is '%')."""
    return name.replace("/", "%") if name else "%"


@dataclass(frozen=True)
class Qos:
    """What imud's publishers offer: volatile, keep-last, no deadline, lifespan or lease."""

    reliable: bool = True
    depth: int = 5

    def keyexpr(self) -> str:
        """rmw_zenoh's QoS string: `rel:dur:hist,depth:dl:ls:liv,lease`, each part empty when
        it is rmw_zenoh's default (reliable, volatile, keep-last, depth 42, infinite, automatic)."""
        rel = "" if self.reliable else "2"  # RMW_QOS_POLICY_RELIABILITY_BEST_EFFORT
        depth = "" if self.depth == 42 else str(self.depth)
        return f"{rel}::,{depth}:,:,:,,"


def node_token(domain: int, zid: str, node_id: int, namespace: str, node: str) -> str:
    return f"@ros2_lv/{domain}/{zid}/{node_id}/{node_id}/NN/%/{mangle(namespace)}/{node}"


def publisher_token(
    domain: int,
    zid: str,
    node_id: int,
    entity_id: int,
    namespace: str,
    node: str,
    topic: str,
    type_name: str,
    type_hash: str,
    qos: Qos,
) -> str:
    return (
        f"@ros2_lv/{domain}/{zid}/{node_id}/{entity_id}/MP/%/{mangle(namespace)}/{node}/"
        f"{mangle(topic)}/{dds_type(type_name)}/{type_hash}/{qos.keyexpr()}"
    )


def gid(token: str) -> bytes:
    """The publisher's GID as rmw_zenoh derives it from its liveliness token."""
    h = xxhash.xxh3_128_intdigest(token.encode())
    return struct.pack("<QQ", h & 0xFFFF_FFFF_FFFF_FFFF, h >> 64)


def attachment(seq: int, t_ns: int, gid16: bytes, form: Attachment = Attachment.CURRENT) -> bytes:
    """The attachment of a publisher's `seq`-th put (from 1), published at `t_ns`."""
    if form is Attachment.CURRENT:
        return _CURRENT.pack(seq, t_ns, GID_SIZE) + gid16
    out = bytearray()
    for (key, fmt), value in zip(_KEY_VALUE, (seq, t_ns), strict=True):
        out += bytes([len(key)]) + key + fmt.pack(value)
    out += bytes([len(b"source_gid")]) + b"source_gid" + bytes([GID_SIZE]) + gid16
    return bytes(out)
