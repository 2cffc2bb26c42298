"""A chip that resets itself (`[device.sim.faults] resets`, a brown-out) and a chip whose identity
register reads garbage at start-up (`garbage_identity_s`), through each chip's driver and the
device runner at virtual time, next to a healthy device on the same bus (no scheduler involved).

What must hold (issue 10): the reset is found within 100 ms of it (the register re-check's
sentinel, or the chip's own sign of a reset), counted in status `resets` with a message saying
so, and the device streams again within 1 s of the chip answering again; the samples lost across
it are one sequence gap equal to `lost_samples`, and that gap is the number of sample slots the
chip's true clock had between the last sample published before it and the first after (to
within one: the restarted chip's sample grid has a new phase); the neighbour on the bus loses
nothing. A start-up with garbage in the identity register fails naming the register, the byte
read and the byte expected, and the device runs once the window is over."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from imud.clock import VirtualClock
from imud.config import parse_config
from imud.device import DeviceRunner
from imud.sim.filters import FilteredChip
from imud.sim.i2c import SimI2CBus
from imud.wire import decode
from imud.wiring import connect
from tests.helpers import concat, match_truth
from tests.test_stim300_sim import rig as stim_rig
from tests.test_stim300_sim import run as stim_run

I2C = {"kind": "sim", "bus": "i2c0"}
SPI = {"kind": "sim", "bus": "spi0", "transport": "spi"}
RESET_AT_S = 1.5
# How long each chip is silent after a reset, from its datasheet: the fault ends then, and the
# device must stream within 1 s of it. BNO055 power-on reset 650 ms; ADIS16465 software reset
# 198 ms; MPU6050, ICM-42688-P and BMI088 answer within the BMI088 gyro's 30 ms.
SILENT_S = {"bno055": 0.65, "adis16465": 0.198}
DEVICES: dict[str, dict[str, Any]] = {
    "mpu6050": {"chip": "mpu6050", "odr_hz": 1000, "bus": {**I2C, "address": 0x68}},
    "icm42688p": {"chip": "icm42688p", "odr_hz": 8000, "bus": {**SPI, "cs": 0}},
    "bmi088": {"chip": "bmi088", "bus": {**I2C, "address": 0x18},
               "gyro_bus": {**I2C, "address": 0x68}},
    "adis16465": {"chip": "adis16465", "model": 3, "bus": {**SPI, "cs": 0}},
    "bno055": {"chip": "bno055", "bus": {**I2C, "address": 0x28}, "save_offsets": False},
}  # fmt: skip
# the healthy neighbour: an MPU6050 on the same I2C bus, or an ICM-42688-P on the next chip select
NEIGHBOUR_I2C = {"chip": "mpu6050", "odr_hz": 1000, "bus": {**I2C, "address": 0x69}}
NEIGHBOUR_SPI = {"chip": "icm42688p", "odr_hz": 1000, "bus": {**SPI, "cs": 1}}
# what each chip's driver names when the identity register reads garbage
IDENTITY = {
    "mpu6050": r"WHO_AM_I \(0x75\) at address 0x68 reads 0x[0-9a-f]{2}, expected 0x68",
    "icm42688p": r"WHO_AM_I \(0x75\) reads 0x[0-9a-f]{2}, expected 0x47",
    "bmi088": r"accel die: CHIP_ID \(0x00\) reads 0x[0-9a-f]{2}, expected 0x1e",
    "adis16465": r"PROD_ID \(0x72\) reads 0x[0-9a-f]{4}",
    "bno055": r"CHIP_ID \(0x00\) reads 0x[0-9a-f]{2}, expected 0xa0",
}


@dataclass
class Bus:
    """Runners sharing one virtual clock (and one simulated I2C bus), each stepped when due, as
    a bus worker steps its devices."""

    clock: VirtualClock
    runners: list[DeviceRunner]
    sims: list[Any]
    out: list[list[bytes]]
    truth: list[list[bytes]]
    t0: int
    detected_ns: list[int] = field(default_factory=list)
    detected: list[str] = field(default_factory=list)  # what the runner said then

    def run(self, seconds: float) -> None:
        end = self.clock.now_ns() + int(seconds * 1e9)
        while self.clock.now_ns() < end:
            r = min(self.runners, key=lambda r: r.next_due_ns)
            self.clock.advance(max(0, r.next_due_ns - self.clock.now_ns()))
            before, now = r.resets, self.clock.now_ns()
            r.step()
            if r.resets > before:
                self.detected_ns.append(now)
                self.detected.append(str(r.last_error))


def _bus(device: dict[str, Any], faults: dict[str, Any], tmp: Path) -> Bus:
    neighbour = NEIGHBOUR_SPI if device["bus"].get("transport") == "spi" else NEIGHBOUR_I2C
    sim = {"seed": 7, "truth": True, "clock_error": 0.004, "errors": {"ideal": True},
           "motion": {"kind": "tumble", "rate_dps": [10.0, 20.0, 30.0]}}  # fmt: skip
    dut = {"name": "dut", **device, "sim": {**sim, "faults": faults}}
    if device["chip"] == "bno055":
        dut["offsets_file"] = str(tmp / "offsets.toml")
    cfg = parse_config({"device": [dut, {"name": "nb", **neighbour, "sim": {**sim, "seed": 8}}]})
    clock = VirtualClock()
    bus = Bus(clock, [], [], [], [], clock.now_ns())
    i2c = SimI2CBus()
    for d in cfg.device:
        driver, chip = connect(d, i2c, clock)
        out: list[bytes] = []
        truth: list[bytes] = []
        runner = DeviceRunner(d, driver, None, out.append, 0, sim=chip,
                              publish_truth=truth.append, now_ns=clock.now_ns)  # fmt: skip
        bus.runners.append(runner)
        bus.sims.append(chip)
        bus.out.append(out)
        bus.truth.append(truth)
    return bus


def _gap_matches_the_true_clock(
    out: list[bytes], truth: list[bytes], lost: int, undeclared_ns: float = 0.0,
    within: float = 1.0,
) -> int:  # fmt: skip
    """The one seq gap: equal to `lost`, and to the slots of the chip's true sample clock
    between the samples either side of it, to within one (the restarted grid has a new phase).
    `undeclared_ns`: filter delay the simulator models and the driver does not declare yet (a
    true instant is the motion's; a stamp is moved back only by the declared delay). Returns
    the gap's index."""
    m = concat([decode(b) for b in out])
    gaps = np.diff(m["seq"]) - 1
    assert np.all(gaps >= 0) and np.all(np.diff(m["t_ns"]) > 0)
    assert int(gaps.sum()) == lost > 0
    j = int(np.argmax(gaps))
    assert gaps[j] == lost  # one gap: every sample lost is lost across the reset
    t = concat([decode(b) for b in truth])
    i = match_truth({**m, "t_ns": m["t_ns"] - round(undeclared_ns)}, t)
    period = float(np.median(np.diff(t["t_ns"])))  # the true clock, off by clock_error
    slots = (t["t_ns"][i[j + 1]] - t["t_ns"][i[j]]) / period - 1
    assert abs(gaps[j] - slots) < within, (gaps[j], slots)
    return j


def _undeclared_ns(sim: Any, driver: Any) -> float:
    die = sim.dies[-1]
    return die.group_delay_ns() - driver.group_delay_ns if isinstance(die, FilteredChip) else 0.0


@pytest.mark.parametrize("chip", list(DEVICES))
def test_a_chip_that_resets_itself_is_found_within_100_ms_and_streams_again(
    chip: str, tmp_path: Path
) -> None:
    bus = _bus(DEVICES[chip], {"resets": [{"at_s": RESET_AT_S}]}, tmp_path)
    bus.run(RESET_AT_S + 2.0)
    dut, nb = bus.runners
    reset_ns = bus.t0 + int(RESET_AT_S * 1e9)
    # the simulator reset every die, once
    assert [d.self_resets for d in bus.sims[0].dies] == [1] * len(bus.sims[0].dies)
    # found once, within 100 ms, and said so
    assert len(bus.detected_ns) == 1
    assert 0 <= bus.detected_ns[0] - reset_ns <= 100_000_000, bus.detected_ns[0] - reset_ns
    st = dut.status().to_json()
    assert st["resets"] == 1 and st["state"] == "running"
    assert "reset" in bus.detected[0], bus.detected
    # streams again within 1 s of the chip answering again
    undeclared = _undeclared_ns(bus.sims[0], bus.runners[0].driver)
    j = _gap_matches_the_true_clock(bus.out[0], bus.truth[0], st["lost_samples"], undeclared)
    m = concat([decode(b) for b in bus.out[0]])
    assert m["t_ns"][j] < reset_ns < m["t_ns"][j + 1]
    back_ns = reset_ns + int(SILENT_S.get(chip, 0.03) * 1e9)
    assert m["t_ns"][j + 1] < back_ns + 1_000_000_000
    # the neighbour on the bus lost nothing
    n = nb.status().to_json()
    assert n["lost_samples"] == 0 and n["resets"] == 0 and n["state"] == "running"
    seq = concat([decode(b) for b in bus.out[1]])["seq"]
    assert np.all(np.diff(seq) == 1)


def test_a_stim300_that_resets_itself_restarts_its_stream() -> None:
    """The STIM300 has no registers: a reset shows as the start-up status bit coming back after
    valid data (its counter starts over too). The driver finds it in the first datagram after
    the reset, the runner restarts the stream, and the start-up datagrams count as lost in the
    same one gap."""
    _, clock, sim, driver, runner, out, truth = stim_rig(
        {"seed": 4, "clock_error": 0.004, "faults": {"resets": [{"at_s": 1.0}]}},
        startup_ns=200_000_000,
    )
    t0 = clock.now_ns()
    detected: list[int] = []
    step = runner.step

    def watched() -> None:
        before, now = runner.resets, clock.now_ns()
        step()
        if runner.resets > before:
            detected.append(now)

    runner.step = watched  # type: ignore[method-assign]
    stim_run(clock, runner, 2.5)
    st = runner.status().to_json()
    assert sim.self_resets == 1 and st["resets"] == 1 and st["state"] == "running"
    assert len(detected) == 1 and 0 <= detected[0] - (t0 + 1_000_000_000) <= 100_000_000
    assert "start-up status bit" in str(st["last_error"])
    # the start-up datagrams of power-on and of the reset are all lost: two gaps
    m = concat([decode(b) for b in out])
    gaps = np.diff(m["seq"]) - 1
    assert np.all(gaps >= 0) and int(gaps.sum()) + _first_seq_gap(out) == st["lost_samples"]
    # within one slot, and one more: a stream says nothing of when the restart was, so the first
    # batch after it is placed by one read, which is up to a period late (FIFO chips are placed
    # by their FIFO's restart instant)
    undeclared = _undeclared_ns(sim, driver)
    j = _gap_matches_the_true_clock(out, truth, int(gaps.max()), undeclared, within=2.0)
    # back (start-up over) 1.2 s after the reset; streaming within 1 s of it
    assert m["t_ns"][j + 1] < t0 + int((1.0 + 0.2 + 1.0) * 1e9)


def _first_seq_gap(out: list[bytes]) -> int:
    """Samples lost before the first one published (the power-on start-up datagrams)."""
    return int(decode(out[0]).lost_before)


@pytest.mark.parametrize("chip", list(DEVICES))
def test_garbage_in_the_identity_register_fails_the_start_naming_it_then_runs(
    chip: str, tmp_path: Path
) -> None:
    window_s = 1.0
    bus = _bus(DEVICES[chip], {"garbage_identity_s": window_s}, tmp_path)
    errors: list[str] = []
    fail = bus.runners[0]._fail

    def noted(msg: str, now: int) -> None:
        errors.append(msg)
        fail(msg, now)

    bus.runners[0]._fail = noted  # type: ignore[method-assign]
    bus.run(window_s + 2.5)
    dut, nb = bus.runners
    assert errors, "the start never failed"
    assert all(e.startswith("start failed: ") for e in errors), errors
    assert re.search(IDENTITY[chip], errors[0]), errors[0]
    # the runner retried (backoff capped at 1 s) and the device runs after the window
    st = dut.status().to_json()
    assert st["state"] == "running" and st["samples"] > 0
    m = concat([decode(b) for b in bus.out[0]])
    window_end = bus.t0 + int(window_s * 1e9)
    assert m["t_ns"][0] > window_end - 100_000_000  # nothing before the chip was identified
    assert nb.status().lost_samples == 0
