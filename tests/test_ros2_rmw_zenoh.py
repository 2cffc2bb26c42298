"""What imud puts before rmw_zenoh, checked against rules and vectors written down from
rmw_zenoh's sources (liveliness_utils.cpp, attachment_helpers.cpp, qos.cpp, its design document)
and against Zenoh's own serialiser, never against imud's code: the parsers here are the test's
own."""

from __future__ import annotations

import struct

import pytest
import zenoh.ext as zext

from imud.ros2 import rmw_zenoh as rz
from imud.rosnames import join, name_problem, node_problem

# rmw_zenoh's design document, a talker's publisher token; its GID as rmw_zenoh computes it
# (XXH3-128, low then high 64 bits little-endian), computed with xxhash by hand once
DESIGN_TALKER = (
    "@ros2_lv/0/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
    "std_msgs::msg::dds_::String_/"
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
)
DESIGN_TALKER_GID = "eb85fa883b7846dc448a4501890ad062"
KINDS = {"NN", "MP", "MS", "SS", "SC"}


def parse_token(token: str) -> dict[str, str]:
    """rmw_zenoh's liveliness parser's rules: at least 9 parts, none empty, a known kind, an
    entity 13 parts with a QoS of six ':'-separated fields."""
    parts = token.split("/")
    assert parts[0] == "@ros2_lv" and len(parts) >= 9, token
    assert all(parts), f"an empty part in {token!r}"
    keys = ["admin", "domain", "zid", "nid", "id", "kind", "enclave", "namespace", "node"]
    out = dict(zip(keys, parts[:9], strict=True))
    assert out["kind"] in KINDS
    if out["kind"] != "NN":
        assert len(parts) == 13, token
        out |= dict(zip(["topic", "type", "hash", "qos"], parts[9:], strict=True))
        # rel:dur:hist,depth:deadline s,ns:lifespan s,ns:liveliness,lease s,ns
        fields = out["qos"].split(":")
        assert [f.count(",") for f in fields] == [0, 0, 1, 1, 1, 2], out["qos"]
    return out


def test_the_gid_of_design_mds_talker_is_rmw_zenohs() -> None:
    assert rz.gid(DESIGN_TALKER).hex() == DESIGN_TALKER_GID


def test_a_token_built_as_design_md_shows_it_is_the_same_string() -> None:
    qos = rz.Qos(reliable=True, depth=7)
    got = rz.publisher_token(
        0,
        "8b20917502ee955ac4476e0266340d5c",
        0,
        10,
        "/",
        "talker",
        "/chatter",
        "std_msgs/msg/String",
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
        qos,
    )
    assert got == DESIGN_TALKER


def test_the_attachment_is_zenohs_serialisation_33_bytes() -> None:
    gid = rz.gid(DESIGN_TALKER)
    for seq, t in [(1, 0), (2, 1_764_000_000_123_456_789), (2**40, 2**62)]:
        a = rz.attachment(seq, t, gid)
        # zenoh-cpp serialises rmw_zenoh's (int64, int64, std::array<uint8_t, 16>) like this
        ref = zext.z_serialize((zext.Int64(seq), zext.Int64(t), gid)).to_bytes()
        assert a == ref and len(a) == 33
        s, ts, n = struct.unpack_from("<qqB", a)
        assert (s, ts, n, a[17:]) == (seq, t, 16, gid)


def test_the_key_value_attachment_of_older_rmw_zenoh_is_77_bytes() -> None:
    gid = bytes(range(16))
    a = rz.attachment(3, 42, gid, rz.Attachment.KEY_VALUE)
    ref = zext.z_serialize(
        ("sequence_number", zext.Int64(3), "source_timestamp", zext.Int64(42), "source_gid", gid)
    ).to_bytes()
    assert a == ref and len(a) == 77
    assert a[:16] == b"\x0fsequence_number"


@pytest.mark.parametrize(
    ("topic", "key"),
    [
        ("/imu/data", "0/imu/data/sensor_msgs::msg::dds_::Imu_/RIHS01_7d9a"),
        ("/robot1/imu0/imu/data_raw", "0/robot1/imu0/imu/data_raw/sensor_msgs::msg::dds_::Imu_/"),
    ],
)
def test_the_data_key_is_the_topic_without_its_slash_and_no_mangling(topic: str, key: str) -> None:
    got = rz.data_key(0, topic, "sensor_msgs/msg/Imu", rz.TYPE_HASHES["sensor_msgs/msg/Imu"])
    assert got.startswith(key)
    assert "%" not in got
    assert got.split("/")[-1] == rz.TYPE_HASHES["sensor_msgs/msg/Imu"]
    humble = rz.data_key(7, topic, "sensor_msgs/msg/MagneticField", rz.NO_TYPE_HASH)
    assert humble.startswith("7/") and humble.endswith(
        "/sensor_msgs::msg::dds_::MagneticField_/TypeHashNotSupported"
    )


def test_tokens_parse_under_rmw_zenohs_rules() -> None:
    zid = "0123456789abcdef0123456789abcdef"
    node = parse_token(rz.node_token(3, zid, 0, "/robot1", "imud"))
    assert (node["domain"], node["nid"], node["id"], node["namespace"]) == (
        "3",
        "0",
        "0",
        "%robot1",
    )
    assert node["enclave"] == "%" and node["node"] == "imud"
    root = parse_token(rz.node_token(0, zid, 0, "/", "imud"))
    assert root["namespace"] == "%"
    pub = parse_token(
        rz.publisher_token(
            3, zid, 0, 4, "/robot1", "imud", "/robot1/imu0/imu/data", "sensor_msgs/msg/Imu",
            rz.TYPE_HASHES["sensor_msgs/msg/Imu"], rz.Qos(reliable=False, depth=5),
        )
    )  # fmt: skip
    assert pub["topic"] == "%robot1%imu0%imu%data"
    assert pub["type"] == "sensor_msgs::msg::dds_::Imu_"
    assert pub["qos"] == "2::,5:,:,:,,"  # SensorDataQoS, as the reference note gives it


@pytest.mark.parametrize(
    ("reliable", "depth", "want"),
    [(True, 10, "::,10:,:,:,,"), (False, 5, "2::,5:,:,:,,"), (True, 42, "::,:,:,:,,")],
)
def test_the_qos_string_leaves_rmw_zenohs_defaults_empty(
    reliable: bool, depth: int, want: str
) -> None:
    assert rz.Qos(reliable, depth).keyexpr() == want


@pytest.mark.extra  # rosbags
def test_the_type_hashes_are_rosidls() -> None:
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    for name, h in rz.TYPE_HASHES.items():
        assert store.hash_rihs01(name) == h


@pytest.mark.parametrize(
    ("name", "problem"),
    [
        ("/imu/data", None),
        ("imu/data", "absolute"),
        ("/imu/", "end with"),
        ("/imu//data", "empty part"),
        ("/imu/9data", "starts with a digit"),
        ("/imu/da-ta", "'-'"),
        ("/imu/dätä", "'ä'"),
    ],
)
def test_topic_names_follow_ros2s_rules(name: str, problem: str | None) -> None:
    got = name_problem(name)
    assert (got is None) if problem is None else (got is not None and problem in got), got


def test_node_names_and_joining() -> None:
    assert node_problem("imud") is None and node_problem("imu-d") is not None
    assert node_problem("1imud") is not None
    assert join("/", "imu0", "imu/data_raw") == "/imu0/imu/data_raw"
    assert join("/robot1/", "imu0", "/imu/mag") == "/robot1/imu0/imu/mag"
    assert name_problem("/", "namespace") is None
