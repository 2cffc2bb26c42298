"""`[ros2]` in the config: what a bad value gets told, and configs/sim-ros2.toml."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import pytest

from imud.config import load_config, parse_config
from imud.errors import ConfigError
from imud.ros2.output import DomainError, domain_id

REPO = Path(__file__).resolve().parent.parent
DEVICE = {"name": "imu0", "chip": "mpu6050", "bus": {"kind": "sim"}, "odr_hz": 1000}


def _problem(raw: dict[str, Any]) -> str:
    with pytest.raises(ConfigError) as e:
        parse_config(raw)
    return str(e.value)


@pytest.mark.parametrize(
    ("ros2", "device", "says"),
    [
        ({"profiles": ["ros1"]}, {}, "ros2.profiles.0 = 'ros1'"),
        ({"profiles": []}, {}, "ros2.profiles"),
        ({"domain_id": 233}, {}, "ros2.domain_id = 233"),
        ({"namespace": "robot1"}, {}, "must be absolute"),
        ({"namespace": "/robot-1"}, {}, "'-'"),
        ({"node": "imu d"}, {}, "ros2.node"),
        ({"connect": ["127.0.0.1:7447"]}, {}, "PROTOCOL/HOST:PORT"),
        ({}, {"ros2": {"rate_hz": 2000}}, "ros2.rate_hz = 2000 is above its odr_hz (1000)"),
        ({}, {"ros2": {"namespace": "2nd"}}, "starts with a digit"),
        ({"attachment": "v1"}, {}, "ros2.attachment"),
    ],
)
def test_a_bad_ros2_value_is_named_with_its_fix(
    ros2: dict[str, Any], device: dict[str, Any], says: str
) -> None:
    text = _problem({"ros2": {"enabled": True, **ros2}, "device": [{**DEVICE, **device}]})
    assert says in text, text


def test_two_devices_cannot_share_a_namespace() -> None:
    other = {**DEVICE, "name": "imu1", "bus": {"kind": "sim", "address": 0x69}}
    text = _problem(
        {
            "ros2": {"enabled": True},
            "device": [
                {**DEVICE, "ros2": {"namespace": "imu"}},
                {**other, "ros2": {"namespace": "imu"}},
            ],
        }
    )
    assert "would both publish under /imu" in text and "namespace of its own" in text


def test_ros_domain_id_from_the_environment_and_its_errors() -> None:
    s = parse_config({"ros2": {"enabled": True}, "device": [DEVICE]}).ros2
    assert domain_id(s, {}) == 0
    assert domain_id(s, {"ROS_DOMAIN_ID": "42"}) == 42
    for bad in ("x", "-1", "300"):
        with pytest.raises(DomainError, match="ROS_DOMAIN_ID"):
            domain_id(s, {"ROS_DOMAIN_ID": bad})
    fixed = parse_config({"ros2": {"enabled": True, "domain_id": 5}, "device": [DEVICE]}).ros2
    assert domain_id(fixed, {"ROS_DOMAIN_ID": "x"}) == 5  # the config wins


def test_the_cli_says_it_without_a_traceback(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[ros2]\nenabled = true\nprofiles = ["dds", "rmw_zenohh"]\n\n[[device]]\nname = "imu0"\n'
        'chip = "mpu6050"\nbus = { kind = "sim" }\n'
    )
    r = subprocess.run(
        [sys.executable, "-m", "imud", "check-config", str(bad)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "ros2.profiles.1 = 'rmw_zenohh'" in r.stderr and "'rmw_zenoh'" in r.stderr


def test_sim_ros2_is_the_quick_start_with_ros2_on() -> None:
    quick = tomllib.loads((REPO / "configs" / "sim.toml").read_text())
    ros = tomllib.loads((REPO / "configs" / "sim-ros2.toml").read_text())
    assert ros["device"] == quick["device"] and ros["daemon"] == quick["daemon"]
    cfg = load_config(REPO / "configs" / "sim-ros2.toml")
    assert cfg.ros2.enabled and cfg.ros2.profiles == ["rmw_zenoh"]
    # its own loopback listener, clear of the ROS router's 7447, which it connects to
    assert cfg.zenoh.listen == ["tcp/127.0.0.1:7450"]
    assert cfg.session_settings().connect == ["tcp/127.0.0.1:7447"]
