"""`imud status`'s human view shows each chip's own health (its driver's chip_status) on a line
of its own, whatever the chip: zeros and empties left out, nested tables as key=value."""

from __future__ import annotations

from rich.console import Console

from imud.cli.status_view import status_view
from imud.config import parse_config
from imud.device import initial_status


def test_chip_status_is_shown_on_its_own_line() -> None:
    cfg = parse_config(
        {"device": [{"name": "stim0", "chip": "stim300",
                     "bus": {"kind": "sim", "transport": "serial", "baud": 1843200}}]}
    ).device[0]  # fmt: skip
    d = initial_status(cfg).to_json()
    d["state"] = "running"
    d["chip_counters"] = {"crc_errors": 3}
    d["chip_status"] = {
        "datagram": "0xA7 rate_acc_incl_temp",
        "resyncs": 0,
        "status_bits": ["STARTUP"],
        "status_counts": {"STARTUP": 1352},
        "calibration": {"sys": 3, "gyro": 3},
    }
    console = Console(width=200, record=True)
    for r in status_view({"version": "x", "uptime_s": 1, "devices": [d]}, "tcp/x:1", console):
        console.print(r)
    text = console.export_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("stim0 stim300:"))
    assert "datagram 0xA7 rate_acc_incl_temp" in line
    assert "stim0: 3 crc errors" in text  # a counter its spec declares, among the device's
    assert "resyncs" not in line  # zero: nothing to say
    assert "status counts STARTUP=1352" in line and "calibration sys=3 gyro=3" in line


def test_the_ros2_output_has_a_line_naming_a_profile_that_did_not_start() -> None:
    ros2 = {
        "profiles": ["rmw_zenoh", "dds"],
        "domain_id": 3,
        "node": "imud",
        "topics": ["/imu0/imu/data_raw", "/diagnostics"],
        "messages": {"/imu0/imu/data_raw": 4000, "/diagnostics": 20},
        "dropped": {"imu0": 2},
        "error": "dds: the dds profile needs Cyclone DDS",
    }
    console = Console(width=300, record=True)
    st = {"version": "x", "uptime_s": 1, "devices": [], "ros2": ros2}
    for r in status_view(st, "tcp/x:1", console):
        console.print(r)
    (line,) = [ln for ln in console.export_text().splitlines() if ln.startswith("ROS 2")]
    assert line.startswith("ROS 2 (rmw_zenoh, dds) domain 3, node imud: 2 topics, 4020 messages")
    assert "not sent, stamp not after the last: imu0 2" in line
    assert line.endswith("; dds: the dds profile needs Cyclone DDS")
