"""ICM-42688-P config accepted and rejected, with the error message checked.

Expected limits come from the datasheet facts (docs/chips/icm42688p.md)
and the bus arithmetic written out in each test: a FIFO stream needs
ODR x packet bytes (16, or 20 with hires) x bits per byte (8 on SPI, 9 on I2C) x 1.25 overhead.
Most tests build the `[[device]]` table as a dict for `parse_config`; the SPI rate tests write
real TOML files and go through `load_config`, as the daemon does.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from imud.buses.models import SimBus, SpiBus
from imud.chips.icm42688p.config import Icm42688pConfig
from imud.config import ImudConfig, load_config, parse_config
from imud.errors import ConfigError

SPI_10M: dict[str, Any] = {"kind": "spi", "path": "/dev/spidev0.0", "speed_hz": 10_000_000}
SIM_SPI: dict[str, Any] = {"kind": "sim", "transport": "spi"}  # default clock 10 MHz
I2C_400K: dict[str, Any] = {"kind": "i2c", "bus": 1, "address": 0x68, "speed_hz": 400_000}
I2C_1M: dict[str, Any] = {"kind": "i2c", "bus": 1, "address": 0x68, "speed_hz": 1_000_000}

ALL_GYRO_RANGES = [15.625, 31.25, 62.5, 125, 250, 500, 1000, 2000]
ALL_ODRS = [12.5, 25, 50, 100, 200, 500, 1000, 2000, 4000, 8000, 16000, 32000]
UI_FILTERS = [
    "odr/2", "odr/4", "odr/5", "odr/8", "odr/10", "odr/16", "odr/20", "odr/40",
    "low_latency", "low_latency_8x",
]  # fmt: skip


def spi(speed_hz: int) -> dict[str, Any]:
    return {"kind": "spi", "path": "/dev/spidev0.0", "speed_hz": speed_hz}


def icm(bus: dict[str, Any] | None = None, name: str = "icm0", **fields: Any) -> dict[str, Any]:
    return {"name": name, "chip": "icm42688p", "bus": bus or SPI_10M, **fields}


def accept(*devices: dict[str, Any]) -> ImudConfig:
    return parse_config({"device": list(devices)})


def one(*devices: dict[str, Any], index: int = 0) -> Icm42688pConfig:
    d = accept(*devices).device[index]
    assert isinstance(d, Icm42688pConfig)
    return d


def errors(*devices: dict[str, Any]) -> list[str]:
    with pytest.raises(ConfigError) as info:
        accept(*devices)
    messages = info.value.messages
    assert messages, "a ConfigError must carry at least one message"
    return messages


def only_error(*devices: dict[str, Any]) -> str:
    messages = errors(*devices)
    assert len(messages) == 1, messages
    return messages[0]


def numbers_after(text: str, marker: str) -> list[str]:
    """The decimal numbers in `text` after the first `marker` (which must be present)."""
    assert marker in text, f"{marker!r} not in {text!r}"
    return re.findall(r"\d+(?:\.\d+)?", text.split(marker, 1)[1])


def needs_bps(odr_hz: float, packet: int, bits_per_byte: int) -> float:
    return odr_hz * packet * bits_per_byte * 1.25


def toml_device(bus: str, **fields: str) -> str:
    lines = ["[[device]]", 'name = "icm0"', 'chip = "icm42688p"', f"bus = {bus}"]
    lines += [f"{k} = {v}" for k, v in fields.items()]
    return "\n".join(lines) + "\n"


def load_toml(tmp_path: Path, text: str) -> ImudConfig:
    p = tmp_path / "imud.toml"
    p.write_text(text, encoding="utf-8")
    return load_config(p)


def toml_error(tmp_path: Path, text: str) -> str:
    with pytest.raises(ConfigError) as info:
        load_toml(tmp_path, text)
    assert len(info.value.messages) == 1, info.value.messages
    return info.value.messages[0]


SPI_TOML = '{ kind = "spi", path = "/dev/spidev0.0", speed_hz = 10000000 }'
SIM_SPI_TOML = '{ kind = "sim", transport = "spi" }'


# --- defaults ------------------------------------------------------------------------------------


def test_minimal_icm_gets_defaults() -> None:
    d = one(icm())
    assert d.chip == "icm42688p"
    assert (d.gyro_range_dps, d.accel_range_g, d.odr_hz) == (2000, 16, 1000)
    assert d.hires is False
    assert d.ui_filter == "odr/4"  # the chip's reset UI filter
    assert (d.gyro_aaf_hz, d.accel_aaf_hz) == (585, 1163)  # the chip's reset AAF rows
    assert isinstance(d.bus, SpiBus)
    assert d.sim is None


# --- ranges --------------------------------------------------------------------------------------


@pytest.mark.parametrize("dps", ALL_GYRO_RANGES)
def test_every_gyro_range_accepted(dps: float) -> None:
    assert one(icm(gyro_range_dps=dps)).gyro_range_dps == dps


def test_gyro_range_300_rejected_with_allowed_ranges() -> None:
    msg = only_error(icm(gyro_range_dps=300))
    assert "device[0]" in msg and "'icm0'" in msg
    after = numbers_after(msg, "gyro_range_dps")
    assert after[0] == "300", msg
    assert {"15.625", "31.25", "62.5", "125", "250", "500", "1000", "2000"} <= set(after[1:])


@pytest.mark.parametrize("g", [2, 4, 8, 16])
def test_every_accel_range_accepted(g: int) -> None:
    assert one(icm(accel_range_g=g)).accel_range_g == g


def test_accel_range_3_rejected_with_allowed_ranges() -> None:
    msg = only_error(icm(accel_range_g=3))
    after = numbers_after(msg, "accel_range_g")
    assert after[0] == "3", msg
    assert {"2", "4", "8", "16"} <= set(after[1:]), msg


# --- output data rate ----------------------------------------------------------------------------


@pytest.mark.parametrize("bus", [SPI_TOML, SIM_SPI_TOML], ids=["spi", "sim-spi"])
@pytest.mark.parametrize("odr", ALL_ODRS)
def test_every_odr_accepted_on_10mhz_spi(tmp_path: Path, bus: str, odr: float) -> None:
    # the worst case, 32 kHz: 32000 * 16 * 8 * 1.25 = 5.12 Mbit/s < 10 MHz
    cfg = load_toml(tmp_path, toml_device(bus, odr_hz=f"{odr:g}"))
    d = cfg.device[0]
    assert isinstance(d, Icm42688pConfig)
    assert d.odr_hz == odr


def test_sim_spi_bus_model() -> None:
    d = one(icm(SIM_SPI, odr_hz=32000))
    assert isinstance(d.bus, SimBus)
    assert (d.bus.transport, d.bus.cs) == ("spi", 0)
    assert d.sim is not None  # a simulated bus gets default simulator settings


def test_odr_300_rejected_with_allowed_rates(tmp_path: Path) -> None:
    msg = toml_error(tmp_path, toml_device(SPI_TOML, odr_hz="300"))
    after = numbers_after(msg, "odr_hz")
    assert after[0] == "300", msg
    assert {"12.5", "500", "1000", "8000", "32000"} <= set(after[1:]), msg


def _highest_named(msg: str, rate: int) -> bool:
    return re.search(rf"(at most|up to|highest|max\w*)\D{{0,30}}\b{rate}\b", msg) is not None


def test_i2c_400k_carries_2000_hz() -> None:
    assert needs_bps(2000, 16, 9) == 360_000  # <= 400 kHz
    assert one(icm(I2C_400K, odr_hz=2000)).odr_hz == 2000


@pytest.mark.parametrize("bus", [I2C_400K, {"kind": "sim"}], ids=["i2c", "sim-i2c"])
def test_i2c_400k_rejects_4000_hz(bus: dict[str, Any]) -> None:
    assert needs_bps(4000, 16, 9) == 720_000  # > 400 kHz; 2000 Hz (360 kbit/s) would fit
    msg = only_error(icm(bus, odr_hz=4000))
    assert "odr_hz" in msg and "'icm0'" in msg
    assert "I2C" in msg
    assert re.search(r"720 kbit/s", msg), msg  # what it needs
    assert re.search(r"0\.4 ?MHz|400 ?kHz|400000", msg), msg  # what the bus runs at
    assert _highest_named(msg, 2000), msg


def test_i2c_1mhz_carries_4000_rejects_8000() -> None:
    assert needs_bps(4000, 16, 9) == 720_000  # <= 1 MHz
    assert one(icm(I2C_1M, odr_hz=4000)).odr_hz == 4000
    assert needs_bps(8000, 16, 9) == 1_440_000  # > 1 MHz
    msg = only_error(icm(I2C_1M, odr_hz=8000))
    assert "I2C" in msg
    assert re.search(r"1\.44\d* ?Mbit/s", msg), msg
    assert re.search(r"\b1 ?MHz|1000 ?kHz|1000000", msg), msg
    assert _highest_named(msg, 4000), msg


def test_32khz_on_4mhz_spi_rejected() -> None:
    assert needs_bps(32000, 16, 8) == 5_120_000  # > 4 MHz; 16 kHz (2.56 Mbit/s) fits
    msg = only_error(icm(spi(4_000_000), odr_hz=32000))
    assert "SPI" in msg
    assert re.search(r"5\.12\d* ?Mbit/s", msg), msg
    assert re.search(r"\b4 ?MHz|4000 ?kHz|4000000", msg), msg
    assert _highest_named(msg, 16000), msg


def test_32khz_on_8mhz_spi_accepted() -> None:
    assert one(icm(spi(8_000_000), odr_hz=32000)).odr_hz == 32000


def test_spi_rate_check_through_toml(tmp_path: Path) -> None:
    bus = '{ kind = "spi", path = "/dev/spidev0.0", speed_hz = 4000000 }'
    msg = toml_error(tmp_path, toml_device(bus, odr_hz="32000"))
    assert "5.12" in msg and "SPI" in msg


@pytest.mark.parametrize("speed_hz", [24_000_001, 25_000_000, 50_000_000])
def test_spi_faster_than_24mhz_rejected(speed_hz: int) -> None:
    msg = only_error(icm(spi(speed_hz), odr_hz=1000))
    assert "SPI" in msg
    assert re.search(r"24 ?MHz|24000000", msg), msg


def test_spi_at_24mhz_accepted() -> None:
    d = one(icm(spi(24_000_000), odr_hz=32000))
    assert isinstance(d.bus, SpiBus) and d.bus.speed_hz == 24_000_000


def test_sim_spi_faster_than_24mhz_rejected() -> None:
    msg = only_error(icm({**SIM_SPI, "speed_hz": 30_000_000}, odr_hz=1000))
    assert re.search(r"24 ?MHz|24000000", msg), msg


def test_spi_faster_than_24mhz_rejected_with_default_odr() -> None:
    msg = only_error(icm(spi(25_000_000)))
    assert re.search(r"24 ?MHz|24000000", msg), msg


def test_default_odr_too_fast_for_100khz_i2c() -> None:
    assert needs_bps(1000, 16, 9) == 180_000  # > 100 kHz
    msg = only_error(icm({**I2C_400K, "speed_hz": 100_000}))
    assert "I2C" in msg and _highest_named(msg, 500), msg


def test_explicit_1000hz_too_fast_for_100khz_i2c() -> None:
    msg = only_error(icm({**I2C_400K, "speed_hz": 100_000}, odr_hz=1000))
    assert "I2C" in msg
    assert re.search(r"180 kbit/s", msg), msg
    assert _highest_named(msg, 500), msg  # 500 Hz needs 90 kbit/s


# --- hires (20-bit packets) ----------------------------------------------------------------------


def test_hires_at_2000_dps_16_g_accepted() -> None:
    d = one(icm(hires=True, gyro_range_dps=2000, accel_range_g=16))
    assert d.hires is True
    assert one(icm(hires=True)).hires is True  # 2000 / 16 are the defaults


def test_hires_with_1000_dps_rejected_naming_both_ranges() -> None:
    msg = only_error(icm(hires=True, gyro_range_dps=1000))
    assert "hires" in msg
    assert re.search(r"\b1000\b", msg) and re.search(r"\b2000\b", msg), msg


def test_hires_with_8_g_rejected_naming_both_ranges() -> None:
    msg = only_error(icm(hires=True, accel_range_g=8))
    assert "hires" in msg
    assert re.search(r"\b8\b", msg) and re.search(r"\b16\b", msg), msg


def test_hires_false_at_other_ranges_accepted() -> None:
    d = one(icm(hires=False, gyro_range_dps=1000, accel_range_g=8))
    assert (d.gyro_range_dps, d.accel_range_g, d.hires) == (1000, 8, False)


@pytest.mark.parametrize("bad", [{"gyro_range_dps": 300}, {"accel_range_g": 3}])
def test_hires_with_invalid_range_is_a_config_error(bad: dict[str, Any]) -> None:
    messages = errors(icm(hires=True, **bad))
    field = next(iter(bad))
    assert any(field in m for m in messages), messages


def test_hires_32khz_on_6mhz_spi_uses_20_byte_packets() -> None:
    # 16-byte packets fit 6 MHz (5.12 Mbit/s); 20-byte ones do not (6.4 Mbit/s)
    assert needs_bps(32000, 16, 8) == 5_120_000
    assert needs_bps(32000, 20, 8) == 6_400_000
    assert one(icm(spi(6_000_000), odr_hz=32000)).odr_hz == 32000
    msg = only_error(icm(spi(6_000_000), odr_hz=32000, hires=True))
    assert re.search(r"6\.40* ?Mbit/s", msg), msg
    assert _highest_named(msg, 16000), msg


def test_hires_on_i2c_uses_20_byte_packets() -> None:
    # 2000 Hz on 400 kHz I2C: 360 kbit/s with 16-byte packets, 450 kbit/s with 20-byte ones
    assert needs_bps(2000, 20, 9) == 450_000
    assert one(icm(I2C_400K, odr_hz=2000)).odr_hz == 2000
    msg = only_error(icm(I2C_400K, odr_hz=2000, hires=True))
    assert "I2C" in msg
    assert re.search(r"450 kbit/s", msg), msg
    assert _highest_named(msg, 1000), msg


# --- filters -------------------------------------------------------------------------------------


@pytest.mark.parametrize("ui", UI_FILTERS)
def test_ui_filter_accepted(ui: str) -> None:
    assert one(icm(ui_filter=ui)).ui_filter == ui


@pytest.mark.parametrize("bad", ["odr/3", "ODR/4", "odr/80", "", 4])
def test_ui_filter_rejected(bad: object) -> None:
    msg = only_error(icm(ui_filter=bad))
    assert "ui_filter" in msg
    assert "odr/4" in msg and "low_latency" in msg, msg  # lists what is allowed


@pytest.mark.parametrize("field", ["gyro_aaf_hz", "accel_aaf_hz"])
@pytest.mark.parametrize("value", [42, 258, 585, 1163, 3979, "off"])
def test_aaf_rows_and_off_accepted(field: str, value: int | str) -> None:
    fields: dict[str, Any] = {field: value}
    assert getattr(one(icm(**fields)), field) == value


@pytest.mark.parametrize(
    ("field", "bad", "nearest"),
    [
        ("gyro_aaf_hz", 250, 258),
        ("gyro_aaf_hz", 4000, 3979),
        ("gyro_aaf_hz", 10, 42),
        ("accel_aaf_hz", 1000, 997),
    ],
)
def test_aaf_off_table_rejected_naming_nearest(field: str, bad: int, nearest: int) -> None:
    fields: dict[str, Any] = {field: bad}
    msg = only_error(icm(**fields))
    after = numbers_after(msg, field)
    assert after[0] == str(bad), msg
    assert re.search(rf"nearest\D{{0,10}}{nearest}\b", msg), msg
    assert '"off"' in msg or "'off'" in msg, msg


def test_aaf_unknown_word_rejected() -> None:
    messages = errors(icm(gyro_aaf_hz="on"))
    assert all("gyro_aaf_hz" in m for m in messages), messages


# --- buses and slots -----------------------------------------------------------------------------


def test_i2c_icm_accepted() -> None:
    d = one(icm(I2C_400K))
    assert d.bus.kind == "i2c"


def test_icm_on_serial_bus_rejected() -> None:
    msg = only_error(icm({"kind": "serial", "port": "/dev/ttyUSB0"}))
    assert "serial" in msg
    assert "spi" in msg and "i2c" in msg, msg  # the buses it works over


def test_two_sim_spi_devices_same_cs_rejected() -> None:
    msg = only_error(icm(SIM_SPI, name="a"), icm({**SIM_SPI, "cs": 0}, name="b"))
    assert "device[1]" in msg and "'b'" in msg
    assert "'a'" in msg  # who already has it
    assert "cs0" in msg or "cs = 0" in msg, msg


def test_two_sim_spi_devices_different_cs_accepted() -> None:
    cfg = accept(icm({**SIM_SPI, "cs": 0}, name="a"), icm({**SIM_SPI, "cs": 1}, name="b"))
    buses = [d.bus for d in cfg.device]
    assert all(isinstance(b, SimBus) for b in buses)
    assert [b.cs for b in buses if isinstance(b, SimBus)] == [0, 1]
    assert len({b.key for b in buses}) == 1  # one bus, shared


def test_same_cs_on_different_sim_buses_accepted() -> None:
    cfg = accept(icm({**SIM_SPI, "bus": "s0"}, name="a"), icm({**SIM_SPI, "bus": "s1"}, name="b"))
    assert len(cfg.device) == 2


def test_sim_spi_and_sim_i2c_on_one_bus_accepted() -> None:
    # cs 0 and I2C address 0x68 are different slots
    cfg = accept(icm(SIM_SPI, name="a"), icm({"kind": "sim"}, name="b"))
    assert len(cfg.device) == 2


def test_two_real_spi_devices_same_path_rejected() -> None:
    msg = only_error(icm(SPI_10M, name="a"), icm(SPI_10M, name="b"))
    assert "/dev/spidev0.0" in msg and "'a'" in msg


# --- fields from other chips ---------------------------------------------------------------------


@pytest.mark.parametrize("value", [188, 256])
def test_mpu6050_dlpf_field_unknown_for_icm(value: int) -> None:
    # dlpf_hz is an MPU6050 field; the ICM's filters are ui_filter and the *_aaf_hz fields
    msg = only_error(icm(dlpf_hz=value))
    assert "dlpf_hz" in msg
    assert "unknown field" in msg
    assert "(icm42688p)" in msg


def test_mpu6050_field_unknown_for_icm_in_toml(tmp_path: Path) -> None:
    msg = toml_error(tmp_path, toml_device(SPI_TOML, dlpf_hz="188"))
    assert "dlpf_hz" in msg and "unknown field" in msg
