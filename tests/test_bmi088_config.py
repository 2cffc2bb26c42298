"""BMI088 config accepted and rejected through `imud.config.parse_config`, messages checked.

Expected values come from the facts sheet (docs/chips/bmi088.md): accel ODR codes 12.5..1600 Hz,
accel ranges 3/6/12/24 g, gyro ranges 125..2000 dps, the GYRO_BANDWIDTH table (code -> ODR /
filter), the 10 MHz SPI limit. The I2C bandwidth a BMI088 needs is written out in each test: (accel
ODR x 7 B + gyro ODR x 6 B) x 9 bits a byte x 1.25 overhead.
"""

from __future__ import annotations

import re
from typing import Any

import pytest

from imud.buses.models import I2cBus, SimBus, SpiBus
from imud.chips.bmi088.config import Bmi088Config
from imud.config import ImudConfig, parse_config
from imud.errors import ConfigError

ACC_SPI: dict[str, Any] = {"kind": "spi", "path": "/dev/spidev1.0", "speed_hz": 10_000_000}
GYR_SPI: dict[str, Any] = {"kind": "spi", "path": "/dev/spidev1.1", "speed_hz": 10_000_000}
ACC_I2C: dict[str, Any] = {"kind": "i2c", "bus": 1, "address": 0x18}
GYR_I2C: dict[str, Any] = {"kind": "i2c", "bus": 1, "address": 0x68}

# GYRO_BANDWIDTH, from the datasheet table: code -> (ODR Hz, filter Hz)
BANDWIDTH_TABLE = {
    0x00: (2000, 532), 0x01: (2000, 230), 0x02: (1000, 116), 0x03: (400, 47),
    0x04: (200, 23), 0x05: (100, 12), 0x06: (200, 64), 0x07: (100, 32),
}  # fmt: skip
ACCEL_ODRS = [12.5, 25, 50, 100, 200, 400, 800, 1600]


def i2c(address: int, speed_hz: int | None = None, bus: int = 1) -> dict[str, Any]:
    d: dict[str, Any] = {"kind": "i2c", "bus": bus, "address": address}
    if speed_hz is not None:
        d["speed_hz"] = speed_hz
    return d


def bmi(
    bus: dict[str, Any] | None = None,
    gyro_bus: dict[str, Any] | None = None,
    name: str = "bmi0",
    **fields: Any,
) -> dict[str, Any]:
    return {
        "name": name,
        "chip": "bmi088",
        "bus": bus or ACC_SPI,
        "gyro_bus": gyro_bus or GYR_SPI,
        **fields,
    }


def accept(*devices: dict[str, Any]) -> ImudConfig:
    return parse_config({"device": list(devices)})


def one(*devices: dict[str, Any], index: int = 0) -> Bmi088Config:
    d = accept(*devices).device[index]
    assert isinstance(d, Bmi088Config)
    return d


def only_error(*devices: dict[str, Any]) -> str:
    with pytest.raises(ConfigError) as info:
        accept(*devices)
    messages = info.value.messages
    assert len(messages) == 1, messages
    assert str(info.value) == messages[0]
    return messages[0]


def i2c_need_bps(accel_odr: float, gyro_odr: float) -> float:
    return (accel_odr * 7 + gyro_odr * 6) * 9 * 1.25


# --- defaults and derived values -----------------------------------------------------------------


def test_minimal_bmi088_gets_defaults() -> None:
    d = one(bmi())
    assert d.chip == "bmi088"
    assert (d.accel_range_g, d.accel_odr_hz, d.accel_filter) == (24, 1600.0, "normal")
    assert (d.gyro_range_dps, d.odr_hz) == (2000, 2000)
    assert d.gyro_filter_hz == 532  # the widest filter at 2000 Hz
    assert isinstance(d.bus, SpiBus) and isinstance(d.gyro_bus, SpiBus)
    assert d.sim is None


def test_odr_hz_is_the_gyro_rate() -> None:
    # the published rate is the gyro's, whatever the accel runs at: it picks GYRO_BANDWIDTH
    d = one(bmi(odr_hz=400, accel_odr_hz=1600))
    assert d.odr_hz == 400.0 and d.accel_odr_hz == 1600.0
    assert d.gyro_bandwidth_code() == 0x03  # 400 Hz ODR, 47 Hz filter (the only one)
    d = one(bmi(odr_hz=100, accel_odr_hz=12.5))
    assert d.odr_hz == 100.0 and d.accel_odr_hz == 12.5
    assert d.gyro_bandwidth_code() == 0x07  # 100 Hz ODR, 32 Hz filter (the widest)


def test_gyro_odr_hz_is_no_longer_a_field() -> None:
    # renamed odr_hz (the published rate): the old name is an unknown key, not silently ignored
    msg = only_error(bmi(gyro_odr_hz=400))
    assert "gyro_odr_hz" in msg


def test_die_buses_are_accel_then_gyro() -> None:
    d = one(bmi())
    buses = d.die_buses()
    assert len(buses) == 2
    assert buses[0] is d.bus and buses[1] is d.gyro_bus
    assert [b.slot for b in buses] == [("/dev/spidev1.0",), ("/dev/spidev1.1",)]


def test_die_buses_on_i2c() -> None:
    d = one(bmi(ACC_I2C, GYR_I2C))
    assert [b.slot for b in d.die_buses()] == [("/dev/i2c-1", "0x18"), ("/dev/i2c-1", "0x68")]
    assert all(isinstance(b, I2cBus) for b in d.die_buses())


@pytest.mark.parametrize("code", sorted(BANDWIDTH_TABLE))
def test_gyro_bandwidth_code_for_every_mode(code: int) -> None:
    odr, bw = BANDWIDTH_TABLE[code]
    d = one(bmi(odr_hz=odr, gyro_filter_hz=bw))
    assert d.gyro_filter_hz == bw
    assert d.gyro_bandwidth_code() == code


@pytest.mark.parametrize(
    ("odr", "widest", "code"),
    [(2000, 532, 0x00), (1000, 116, 0x02), (400, 47, 0x03), (200, 64, 0x06), (100, 32, 0x07)],
)
def test_default_gyro_filter_is_the_widest(odr: int, widest: int, code: int) -> None:
    d = one(bmi(odr_hz=odr))
    assert d.gyro_filter_hz == widest
    assert d.gyro_bandwidth_code() == code


# --- ranges, rates, filters ----------------------------------------------------------------------


@pytest.mark.parametrize("g", [3, 6, 12, 24])
def test_every_accel_range_accepted(g: int) -> None:
    assert one(bmi(accel_range_g=g)).accel_range_g == g


@pytest.mark.parametrize("g", [2, 4, 8, 16])
def test_other_accel_ranges_rejected(g: int) -> None:
    msg = only_error(bmi(accel_range_g=g))
    assert "device[0] 'bmi0'" in msg
    assert f"accel_range_g = {g}" in msg
    assert all(str(v) in msg for v in (3, 6, 12, 24)), msg


@pytest.mark.parametrize("dps", [125, 250, 500, 1000, 2000])
def test_every_gyro_range_accepted(dps: int) -> None:
    assert one(bmi(gyro_range_dps=dps)).gyro_range_dps == dps


def test_gyro_range_300_rejected() -> None:
    msg = only_error(bmi(gyro_range_dps=300))
    assert "gyro_range_dps = 300" in msg
    assert all(str(v) in msg for v in (125, 250, 500, 1000, 2000)), msg


@pytest.mark.parametrize("odr", ACCEL_ODRS)
def test_every_accel_odr_accepted(odr: float) -> None:
    assert one(bmi(accel_odr_hz=odr)).accel_odr_hz == float(odr)


@pytest.mark.parametrize("odr", [10, 1000, 3200, 1600.5, 0])
def test_other_accel_odrs_rejected_listing_the_allowed(odr: float) -> None:
    msg = only_error(bmi(accel_odr_hz=odr))
    assert "accel_odr_hz" in msg
    assert f"no output data rate {odr:g} Hz" in msg
    allowed = re.findall(r"\d+(?:\.\d+)?", msg.split("use", 1)[1])
    assert allowed == ["12.5", "25", "50", "100", "200", "400", "800", "1600"]


@pytest.mark.parametrize("flt", ["normal", "osr2", "osr4"])
def test_every_accel_filter_accepted(flt: str) -> None:
    assert one(bmi(accel_filter=flt)).accel_filter == flt


def test_unknown_accel_filter_rejected() -> None:
    msg = only_error(bmi(accel_filter="osr8"))
    assert "accel_filter" in msg and "'osr8'" in msg
    assert all(w in msg for w in ("normal", "osr2", "osr4")), msg


@pytest.mark.parametrize("odr", [100, 200, 400, 1000, 2000])
def test_every_gyro_odr_accepted(odr: int) -> None:
    assert one(bmi(odr_hz=odr)).odr_hz == odr


@pytest.mark.parametrize("odr", [50, 800, 1600, 4000])
def test_other_gyro_odrs_rejected(odr: int) -> None:
    msg = only_error(bmi(odr_hz=odr))
    assert f"odr_hz = {odr}" in msg
    assert all(str(v) in msg for v in (100, 200, 400, 1000, 2000)), msg


@pytest.mark.parametrize(
    ("odr", "bad", "listed"),
    [
        (2000, 116, "532 or 230"),
        (1000, 532, "116"),
        (400, 64, "47"),
        (200, 12, "23 or 64"),
        (100, 23, "12 or 32"),
    ],
)
def test_gyro_filter_not_available_at_odr_rejected(odr: int, bad: int, listed: str) -> None:
    msg = only_error(bmi(odr_hz=odr, gyro_filter_hz=bad))
    assert "device[0] 'bmi0' (bmi088)" in msg
    assert f"gyro_filter_hz = {bad}" in msg
    assert f"odr_hz = {odr}" in msg
    assert f"filters at {listed} Hz" in msg  # the fix: the values allowed at this rate


# --- SPI -----------------------------------------------------------------------------------------


def test_spi_at_10mhz_accepted() -> None:
    d = one(bmi({**ACC_SPI, "speed_hz": 10_000_000}))
    assert isinstance(d.bus, SpiBus) and d.bus.speed_hz == 10_000_000


@pytest.mark.parametrize("speed_hz", [10_000_001, 20_000_000])
def test_spi_faster_than_10mhz_rejected(speed_hz: int) -> None:
    msg = only_error(bmi({**ACC_SPI, "speed_hz": speed_hz}))
    assert "10 MHz" in msg and "bus.speed_hz" in msg
    assert f"{speed_hz / 1e6:g} MHz" in msg


def test_sim_spi_faster_than_10mhz_rejected() -> None:
    sim = {"kind": "sim", "transport": "spi", "speed_hz": 12_000_000}
    msg = only_error(bmi(sim, {**sim, "cs": 1}))
    assert "10 MHz" in msg and "bus.speed_hz is 12 MHz" in msg


def test_sim_spi_default_clock_accepted() -> None:
    d = one(bmi({"kind": "sim", "transport": "spi"}, {"kind": "sim", "transport": "spi", "cs": 1}))
    assert isinstance(d.bus, SimBus) and d.bus.clock_hz == 10_000_000


def test_gyro_spi_faster_than_10mhz_rejected() -> None:
    msg = only_error(bmi(ACC_SPI, {**GYR_SPI, "speed_hz": 20_000_000}))
    assert "gyro_bus.speed_hz" in msg and "10 MHz" in msg


# --- I2C bandwidth -------------------------------------------------------------------------------


def test_full_rates_fit_400khz_i2c() -> None:
    assert i2c_need_bps(1600, 2000) == pytest.approx(261_000)  # < 400 kbit/s
    d = one(bmi(i2c(0x18, 400_000), i2c(0x68)))
    assert (d.accel_odr_hz, d.odr_hz) == (1600.0, 2000)


def test_full_rates_rejected_on_100khz_i2c_naming_speed_and_fix() -> None:
    msg = only_error(bmi(i2c(0x18, 100_000), i2c(0x68)))
    assert "device[0] 'bmi0' (bmi088)" in msg
    assert "bus.speed_hz" in msg
    assert "261 kbit/s" in msg  # (1600*7 + 2000*6) * 9 * 1.25 = 261 000
    assert "100 kHz" in msg
    assert "lower the rates" in msg and "400 kHz" in msg


@pytest.mark.parametrize(
    ("accel", "gyro", "kbps", "fits"),
    [
        (400, 1000, 99, True),  # (2800 + 6000) * 11.25 = 99 000
        (800, 400, 90, True),  # (5600 + 2400) * 11.25 = 90 000
        (12.5, 1000, 68, True),  # (87.5 + 6000) * 11.25 = 68 484
        (800, 1000, 130, False),  # (5600 + 6000) * 11.25 = 130 500
        (1600, 100, 133, False),  # (11200 + 600) * 11.25 = 132 750
        (100, 2000, 143, False),  # (700 + 12000) * 11.25 = 142 875
    ],
)
def test_100khz_i2c_boundary(accel: float, gyro: int, kbps: int, fits: bool) -> None:
    assert round(i2c_need_bps(accel, gyro) / 1e3) == kbps
    dev = bmi(i2c(0x18, 100_000), i2c(0x68), accel_odr_hz=accel, odr_hz=gyro)
    if fits:
        d = one(dev)
        assert (d.accel_odr_hz, d.odr_hz) == (accel, gyro)
    else:
        msg = only_error(dev)
        assert f"accel {accel:g} Hz + gyro {gyro} Hz" in msg and f"needs about {kbps} kbit/s" in msg
        assert "bus.speed_hz" in msg and "100 kHz" in msg


def test_sim_i2c_default_400khz_accepted_and_100khz_rejected() -> None:
    sim = {"kind": "sim", "transport": "i2c", "address": 0x18}
    d = one(bmi(sim, {**sim, "address": 0x68}))
    assert isinstance(d.bus, SimBus) and d.bus.clock_hz == 400_000
    msg = only_error(bmi({**sim, "speed_hz": 100_000}, {**sim, "address": 0x68}))
    assert "bus.speed_hz" in msg and "100 kHz" in msg


def test_i2c_speed_above_10mhz_is_not_an_spi_error() -> None:
    # the 10 MHz limit is the SPI one: a (fictional) fast I2C clock is only checked for bandwidth
    d = one(bmi(i2c(0x18, 20_000_000), i2c(0x68)))
    assert isinstance(d.bus, I2cBus)


# --- two dies on one bus -------------------------------------------------------------------------


def test_gyro_bus_is_required() -> None:
    dev = bmi()
    del dev["gyro_bus"]
    msg = only_error(dev)
    assert "gyro_bus" in msg and "required" in msg


def test_same_spi_chip_select_rejected() -> None:
    msg = only_error(bmi(ACC_SPI, {**GYR_SPI, "path": "/dev/spidev1.0"}))
    assert "gyro_bus" in msg
    assert "own chip select" in msg and "/dev/spidev1.0" in msg


def test_gyro_on_another_spi_bus_rejected() -> None:
    msg = only_error(bmi(ACC_SPI, {**GYR_SPI, "path": "/dev/spidev0.1"}))
    assert "gyro_bus" in msg
    assert "accel die's bus (spi /dev/spidev1)" in msg
    assert "own chip select (SPI) or address (I2C)" in msg


def test_same_i2c_address_rejected() -> None:
    msg = only_error(bmi(i2c(0x18), i2c(0x18)))
    assert "gyro_bus" in msg
    assert "own address" in msg and "0x18" in msg


def test_gyro_on_another_i2c_bus_rejected() -> None:
    msg = only_error(bmi(i2c(0x18), i2c(0x68, bus=0)))
    assert "gyro_bus" in msg and "accel die's bus (i2c /dev/i2c-1)" in msg


def test_i2c_bus_by_number_and_by_path_is_one_bus() -> None:
    d = one(bmi(i2c(0x18), {"kind": "i2c", "bus": "/dev/i2c-1", "address": 0x69}))
    assert d.bus.key == d.gyro_bus.key == "/dev/i2c-1"


def test_mixed_bus_kinds_rejected() -> None:
    msg = only_error(bmi(ACC_SPI, GYR_I2C))
    assert "gyro_bus" in msg and "accel die's bus (spi /dev/spidev1)" in msg


def test_sim_spi_dies_on_two_chip_selects_accepted() -> None:
    d = one(bmi({"kind": "sim", "transport": "spi"}, {"kind": "sim", "transport": "spi", "cs": 1}))
    assert [b.slot for b in d.die_buses()] == [("sim:sim0", "cs0"), ("sim:sim0", "cs1")]


def test_sim_spi_dies_on_one_chip_select_rejected() -> None:
    # different addresses do not matter on SPI: the chip select is the slot
    acc = {"kind": "sim", "transport": "spi", "cs": 2, "address": 0x18}
    msg = only_error(bmi(acc, {**acc, "address": 0x68}))
    assert "gyro_bus" in msg and "own chip select" in msg and "cs2" in msg


def test_sim_i2c_dies_on_two_addresses_accepted() -> None:
    acc = {"kind": "sim", "transport": "i2c", "address": 0x18}
    d = one(bmi(acc, {**acc, "address": 0x68}))
    assert [b.slot for b in d.die_buses()] == [("sim:sim0", "0x18"), ("sim:sim0", "0x68")]


def test_sim_i2c_dies_on_one_address_rejected() -> None:
    # different chip selects do not matter on I2C: the address is the slot
    acc = {"kind": "sim", "transport": "i2c", "address": 0x18, "cs": 0}
    msg = only_error(bmi(acc, {**acc, "cs": 1}))
    assert "gyro_bus" in msg and "0x18" in msg


def test_sim_i2c_same_address_message_says_address() -> None:
    acc = {"kind": "sim", "transport": "i2c", "address": 0x18}
    msg = only_error(bmi(acc, dict(acc)))
    assert "own address" in msg


def test_sim_dies_on_different_transports_rejected() -> None:
    msg = only_error(bmi({"kind": "sim", "transport": "spi"}, {"kind": "sim", "transport": "i2c"}))
    assert "gyro_bus" in msg and "same transport" in msg


def test_sim_dies_on_different_sim_buses_rejected() -> None:
    msg = only_error(bmi({"kind": "sim", "bus": "a", "address": 0x18}, {"kind": "sim", "bus": "b"}))
    assert "gyro_bus" in msg and "accel die's bus (sim sim:a)" in msg


def test_sim_bus_gets_default_sim_settings() -> None:
    d = one(bmi({"kind": "sim", "address": 0x18}, {"kind": "sim", "address": 0x68}))
    assert d.sim is not None and d.sim.seed == 0


def test_sim_table_on_real_bus_rejected() -> None:
    msg = only_error(bmi(ACC_I2C, GYR_I2C, sim={}))
    assert "[device.sim]" in msg and 'bus.kind = "sim"' in msg


# --- serial --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("acc", "gyr"),
    [
        ({"kind": "serial", "port": "/dev/ttyUSB0"}, {"kind": "serial", "port": "/dev/ttyUSB0"}),
        ({"kind": "serial", "port": "/dev/ttyUSB0"}, {"kind": "serial", "port": "/dev/ttyUSB1"}),
        ({"kind": "serial", "port": "/dev/ttyUSB0"}, GYR_I2C),
    ],
    ids=["same-port", "two-ports", "serial-and-i2c"],
)
def test_serial_bus_rejected(acc: dict[str, Any], gyr: dict[str, Any]) -> None:
    msg = only_error(bmi(acc, gyr))
    assert "device[0] 'bmi0'" in msg
    assert "cannot be on a serial bus" in msg and "spi, i2c" in msg


def test_serial_bus_rejected_saying_the_transports() -> None:
    port = {"kind": "serial", "port": "/dev/ttyUSB0"}
    msg = only_error(bmi(port, dict(port)))
    assert "serial" in msg and "spi" in msg and "i2c" in msg


# --- slots shared between devices ----------------------------------------------------------------


def test_gyro_die_and_mpu6050_on_one_address_rejected() -> None:
    mpu = {"name": "mpu0", "chip": "mpu6050", "bus": i2c(0x68)}
    msg = only_error(bmi(ACC_I2C, GYR_I2C), mpu)
    assert msg.startswith("device[1] 'mpu0'")
    assert "/dev/i2c-1 0x68" in msg and "already taken by 'bmi0'" in msg


def test_mpu6050_first_then_gyro_die_on_its_address_rejected() -> None:
    mpu = {"name": "mpu0", "chip": "mpu6050", "bus": i2c(0x68)}
    msg = only_error(mpu, bmi(ACC_I2C, GYR_I2C))
    assert msg.startswith("device[1] 'bmi0'")
    assert "/dev/i2c-1 0x68" in msg and "already taken by 'mpu0'" in msg


def test_accel_die_and_mpu6050_on_one_address_rejected() -> None:
    mpu = {"name": "mpu0", "chip": "mpu6050", "bus": i2c(0x18)}
    msg = only_error(bmi(ACC_I2C, GYR_I2C), mpu)
    assert "/dev/i2c-1 0x18" in msg and "already taken by 'bmi0'" in msg


def test_mpu6050_on_another_address_accepted() -> None:
    mpu = {"name": "mpu0", "chip": "mpu6050", "bus": i2c(0x69)}
    cfg = accept(bmi(ACC_I2C, GYR_I2C), mpu)
    assert [d.name for d in cfg.device] == ["bmi0", "mpu0"]


def test_mpu6050_same_address_on_another_i2c_bus_accepted() -> None:
    mpu = {"name": "mpu0", "chip": "mpu6050", "bus": i2c(0x68, bus=0)}
    assert len(accept(bmi(ACC_I2C, GYR_I2C), mpu).device) == 2


def test_two_bmi088_sharing_a_chip_select_rejected() -> None:
    second = bmi(
        {**ACC_SPI, "path": "/dev/spidev1.2"}, {**GYR_SPI, "path": "/dev/spidev1.0"}, name="bmi1"
    )
    msg = only_error(bmi(), second)
    assert msg.startswith("device[1] 'bmi1'")
    assert "/dev/spidev1.0 is already taken by 'bmi0'" in msg


def test_two_bmi088_on_four_chip_selects_accepted() -> None:
    second = bmi(
        {**ACC_SPI, "path": "/dev/spidev1.2"}, {**GYR_SPI, "path": "/dev/spidev1.3"}, name="bmi1"
    )
    assert len(accept(bmi(), second).device) == 2


def test_icm_on_a_bmi088_gyro_chip_select_rejected() -> None:
    icm = {"name": "icm0", "chip": "icm42688p", "bus": {**GYR_SPI}}
    msg = only_error(bmi(), icm)
    assert "/dev/spidev1.1 is already taken by 'bmi0'" in msg


def test_sim_gyro_die_and_sim_mpu6050_share_an_address_rejected() -> None:
    acc = {"kind": "sim", "address": 0x18}
    mpu = {"name": "mpu0", "chip": "mpu6050", "bus": {"kind": "sim"}}  # default 0x68
    msg = only_error(bmi(acc, {"kind": "sim", "address": 0x68}), mpu)
    assert "sim:sim0 0x68 is already taken by 'bmi0'" in msg
