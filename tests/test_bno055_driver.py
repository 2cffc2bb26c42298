"""The BNO055 driver: a burst decoded with the data sheet's scales, what each mode publishes,
repeated and skipped samples counted exactly, identity checks, register settings composed from
the map's fields, and a bad offsets file that does not stop the device."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from imud.channels import Channel
from imud.chips.bno055.config import Bno055Config
from imud.chips.bno055.driver import Bno055Driver, config_plan
from imud.clock import VirtualClock
from imud.config import parse_config
from imud.errors import RegisterMismatch
from imud.pipeline import Pipeline, to_si
from imud.timestamps import SampleClock
from tests.helpers import make_rig

# One burst from 0x08 (data sheet §4.2 map): ACC, MAG, GYR, EUL, QUA (w x y z), LIA, GRV as int16
# LE, then TEMP (int8) and CALIB_STAT
WORDS = [
    100, -200, 981,  # ACC: 1 m/s^2 = 100 LSB (Table 3-17) -> 1.00, -2.00, 9.81 m/s^2
    16, -32, 800,  # MAG: 1 uT = 16 LSB -> 1, -2, 50 uT
    900, -450, 0,  # GYR: 1 rad/s = 900 LSB (Table 3-22) -> 1.0, -0.5, 0 rad/s
    0, 0, 0,  # EUL (not published)
    11585, 0, 0, 11585,  # QUA: 1 = 2^14 LSB (Table 3-31) -> 0.7071, 0, 0, 0.7071 (90 deg about z)
    10, 0, -5,  # LIA: 100 LSB per m/s^2 (Table 3-33) -> 0.10, 0, -0.05
    0, 0, 981,  # GRV: 100 LSB per m/s^2 (Table 3-35) -> 0, 0, 9.81
]  # fmt: skip
TEMP = bytes([0xE7])  # int8 -25: 1 deg C = 1 LSB (Table 3-37)
CALIB = bytes([0b11_10_01_00])  # SYS 3, GYR 2, ACC 1, MAG 0
BURST = np.asarray(WORDS, dtype="<i2").tobytes() + TEMP + CALIB


def config(**kw: Any) -> Bno055Config:
    d = {"name": "b0", "chip": "bno055", "bus": {"kind": "sim", "address": 0x28}, **kw}
    cfg: Bno055Config = parse_config({"device": [d]}).device[0]
    return cfg


class Burst:
    """A register device that answers the data burst with fixed bytes."""

    address = 0x28

    def __init__(self, data: bytes) -> None:
        self.data = data

    def read(self, register: int, length: int) -> bytes:
        assert (register, length) == (0x08, 46)
        return self.data

    def read_u8(self, register: int) -> int:
        return 0x0C if register == 0x3D else 0

    def write_u8(self, register: int, value: int) -> None:
        pass


def si_of(mode: str, data: bytes) -> tuple[dict[Channel, np.ndarray], Any]:
    drv = Bno055Driver(config(mode=mode), Burst(data), VirtualClock())
    raw = drv.read()
    return to_si(raw), raw


def test_a_burst_decodes_to_si_units_with_the_datasheet_scales() -> None:
    si, raw = si_of("ndof", BURST)
    assert raw.n == 1
    np.testing.assert_allclose(si[Channel.ACCEL][0], [1.00, -2.00, 9.81])
    np.testing.assert_allclose(si[Channel.MAG][0], [1e-6, -2e-6, 50e-6])
    np.testing.assert_allclose(si[Channel.GYRO][0], [1.0, -0.5, 0.0])
    np.testing.assert_allclose(si[Channel.ORIENTATION][0], [0.70709, 0, 0, 0.70709], atol=1e-4)
    np.testing.assert_allclose(si[Channel.LINEAR_ACCEL][0], [0.10, 0.0, -0.05])
    np.testing.assert_allclose(si[Channel.GRAVITY][0], [0.0, 0.0, 9.81])
    assert si[Channel.TEMPERATURE][0] == -25.0


def test_the_calibration_status_is_decoded() -> None:
    drv = Bno055Driver(config(), Burst(BURST), VirtualClock())
    drv.read()
    st = drv.chip_status()
    assert st["calibration"] == {"sys": 3, "gyro": 2, "accel": 1, "mag": 0}
    assert st["fully_calibrated"] is False


def test_each_mode_publishes_what_it_gives() -> None:
    ndof, _ = si_of("ndof", BURST)
    imu, _ = si_of("imu", BURST)
    amg, _ = si_of("amg", BURST)
    fusion = {Channel.ORIENTATION, Channel.LINEAR_ACCEL, Channel.GRAVITY}
    basic = {Channel.ACCEL, Channel.GYRO, Channel.TEMPERATURE}
    assert set(ndof) == basic | fusion | {Channel.MAG}
    assert set(imu) == basic | fusion  # accel + gyro fusion: no magnetometer
    assert set(amg) == basic | {Channel.MAG}  # raw sensors: no fusion outputs


def test_raw_gyro_counts_scale_with_the_range_in_amg_mode() -> None:
    """Firmware 3.11 outside fusion: the range (2000 deg/s after reset, Table 3-4) over 2^15,
    as Linux's bno055.c reads it: 16384 counts = 1000 deg/s."""
    words = list(WORDS)
    words[6] = 16384
    si, _ = si_of("amg", np.asarray(words, dtype="<i2").tobytes() + TEMP + CALIB)
    assert si[Channel.GYRO][0][0] == pytest.approx(math.radians(1000.0))


def test_a_quaternion_far_from_unit_length_is_marked_invalid() -> None:
    words = list(WORDS)
    words[12:16] = [0, 0, 0, 100]  # |q| = 0.006: a garbled read, not an orientation
    si, _ = si_of("ndof", np.asarray(words, dtype="<i2").tobytes() + TEMP + CALIB)
    assert np.isnan(si[Channel.ORIENTATION][0]).all()
    assert not np.isnan(si[Channel.ACCEL][0]).any()


def test_an_all_zero_burst_is_no_sample() -> None:
    drv = Bno055Driver(config(), Burst(bytes(46)), VirtualClock())
    assert drv.read().n == 0
    assert drv.chip_status()["empty_reads"] == 1


# --- repeated and skipped samples --------------------------------------------------------------
class GridChip:
    """A chip whose data registers change every `period_ns` (sample k from phase + k period);
    the sample index is written into the accel x word, so every sample reads differently."""

    address = 0x28

    def __init__(self, clock: VirtualClock, period_ns: int, phase_ns: int) -> None:
        self.clock, self.period, self.phase = clock, period_ns, phase_ns
        self.reads: list[int] = []  # the index each bus read saw

    def index(self) -> int:
        return (self.clock.now_ns() - self.phase) // self.period

    def read(self, register: int, length: int) -> bytes:
        k = self.index()
        self.reads.append(k)
        words = list(WORDS)
        words[0] = k % 30000
        return np.asarray(words, dtype="<i2").tobytes() + TEMP + bytes([0])

    def read_u8(self, register: int) -> int:
        return 0x0C

    def write_u8(self, register: int, value: int) -> None:
        pass


def test_repeats_and_a_skip_are_counted_exactly() -> None:
    """Reads every 4 ms for 1 s, a 25 ms stall, then every 4 ms again, on a 10 ms grid: each
    new sample is published once, every other poll is a repeat (read or skipped), and the stall
    is the one gap: the grid has the phase pinned by then, so it counts the gap exactly (no
    suspected miss) and the pipeline reports exactly the samples it skipped."""
    clock = VirtualClock()
    chip = GridChip(clock, 10_000_000, 3_000_000)
    drv = Bno055Driver(config(), chip, clock)
    pipe = Pipeline(SampleClock(drv.nominal_period_ns), None, 0)
    polls: list[tuple[int, int]] = []  # (index at the poll, n)
    lost = 0
    flagged = 0
    for i in range(376):
        clock.advance(25_000_000 if i == 250 else 4_000_000)
        k = chip.index()
        raw = drv.read()
        flagged += int(raw.timing.resync)  # type: ignore[union-attr]
        lost += pipe.process(raw).lost_before
        polls.append((k, raw.n))
    ks = [k for k, _ in polls]
    new = [i for i, (k, n) in enumerate(polls) if n]
    # a batch exactly when the chip's index moved on, never otherwise
    assert new == [0] + [i for i in range(1, len(ks)) if ks[i] != ks[i - 1]]
    st = drv.chip_status()
    assert st["repeated_reads"] + st["skipped_polls"] == len(polls) - len(new)
    assert st["repeated_reads"] == len(chip.reads) - len(set(chip.reads))
    # the stall is the only read whose count exceeds 1, and the only batch that says so
    jump = ks[250] - ks[249]
    assert jump >= 3
    assert st["suspected_missed"] == 0 and flagged == 1
    assert lost == jump - 1


def test_a_chip_that_stops_producing_is_reinitialised() -> None:
    clock = VirtualClock()
    drv = Bno055Driver(config(), Burst(BURST), clock)
    drv.read()
    with pytest.raises(RegisterMismatch, match=r"OPR_MODE reads 0x0c|fusion stalled"):
        for _ in range(100):
            clock.advance(5_000_000)
            drv.read()


# --- identity and settings ---------------------------------------------------------------------
@pytest.mark.parametrize(
    ("reg", "value", "message"),
    [
        (0x00, 0x68, "CHIP_ID (0x00) reads 0x68, expected 0xa0"),
        (0x01, 0x00, "ACC_ID (0x01) reads 0x00, expected 0xfb"),
        (0x02, 0x00, "MAG_ID (0x02) reads 0x00, expected 0x32"),
        (0x03, 0x00, "GYR_ID (0x03) reads 0x00, expected 0x0f"),
    ],
)
def test_a_wrong_chip_or_sub_chip_id_fails_start_naming_it(
    reg: int, value: int, message: str
) -> None:
    rig = make_rig({"chip": "bno055", "bus": {"kind": "sim", "address": 0x28}})
    rig.sim.p0[reg] = value
    rig.run(0.2)
    assert rig.runner.state == "error"
    assert message in (rig.runner.last_error or "")


@pytest.mark.parametrize(
    ("remap", "config_byte", "sign_byte", "source"),
    [
        ("+x+y+z", 0x24, 0x00, "DS §3.4: default P1"),
        ("+y+x-z", 0x21, 0x01, "Bosch forum: P5 = 0x21, 0x01"),
        ("-x+y-z", 0x24, 0x05, "Bosch forum: P7 = 0x24, 0x05"),
    ],
)
def test_the_axis_remap_bytes(remap: str, config_byte: int, sign_byte: int, source: str) -> None:
    plan = {s.register: s for s in config_plan(config(axis_remap=remap))}
    assert plan[0x41].set_bits == config_byte and plan[0x41].mask == 0x3F, source
    assert plan[0x42].set_bits == sign_byte and plan[0x42].mask == 0x07, source


def test_unit_sel_is_what_linux_writes() -> None:
    """m/s^2, rad/s, deg C, Android orientation: 0x82 (Linux bno055.c writes ANDROID | GYR_RPS)."""
    plan = {s.register: s for s in config_plan(config())}
    assert plan[0x3B].set_bits == 0x82 and plan[0x3B].clear_bits == 0x11


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"odr_hz": 50}, "fixed 100 Hz"),
        ({"axis_remap": "+y+x+z"}, "mirror image"),
        ({"axis_remap": "+x+x+z"}, "twice"),
        ({"bus": {"kind": "sim", "transport": "serial", "baud": 9600}}, "115200"),
        ({"bus": {"kind": "i2c", "bus": 1, "address": 0x68}}, "0x28"),
        # (3 + 46 bytes) * 9 bits * 100 Hz * 1.25 = 55.1 kbit/s: Adafruit's 10 kHz fix is too slow
        ({"bus": {"kind": "i2c", "bus": 1, "address": 0x28, "speed_hz": 10_000}}, "55.1 kbit/s"),
    ],
)
def test_the_config_refuses_what_the_chip_cannot_do(fields: dict[str, Any], message: str) -> None:
    from imud.errors import ConfigError

    with pytest.raises(ConfigError, match=message):
        config(**fields)


def test_a_bad_offsets_file_is_reported_and_the_device_runs(tmp_path: Path) -> None:
    bad = tmp_path / "b0.toml"
    bad.write_text("this is not toml [")
    rig = make_rig({"chip": "bno055", "bus": {"kind": "sim"}, "offsets_file": str(bad)})
    rig.run(1.5)
    st = rig.driver.chip_status()
    assert st["offsets_restored"].startswith(f"error: {bad}: not valid TOML")
    assert rig.runner.state == "running" and rig.runner.samples > 50
