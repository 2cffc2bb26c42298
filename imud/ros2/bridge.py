"""What zenoh-bridge-ros2dds (eclipse-zenoh/zenoh-plugin-ros2dds, 1.x) expects of a Zenoh
publisher it should route to the DDS nodes on its host.

Facts from the bridge's sources (ros2_utils.rs, route_subscriber.rs, liveliness_mgt.rs, lib.rs;
docs/ros2.md "The Zenoh bridge"):

- Data key: the ROS topic without its leading '/' (the bridge's own `namespace` setting, if
  any, is added on its side). The payload is the CDR with its 4-byte encapsulation header, handed
  to `dds_writecdr` as it is; attachment and encoding are ignored.
- The bridge creates its DDS writer when a DDS node on its host subscribes to the topic, or,
  without any subscriber yet, when another Zenoh participant announces a publisher with a
  liveliness token `@/<zid>/@ros2_lv/MP/<key>/<ROS type>/<qos>` (key and type with every '/' as
  '§'). With the token the topic shows in `ros2 topic list` on the DDS side at once, and
  `ros2 topic echo` needs no type argument.
- `<qos>` = `[K]:<reliability>:<durability>:<history>,<depth>[:<user data>]`: 'K' only for a
  keyed topic (ROS topics are keyless), the numbers Cyclone DDS's enum values (BEST_EFFORT 0,
  RELIABLE 1; VOLATILE 0; KEEP_LAST 0), an empty part for DDS's default; the user data is the
  writer's USER_DATA, `typehash=RIHS01_…;` for Iron and later readers.
"""

from __future__ import annotations

SLASH = "§"  # what the bridge's tokens carry for a '/' of a key or a type


def data_key(topic: str) -> str:
    """The key the bridge routes ROS topic `topic` (fully qualified) from."""
    return topic.strip("/")


def qos_keyexpr(reliable: bool, depth: int, type_hash: str | None) -> str:
    rel = "1" if reliable else "0"  # DDS_RELIABILITY_RELIABLE / _BEST_EFFORT
    qos = f":{rel}:0:0,{depth}"  # keyless, volatile, keep-last `depth`
    return qos if type_hash is None else f"{qos}:typehash={type_hash};"


def publisher_token(
    zid: str, topic: str, type_name: str, reliable: bool, depth: int, type_hash: str | None
) -> str:
    """The liveliness token that announces a publisher of `type_name` ('sensor_msgs/msg/Imu')
    on `topic` to every bridge; `type_hash` None for Humble (no USER_DATA)."""
    key = data_key(topic).replace("/", SLASH)
    typ = type_name.replace("/", SLASH)
    return f"@/{zid}/@ros2_lv/MP/{key}/{typ}/{qos_keyexpr(reliable, depth, type_hash)}"
