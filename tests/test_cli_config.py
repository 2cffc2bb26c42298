"""`imud check-config` and `imud config-schema`, run as real subprocesses."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SIM_TOML = REPO / "configs" / "sim.toml"


def imud(*args: str, cwd: Path = REPO) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "imud", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def test_check_config_names_the_ros2_side_and_the_router_it_joins() -> None:
    r = imud("check-config", "configs/sim-ros2.toml")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert "connect tcp/127.0.0.1:7447" in lines[2] and "listen tcp/127.0.0.1:7450" in lines[2]
    assert lines[3].startswith("ros2: rmw_zenoh (jazzy), domain $ROS_DOMAIN_ID or 0")
    assert "/imud/bno0/imu/..." in lines[3]


def test_check_config_prints_a_short_summary() -> None:
    r = imud("check-config", "configs/sim-all.toml")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stdout.splitlines()
    assert len(lines) == 4 + 7  # headline, daemon, zenoh, ros2, one per device
    assert lines[0] == "configs/sim-all.toml: valid, 7 devices"
    assert lines[1].startswith("daemon:") and "realtime priority 20" in lines[1]
    assert lines[2].startswith("zenoh:") and "tcp/127.0.0.1:7450" in lines[2]
    assert "peer" in lines[2] and "'imud'" in lines[2]
    assert lines[3] == "ros2: off"
    devices = {ln.split()[0]: ln for ln in lines[4:]}
    assert list(devices) == ["imu0", "imu1", "icm0", "bmi0", "stim0", "bno0", "adis0"]
    imu0 = devices["imu0"].split()
    assert imu0[:3] == ["imu0", "mpu6050", "sim-i2c:sim0@0x68"]  # hex, not 104
    assert "1000 Hz" in devices["imu0"] and "gyro ±500 °/s" in devices["imu0"]
    assert "accel ±4 g" in devices["imu0"] and "sim (still, truth on)" in devices["imu0"]
    assert "@0x69" in devices["imu1"] and "500 Hz" in devices["imu1"]
    assert "32000 Hz" in devices["icm0"] and "truth" not in devices["icm0"]
    assert "sim-spi:spi1@cs0 + sim-spi:spi1@cs1" in devices["bmi0"]
    assert "sim-serial:rs422@1843200bd" in devices["stim0"] and "2000 Hz" in devices["stim0"]
    assert "sim-serial:uart0@115200bd" in devices["bno0"] and "100 Hz" in devices["bno0"]
    assert "sim-spi:spi2@cs0" in devices["adis0"] and "2000 Hz" in devices["adis0"]
    assert "{" not in r.stdout


def test_check_config_summary_of_real_hardware() -> None:
    r = imud("check-config", "configs/pixhawk-bmi088-spi.toml")
    assert r.returncode == 0, r.stderr
    device = r.stdout.splitlines()[-1]
    assert "spi:/dev/spidev1.0 + spi:/dev/spidev1.1" in device and device.endswith("hardware")


def test_check_config_json_is_the_full_model() -> None:
    r = imud("check-config", "--json", "configs/sim-all.toml")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert [d["name"] for d in doc["device"]] == [
        "imu0", "imu1", "icm0", "bmi0", "stim0", "bno0", "adis0",
    ]  # fmt: skip
    assert [d["chip"] for d in doc["device"]] == [
        "mpu6050", "mpu6050", "icm42688p", "bmi088", "stim300", "bno055", "adis16465",
    ]  # fmt: skip
    assert [d["odr_hz"] for d in doc["device"][:3]] == [1000.0, 500.0, 32000.0]
    assert (doc["device"][3]["odr_hz"], doc["device"][3]["accel_odr_hz"]) == (2000, 1600.0)
    assert [d["bus"]["address"] for d in doc["device"][:2]] == [0x68, 0x69]
    assert doc["device"][2]["bus"]["transport"] == "spi"
    assert doc["zenoh"]["listen"] == ["tcp/127.0.0.1:7450"]
    assert "Traceback" not in r.stderr


def test_check_config_prints_resolved_calibration_path(tmp_path: Path) -> None:
    (tmp_path / "etc").mkdir()
    (tmp_path / "etc" / "imu.cal.toml").write_text("[gyro]\nbias = [0.0, 0.0, 0.0]\n")
    (tmp_path / "etc" / "imud.toml").write_text(
        '[[device]]\nname = "imu0"\nchip = "mpu6050"\nbus = { kind = "sim" }\n'
        'calibration = "imu.cal.toml"\n'
    )
    r = imud("check-config", "--json", "etc/imud.toml", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    cal = json.loads(r.stdout)["device"][0]["calibration"]
    assert Path(cal) == (tmp_path / "etc" / "imu.cal.toml").resolve()


def test_check_config_invalid_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[zenoh]\nlisten = ["127.0.0.1:7450"]\n'
        '[[device]]\nname = "imu0"\nchip = "mpu6050"\n'
        'bus = { kind = "i2c", bus = 1, address = 0x68 }\ngyro_range_dps = 300\n'
    )
    r = imud("check-config", str(bad))
    assert r.returncode == 2
    assert r.stdout == ""
    assert "Traceback" not in r.stderr
    lines = r.stderr.splitlines()
    assert lines[0] == f"{bad}: invalid config:"
    problems = [ln.strip() for ln in lines[1:]]
    assert len(problems) == 2, r.stderr  # one line per problem
    assert any("device[0] 'imu0'" in p and "gyro_range_dps" in p and "300" in p for p in problems)
    assert any("zenoh.listen" in p and "127.0.0.1:7450" in p for p in problems)


def test_check_config_toml_syntax_error(tmp_path: Path) -> None:
    bad = tmp_path / "syntax.toml"
    bad.write_text('[zenoh]\nmode = "peer"\n\n[[device]\nname = "imu0"\n')  # line 4
    r = imud("check-config", str(bad))
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert "line 4" in r.stderr
    assert str(bad) in r.stderr


def test_check_config_missing_file(tmp_path: Path) -> None:
    r = imud("check-config", str(tmp_path / "nope.toml"))
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert "nope.toml" in r.stderr


def test_config_schema() -> None:
    r = imud("config-schema")
    assert r.returncode == 0, r.stderr
    schema = json.loads(r.stdout)
    assert schema["type"] == "object"
    assert {"zenoh", "device"} <= set(schema["properties"])
    assert "mpu6050" in r.stdout
    assert "gyro_range_dps" in r.stdout
    mpu = schema["$defs"]["Mpu6050Config"]
    assert sorted(mpu["properties"]["gyro_range_dps"]["enum"]) == [250, 500, 1000, 2000]
    assert mpu.get("additionalProperties") is False  # typos are rejected


def test_check_config_binary_file_no_traceback(tmp_path: Path) -> None:
    bad = tmp_path / "binary.toml"
    bad.write_bytes(b"\xff\xfe\x00\x01")
    r = imud("check-config", str(bad))
    assert "Traceback" not in r.stderr
    assert r.returncode == 2


def test_check_config_suggests_the_right_names(tmp_path: Path) -> None:
    bad = tmp_path / "typos.toml"
    bad.write_text(
        '[zenoh]\nlisten = ["tcp/127.0.0.1:70000"]\n'
        '[[devices]]\nname = "imu0"\nchip = "mpu6050"\nbus = { kind = "sim" }\n'
    )
    r = imud("check-config", str(bad))
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    problems = [ln.strip() for ln in r.stderr.splitlines()[1:]]
    assert any(p.startswith("devices:") and "[[device]]" in p for p in problems), problems
    assert any("zenoh.listen" in p and "70000" in p and "1-65535" in p for p in problems)
