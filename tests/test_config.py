"""Config files accepted and rejected, with the error message checked.

Every test writes a real TOML file under `tmp_path` and loads it with `imud.config.load_config`,
the same entry point the daemon and the CLI use.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from imud.buses.models import SimBus
from imud.calib.watch import calibration_problems
from imud.chips.mpu6050.config import Mpu6050Config
from imud.config import ImudConfig, load_config
from imud.errors import ConfigError

REPO = Path(__file__).resolve().parent.parent
SIM_TOML = REPO / "configs" / "sim-all.toml"
QUICK_START_TOML = REPO / "configs" / "sim.toml"

# A valid first device, so that the device under test is device[1] and the index is meaningful.
GOOD_DEVICE = """
[[device]]
name = "imu0"
chip = "mpu6050"
bus = { kind = "i2c", bus = 1, address = 0x68 }
"""


def mpu_device(
    name: str = "imu1", address: int = 0x69, extra: dict[str, str] | None = None, **fields: str
) -> str:
    """A `[[device]]` block for an MPU6050 on /dev/i2c-1; field values are TOML literals."""
    fields = {**(extra or {}), **fields}
    lines = [
        "[[device]]",
        f'name = "{name}"',
        'chip = "mpu6050"',
        f'bus = {{ kind = "i2c", bus = 1, address = 0x{address:02x} }}',
    ]
    lines += [f"{k} = {v}" for k, v in fields.items()]
    return "\n".join(lines) + "\n"


def write(tmp_path: Path, text: str, name: str = "imud.toml") -> Path:
    p = tmp_path / name
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text, encoding="utf-8")
    return p


def load_text(tmp_path: Path, text: str) -> ImudConfig:
    return load_config(write(tmp_path, text))


def errors_of(tmp_path: Path, text: str) -> list[str]:
    """Load `text` expecting a ConfigError; return its message lines."""
    with pytest.raises(ConfigError) as info:
        load_text(tmp_path, text)
    messages = info.value.messages
    assert messages, "a ConfigError must carry at least one message"
    assert str(info.value) == "\n".join(messages)
    return messages


def only_error(tmp_path: Path, text: str) -> str:
    messages = errors_of(tmp_path, text)
    assert len(messages) == 1, messages
    return messages[0]


def mpu(cfg: ImudConfig, index: int = 0) -> Mpu6050Config:
    d = cfg.device[index]
    assert isinstance(d, Mpu6050Config)
    return d


def numbers_after(text: str, marker: str) -> list[str]:
    """The decimal numbers in `text` after the first `marker` (which must be present)."""
    assert marker in text, f"{marker!r} not in {text!r}"
    return re.findall(r"\d+(?:\.\d+)?", text.split(marker, 1)[1])


# --- the shipped example -------------------------------------------------------------------------


def test_quick_start_config_is_the_lighter_set() -> None:
    """The README's quick start: the five devices its calibration walk-through uses, the
    ICM-42688-P at 8 kHz (what a 2-core machine runs with the simulators and loses nothing)."""
    cfg = load_config(QUICK_START_TOML)
    assert [(d.name, d.chip) for d in cfg.device] == [
        ("imu0", "mpu6050"), ("imu1", "mpu6050"), ("icm0", "icm42688p"), ("bmi0", "bmi088"),
        ("bno0", "bno055"),
    ]  # fmt: skip
    assert cfg.device[2].odr_hz == 8000.0
    assert cfg.daemon.realtime_priority == 20
    assert cfg.zenoh.listen == ["tcp/127.0.0.1:7450"]


def test_sim_toml_loads_with_both_devices() -> None:
    cfg = load_config(SIM_TOML)
    assert [d.name for d in cfg.device] == [
        "imu0", "imu1", "icm0", "bmi0", "stim0", "bno0", "adis0",
    ]  # fmt: skip
    assert [d.chip for d in cfg.device][3:] == ["bmi088", "stim300", "bno055", "adis16465"]
    imu0, imu1 = mpu(cfg, 0), mpu(cfg, 1)
    assert isinstance(imu0.bus, SimBus) and isinstance(imu1.bus, SimBus)
    assert (imu0.chip, imu1.chip) == ("mpu6050", "mpu6050")
    assert (imu0.gyro_range_dps, imu0.accel_range_g, imu0.dlpf_hz) == (500, 4, 188)
    assert imu0.odr_hz == 1000.0
    assert (imu1.gyro_range_dps, imu1.accel_range_g, imu1.dlpf_hz) == (250, 2, 98)
    assert imu1.odr_hz == 500.0
    assert (imu0.bus.kind, imu0.bus.address) == ("sim", 0x68)
    assert (imu1.bus.kind, imu1.bus.address) == ("sim", 0x69)
    assert imu0.sim is not None and imu1.sim is not None
    assert (imu0.sim.seed, imu1.sim.seed) == (1, 2)
    assert imu0.sim.motion.kind == "still"
    assert imu1.sim.motion.kind == "poses"
    assert cfg.zenoh.listen == ["tcp/127.0.0.1:7450"]
    assert cfg.zenoh.prefix == "imud"


def test_minimal_device_gets_documented_defaults(tmp_path: Path) -> None:
    cfg = load_text(tmp_path, GOOD_DEVICE)
    assert len(cfg.device) == 1
    d = mpu(cfg)
    assert (d.gyro_range_dps, d.accel_range_g, d.dlpf_hz, d.odr_hz) == (500, 4, 188, 1000.0)
    assert d.calibration is None
    assert d.sim is None  # only simulated buses get a default [device.sim]
    assert cfg.zenoh.listen == ["tcp/127.0.0.1:7450"]


def test_sim_bus_without_sim_table_gets_default_sim_settings(tmp_path: Path) -> None:
    cfg = load_text(
        tmp_path,
        '[[device]]\nname = "s"\nchip = "mpu6050"\nbus = { kind = "sim" }\n',
    )
    assert cfg.device[0].sim is not None


# --- MPU6050 fields ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("field", "bad", "allowed"),
    [
        ("gyro_range_dps", "300", {"250", "500", "1000", "2000"}),
        ("accel_range_g", "3", {"2", "4", "8", "16"}),
        ("dlpf_hz", "100", {"256", "188", "98", "42", "20", "10", "5"}),
    ],
)
def test_mpu6050_enum_field_rejected_with_allowed_values(
    tmp_path: Path, field: str, bad: str, allowed: set[str]
) -> None:
    msg = only_error(tmp_path, GOOD_DEVICE + mpu_device(extra={field: bad}))
    assert "device[1]" in msg
    assert "'imu1'" in msg
    assert "imu0" not in msg  # the good device is not blamed
    after_field = numbers_after(msg, field)
    assert after_field[0] == bad, msg  # the bad value comes right after the field name
    assert allowed <= set(after_field[1:]), msg


def test_odr_300_rejected_naming_nearest_reachable_rate(tmp_path: Path) -> None:
    msg = only_error(tmp_path, GOOD_DEVICE + mpu_device(odr_hz="300"))
    assert "device[1]" in msg and "'imu1'" in msg
    assert numbers_after(msg, "odr_hz")[0] == "300"
    # 1 kHz internal rate (DLPF on): 1000/(1+2) = 333.33 is closer to 300 than 1000/(1+3) = 250
    assert re.search(r"nearest\D*333\.333", msg), msg
    allowed = set(numbers_after(msg, "allowed"))
    assert {"1000", "500", "250", "200"} <= allowed, msg


def test_odr_2000_rejected_nearest_is_1khz(tmp_path: Path) -> None:
    msg = only_error(tmp_path, GOOD_DEVICE + mpu_device(odr_hz="2000"))
    assert "device[1]" in msg and "'imu1'" in msg
    assert numbers_after(msg, "odr_hz")[0] == "2000"
    assert re.search(r"nearest\D*1000\b", msg), msg


def test_odr_below_8khz_range_rejected_with_dlpf_off(tmp_path: Path) -> None:
    # DLPF off: 8 kHz / (1 + 255) = 31.25 Hz is the slowest rate; 4 Hz is not reachable
    msg = only_error(tmp_path, GOOD_DEVICE + mpu_device(dlpf_hz="256", odr_hz="4"))
    assert "dlpf_hz = 256" in msg
    assert re.search(r"nearest\D*31\.25\b", msg), msg


def test_odr_8khz_rejected_even_with_dlpf_off(tmp_path: Path) -> None:
    msg = only_error(tmp_path, GOOD_DEVICE + mpu_device(dlpf_hz="256", odr_hz="8000"))
    assert numbers_after(msg, "odr_hz")[0] == "8000"
    assert re.search(r"nearest\D*1000\b", msg), msg


@pytest.mark.parametrize("bad", ["0", "-100.0", "nan"])
def test_odr_must_be_positive(tmp_path: Path, bad: str) -> None:
    msg = only_error(tmp_path, GOOD_DEVICE + mpu_device(odr_hz=bad))
    assert "device[1]" in msg and "odr_hz" in msg


def test_bad_dlpf_and_bad_odr_reports_the_dlpf(tmp_path: Path) -> None:
    # odr_hz depends on dlpf_hz: with dlpf_hz invalid, the dlpf_hz error is the one that matters
    messages = errors_of(tmp_path, GOOD_DEVICE + mpu_device(dlpf_hz="100", odr_hz="300"))
    assert any("dlpf_hz" in m for m in messages), messages


@pytest.mark.parametrize(
    ("dlpf_hz", "odr_toml", "odr_hz", "divider"),
    [
        # sample rate = internal / (1 + SMPLRT_DIV); internal = 1 kHz with the DLPF on
        (188, "1000", 1000.0, 0),
        (188, "500", 500.0, 1),
        (188, "200", 200.0, 4),
        (188, "333.3333333", 1000.0 / 3.0, 2),
        (188, "4", 4.0, 249),
        (188, "3.90625", 1000.0 / 256.0, 255),
        (5, "10", 10.0, 99),
        # DLPF off (dlpf_hz = 256): the gyro samples at 8 kHz
        (256, "1000", 1000.0, 7),
        (256, "888.8888888888889", 8000.0 / 9.0, 8),
        (256, "888.889", 8000.0 / 9.0, 8),
        (256, "31.25", 8000.0 / 256.0, 255),
    ],
)
def test_reachable_odr_accepted(
    tmp_path: Path, dlpf_hz: int, odr_toml: str, odr_hz: float, divider: int
) -> None:
    cfg = load_text(tmp_path, mpu_device(dlpf_hz=str(dlpf_hz), odr_hz=odr_toml))
    d = mpu(cfg)
    assert d.dlpf_hz == dlpf_hz
    assert math.isclose(d.odr_hz, odr_hz, rel_tol=1e-6)
    assert d.smplrt_div == divider


# --- chip, fields, uniqueness --------------------------------------------------------------------


def test_unknown_chip_lists_known_chips(tmp_path: Path) -> None:
    text = GOOD_DEVICE + mpu_device().replace('"mpu6050"', '"icm42688"')
    msg = only_error(tmp_path, text)
    assert "device[1]" in msg and "'imu1'" in msg
    assert "'icm42688'" in msg
    assert "mpu6050" in msg.split("icm42688", 1)[1], msg  # the known chips follow


def test_missing_chip(tmp_path: Path) -> None:
    text = GOOD_DEVICE + mpu_device().replace('chip = "mpu6050"\n', "")
    msg = only_error(tmp_path, text)
    assert "device[1]" in msg and "'imu1'" in msg
    assert "chip" in msg
    assert "mpu6050" in msg  # says which chips there are


def test_unknown_field_named(tmp_path: Path) -> None:
    msg = only_error(tmp_path, GOOD_DEVICE + mpu_device(odr_hx="500"))
    assert "device[1]" in msg and "'imu1'" in msg
    assert "odr_hx" in msg
    assert "unknown field" in msg


def test_unknown_top_level_table_named(tmp_path: Path) -> None:
    messages = errors_of(tmp_path, GOOD_DEVICE + "[zenho]\nmode = 'peer'\n")
    assert any("zenho" in m and "unknown field" in m for m in messages), messages


def test_duplicate_device_names(tmp_path: Path) -> None:
    msg = only_error(tmp_path, GOOD_DEVICE + mpu_device(name="imu0", address=0x69))
    assert "device[1]" in msg
    assert "'imu0'" in msg
    assert "device[0]" in msg  # names the device already using it
    assert "unique" in msg


def test_same_bus_and_address(tmp_path: Path) -> None:
    # bus = 1 and bus = "/dev/i2c-1" are the same bus
    second = mpu_device(name="imu1", address=0x68).replace("bus = 1", 'bus = "/dev/i2c-1"')
    msg = only_error(tmp_path, GOOD_DEVICE + second)
    assert "device[1]" in msg and "'imu1'" in msg
    assert "0x68" in msg
    assert "/dev/i2c-1" in msg
    assert "'imu0'" in msg  # who already holds the address


def test_same_address_on_other_bus_accepted(tmp_path: Path) -> None:
    second = mpu_device(name="imu1", address=0x68).replace("bus = 1", "bus = 2")
    cfg = load_text(tmp_path, GOOD_DEVICE + second)
    assert [d.name for d in cfg.device] == ["imu0", "imu1"]


def test_same_sim_bus_and_address(tmp_path: Path) -> None:
    sim_device = '[[device]]\nname = "{}"\nchip = "mpu6050"\nbus = {{ kind = "sim", bus = "s" }}\n'
    text = sim_device.format("a") + sim_device.format("b")  # both at the default 0x68
    msg = only_error(tmp_path, text)
    assert "device[1]" in msg and "'b'" in msg and "'a'" in msg and "0x68" in msg


def test_sim_table_on_i2c_bus_rejected(tmp_path: Path) -> None:
    text = GOOD_DEVICE + mpu_device() + "[device.sim]\nseed = 3\n"
    msg = only_error(tmp_path, text)
    assert "device[1]" in msg and "'imu1'" in msg
    assert "[device.sim]" in msg
    assert "i2c" in msg


@pytest.mark.parametrize("name", ["imu 1", "imu*", "a/b", ""])
def test_device_name_must_be_key_expression_safe(tmp_path: Path, name: str) -> None:
    msg = only_error(tmp_path, mpu_device(name=name))
    assert "device[0]" in msg
    assert "name" in msg
    assert repr(name) in msg


def test_i2c_address_out_of_7bit_range(tmp_path: Path) -> None:
    msg = only_error(tmp_path, mpu_device(address=0x80))
    assert "device[0]" in msg and "address" in msg and "128" in msg


# --- file-level errors ---------------------------------------------------------------------------


def test_toml_syntax_error_names_the_line(tmp_path: Path) -> None:
    text = '[zenoh]\nmode = "peer"\nprefix = \n' + GOOD_DEVICE  # line 3 has no value
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    (msg,) = info.value.messages
    assert str(path) in msg
    assert "line 3" in msg
    assert "TOML" in msg


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.toml"
    with pytest.raises(ConfigError) as info:
        load_config(path)
    (msg,) = info.value.messages
    assert str(path) in msg
    assert "no such file" in msg


def test_directory_instead_of_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(tmp_path)
    assert "directory" in info.value.messages[0]


def test_empty_device_list_rejected(tmp_path: Path) -> None:
    msg = only_error(tmp_path, "device = []\n")
    assert msg.startswith("device")
    assert "at least 1" in msg


def test_no_device_at_all_rejected(tmp_path: Path) -> None:
    msg = only_error(tmp_path, '[zenoh]\nmode = "peer"\n')
    assert "device" in msg and "missing" in msg


# --- calibration files ---------------------------------------------------------------------------

CAL_TEXT = "version = 1\n[accel]\nbias = [0.1, 0.2, 0.3]\n"


def test_calibration_path_resolved_against_config_dir(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    conf_dir = tmp_path / "etc"
    cal = write(conf_dir, CAL_TEXT, "cal/imu1.toml")
    cfg_path = write(conf_dir, mpu_device(calibration='"cal/imu1.toml"'))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # relative to the config, not to the working directory
    cfg = load_config(cfg_path)
    got = cfg.device[0].calibration
    assert got is not None
    assert got.is_absolute()
    assert got.resolve() == cal.resolve()


def test_calibration_path_via_relative_config_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    write(tmp_path / "etc", CAL_TEXT, "imu1.cal.toml")
    write(tmp_path / "etc", mpu_device(calibration='"imu1.cal.toml"'))
    monkeypatch.chdir(tmp_path)
    cfg = load_config("etc/imud.toml")
    got = cfg.device[0].calibration
    assert got is not None and got.is_absolute()
    assert got == (tmp_path / "etc" / "imu1.cal.toml").resolve()


def test_absolute_calibration_path_kept(tmp_path: Path) -> None:
    cal = write(tmp_path / "abs", CAL_TEXT, "c.toml")
    cfg = load_text(tmp_path, mpu_device(calibration=f'"{cal.as_posix()}"'))
    assert cfg.device[0].calibration == cal


def problems_of(cfg_path: Path) -> list[str]:
    errors, _notes = calibration_problems(load_config(cfg_path))
    return errors


def test_missing_calibration_file(tmp_path: Path) -> None:
    # not written yet: the config loads, the check notes it (the daemon picks it up later)
    conf_dir = tmp_path / "etc"
    (conf_dir / "cal").mkdir(parents=True)
    cfg_path = write(conf_dir, GOOD_DEVICE + mpu_device(calibration='"cal/missing.toml"'))
    errors, (msg,) = calibration_problems(load_config(cfg_path))
    assert errors == []
    assert "device[1]" in msg and "'imu1'" in msg
    assert "calibration" in msg and "does not exist" in msg and "imud calibrate" in msg
    assert str(conf_dir.resolve() / "cal" / "missing.toml") in msg  # the resolved path


def test_invalid_calibration_file_reported_per_device(tmp_path: Path) -> None:
    write(tmp_path, "[accel]\nbias = [0, 0, 0]\nbais = [1, 1, 1]\n", "bad.cal.toml")
    (msg,) = problems_of(write(tmp_path, GOOD_DEVICE + mpu_device(calibration='"bad.cal.toml"')))
    assert "device[1]" in msg and "'imu1'" in msg
    assert "calibration" in msg
    assert "bais" in msg


def test_every_bad_calibration_reported(tmp_path: Path) -> None:
    write(tmp_path, "[accel]\nbias = [nan, 0, 0]\n", "a.toml")
    write(tmp_path, "[gyro]\nscale = [1, 1, 0]\n", "b.toml")
    text = mpu_device(name="a", address=0x68, calibration='"a.toml"') + mpu_device(
        name="b", address=0x69, calibration='"b.toml"'
    )
    messages = problems_of(write(tmp_path, text))
    assert len(messages) == 2
    assert "device[0] 'a'" in messages[0]
    assert "device[1] 'b'" in messages[1]


def test_calibration_for_another_chip_reported(tmp_path: Path) -> None:
    write(tmp_path, 'chip = "icm42688p"\n[gyro]\nbias = [0, 0, 0]\n', "c.toml")
    (msg,) = problems_of(write(tmp_path, mpu_device(calibration='"c.toml"')))
    assert "made for a icm42688p, this device is a mpu6050" in msg


# --- zenoh ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("key", ["listen", "connect"])
@pytest.mark.parametrize("endpoint", ["127.0.0.1:7450", "http/127.0.0.1:80", "localhost"])
def test_bad_zenoh_endpoint_rejected(tmp_path: Path, key: str, endpoint: str) -> None:
    msg = only_error(tmp_path, f'[zenoh]\n{key} = ["{endpoint}"]\n' + GOOD_DEVICE)
    assert f"zenoh.{key}" in msg
    assert repr(endpoint) in msg
    assert "tcp/" in msg  # shows what an endpoint looks like


def test_good_zenoh_endpoints_accepted(tmp_path: Path) -> None:
    text = (
        '[zenoh]\nmode = "client"\n'
        'listen = ["tcp/127.0.0.2:7450", "udp/[::1]:7450"]\n'
        'connect = ["tcp/192.168.1.10:7450", "unixsock-stream//tmp/z.sock"]\n'
        'prefix = "robot1/imud"\n' + GOOD_DEVICE
    )
    cfg = load_text(tmp_path, text)
    assert cfg.zenoh.mode == "client"
    assert cfg.zenoh.listen == ["tcp/127.0.0.2:7450", "udp/[::1]:7450"]
    assert cfg.zenoh.connect[1] == "unixsock-stream//tmp/z.sock"
    assert cfg.zenoh.prefix == "robot1/imud"


@pytest.mark.parametrize("prefix", ["imud/*", "*", "imud/**", "imu*d", "imud/", "/imud", "a//b"])
def test_prefix_wildcards_and_empty_chunks_rejected(tmp_path: Path, prefix: str) -> None:
    msg = only_error(tmp_path, f'[zenoh]\nprefix = "{prefix}"\n' + GOOD_DEVICE)
    assert "zenoh.prefix" in msg
    assert repr(prefix) in msg


def test_bad_zenoh_mode_rejected(tmp_path: Path) -> None:
    msg = only_error(tmp_path, '[zenoh]\nmode = "server"\n' + GOOD_DEVICE)
    assert "zenoh.mode" in msg and "'server'" in msg and "peer" in msg


# --- defects found in review, now fixed ---------------------------------------------------------


def test_unknown_bus_kind_message_is_about_the_bus(tmp_path: Path) -> None:
    text = '[[device]]\nname = "x"\nchip = "mpu6050"\nbus = { kind = "usb" }\n'
    msg = only_error(tmp_path, text)
    assert "bus" in msg and "'usb'" in msg
    assert "chip" not in msg.split("(mpu6050)", 1)[-1], msg


def test_missing_motion_kind_message_is_about_the_motion(tmp_path: Path) -> None:
    text = (
        '[[device]]\nname = "x"\nchip = "mpu6050"\nbus = { kind = "sim" }\n'
        "[device.sim]\nmotion = { rate_dps = [1.0, 2.0, 3.0] }\n"
    )
    msg = only_error(tmp_path, text)
    assert "motion" in msg and "kind" in msg
    assert "chip" not in msg.split("(mpu6050)", 1)[-1], msg


def test_calibration_path_is_a_directory(tmp_path: Path) -> None:
    (tmp_path / "caldir").mkdir()
    (msg,) = problems_of(write(tmp_path, mpu_device(calibration='"caldir"')))
    assert "calibration" in msg and "cannot read" in msg


def test_config_file_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "bin.toml"
    path.write_bytes(b"\xff\xfe[zenoh]\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(path) in info.value.messages[0]


def test_mpu6050_on_spi_bus_rejected(tmp_path: Path) -> None:
    text = (
        '[[device]]\nname = "x"\nchip = "mpu6050"\n'
        'bus = { kind = "spi", path = "/dev/spidev0.0" }\n'
    )
    msg = only_error(tmp_path, text)
    assert "spi" in msg and "i2c" in msg


def test_device_named_daemon_is_reserved(tmp_path: Path) -> None:
    text = '[[device]]\nname = "daemon"\nchip = "mpu6050"\nbus = { kind = "sim" }\n'
    msg = only_error(tmp_path, text)
    assert "reserved" in msg and "daemon/status" in msg


@pytest.mark.parametrize("path", sorted(Path(__file__).parent.parent.glob("configs/*.toml")))
def test_every_shipped_config_validates(path: Path) -> None:
    cfg = load_config(path)
    assert cfg.device, path


# --- "did you mean" and endpoint ports --------------------------------------------------------


@pytest.mark.parametrize(
    ("fragment", "where", "suggestion"),
    [
        ("odr_hx = 500\n", "device[1] 'imu1' (mpu6050): odr_hx", "'odr_hz'"),
        (
            "gyro_rnage_dps = 500\n",
            "device[1] 'imu1' (mpu6050): gyro_rnage_dps",
            "'gyro_range_dps'",
        ),
    ],
)
def test_unknown_device_field_gets_did_you_mean(
    tmp_path: Path, fragment: str, where: str, suggestion: str
) -> None:
    msg = only_error(tmp_path, GOOD_DEVICE + mpu_device() + fragment)
    assert msg.startswith(where + ": unknown field"), msg
    assert f"did you mean {suggestion}?" in msg


def test_unknown_nested_fields_get_did_you_mean_at_their_own_level(tmp_path: Path) -> None:
    text = GOOD_DEVICE + (
        '[[device]]\nname = "imu1"\nchip = "mpu6050"\n'
        'bus = { kind = "sim", adress = 0x69 }\n'
        "[device.sim]\ntruht = true\n"
        'motion = { kind = "tumble", rate_dp = [1.0, 2.0, 3.0] }\n'
        "[device.sim.errors]\nideall = true\n"
    )
    messages = errors_of(tmp_path, text)
    assert len(messages) == 4, messages
    want = {
        "bus.adress": "'address'",  # the union tag ('sim') is not shown as a key
        "sim.truht": "'truth'",
        "sim.motion.rate_dp": "'rate_dps'",
        "sim.errors.ideall": "'ideal'",
    }
    for field, suggestion in want.items():
        line = f"device[1] 'imu1' (mpu6050): {field}: unknown field; did you mean {suggestion}?"
        assert line in messages, messages


def test_devices_table_gets_a_hint_to_write_device(tmp_path: Path) -> None:
    messages = errors_of(tmp_path, GOOD_DEVICE.replace("[[device]]", "[[devices]]"))
    assert any(m.startswith("devices: unknown field; did you mean [[device]]?") for m in messages)
    assert any(m.startswith("device: missing") and "[[device]]" in m for m in messages)


def test_misspelt_top_level_table_gets_did_you_mean(tmp_path: Path) -> None:
    msg = only_error(tmp_path, "[deamon]\nbus_processes = false\n" + GOOD_DEVICE)
    assert msg == "deamon: unknown field; did you mean [daemon]?"


def test_unknown_field_far_from_any_name_lists_the_allowed_ones(tmp_path: Path) -> None:
    msg = only_error(tmp_path, "[daemon]\nzzz = 1\n" + GOOD_DEVICE)
    assert "daemon.zzz: unknown field" in msg
    assert "bus_processes" in msg and "realtime_priority" in msg


def test_unknown_chip_gets_did_you_mean(tmp_path: Path) -> None:
    msg = only_error(tmp_path, GOOD_DEVICE + mpu_device().replace("mpu6050", "mpu6500"))
    assert "did you mean 'mpu6050'?" in msg


@pytest.mark.parametrize("key", ["listen", "connect"])
@pytest.mark.parametrize(
    ("endpoint", "says"),
    [
        ("tcp/127.0.0.1:99999", "port 99999 is out of range (1-65535)"),
        ("tcp/127.0.0.1:0", "port 0 is out of range (1-65535)"),
        ("udp/[::1]:65536", "port 65536 is out of range"),
        ("tcp/127.0.0.1:http", "port 'http' is not a number"),
        ("tcp/127.0.0.1", "needs HOST:PORT"),
    ],
)
def test_endpoint_ports_checked(tmp_path: Path, key: str, endpoint: str, says: str) -> None:
    msg = only_error(tmp_path, f'[zenoh]\n{key} = ["{endpoint}"]\n' + GOOD_DEVICE)
    assert msg.startswith(f"zenoh.{key}: "), msg
    assert repr(endpoint) in msg and says in msg


def test_endpoint_port_bounds_accepted(tmp_path: Path) -> None:
    text = '[zenoh]\nlisten = ["tcp/127.0.0.1:1", "tcp/127.0.0.1:65535?prio=1"]\n' + GOOD_DEVICE
    assert load_text(tmp_path, text).zenoh.listen[1] == "tcp/127.0.0.1:65535?prio=1"
