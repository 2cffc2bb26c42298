"""The message definitions imud writes into its MCAP files are rosbags' own text for each type
(what rosbag2 writes), and the native batch message round-trips."""

from __future__ import annotations

import pytest

from imud.recording.schemas import BATCH, batch_cdr, batch_wire, definition

TYPES = [
    "sensor_msgs/msg/Imu",
    "sensor_msgs/msg/MagneticField",
    "sensor_msgs/msg/Temperature",
    "diagnostic_msgs/msg/DiagnosticArray",
]


@pytest.mark.extra
@pytest.mark.parametrize("type_name", TYPES)
def test_each_definition_is_rosbags_own(type_name: str) -> None:
    from rosbags.typesys import Stores, get_typestore

    text, _ = get_typestore(Stores.ROS2_JAZZY).generate_msgdef(type_name, ros_version=2)
    assert definition(type_name) == text


@pytest.mark.extra
def test_rosbags_decodes_a_batch_by_its_definition() -> None:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(definition(BATCH), BATCH))
    wire = bytes(range(256)) * 3 + b"\x01\x02\x03"
    msg = store.deserialize_cdr(batch_cdr(wire), BATCH)
    assert bytes(msg.wire) == wire


def test_the_batch_message_round_trips_and_refuses_what_it_is_not() -> None:
    for wire in (b"", b"IMUD" + bytes(60), bytes(range(7))):
        assert batch_wire(batch_cdr(wire)) == wire
    with pytest.raises(ValueError, match="not a little-endian CDR"):
        batch_wire(b"\x00\x00\x00\x00\x01\x00\x00\x00x")
    with pytest.raises(ValueError, match="of 9 bytes in 1"):
        batch_wire(b"\x00\x01\x00\x00\x09\x00\x00\x00x")
    with pytest.raises(KeyError, match="no message definition"):
        definition("std_msgs/msg/String")
