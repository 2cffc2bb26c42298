"""The BNO055 simulator, through the real driver at virtual time where it can be: a constant
rotation reads right (gyro, and the quaternion's rotation over time), the fusion tracks the true
orientation, calibration rises only with motion through orientations, the offsets registers
round-trip, and the UART front end answers as the data sheet's §4.7 says."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from imud.channels import Channel
from imud.chips.bno055.sim import Bno055Sim
from imud.clock import VirtualClock
from imud.sim.settings import SimSettings
from tests.helpers import make_rig

IDEAL = {"ideal": True, "accel_noise_ug_rthz": 0.0, "gyro_noise_dps_rthz": 0.0}


def rig_run(mode: str, seconds: float, sim: dict[str, Any], **device: Any) -> Any:
    rig = make_rig(
        {"chip": "bno055", "bus": {"kind": "sim"}, "mode": mode, "save_offsets": False, **device},
        sim,
    )
    rig.run(seconds)
    return rig


def joined(batches: list[Any], ch: Channel) -> np.ndarray:
    return np.concatenate([b.channels[ch] for b in batches if ch in b.channels]).astype(float)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def test_a_constant_rotation_reads_right() -> None:
    """30 deg/s about z, level: the gyro reads 0.5236 rad/s on z, and the published quaternion
    turns by 30 degrees about the body's z axis per second."""
    rig = rig_run(
        "ndof",
        3.0,
        {
            "seed": 2,
            "clock_error": 0.0,
            "errors": IDEAL,
            "motion": {"kind": "tumble", "rate_dps": [0.0, 0.0, 30.0]},
        },
    )
    bs = rig.batches()
    gyro = joined(bs, Channel.GYRO)
    assert np.abs(gyro[:, 2] - math.radians(30.0)).max() <= 1.5 / 900  # 1 LSB = 1/900 rad/s
    assert np.abs(gyro[:, :2]).max() <= 1.5 / 900
    q = joined(bs, Channel.ORIENTATION)
    seq = np.concatenate([b.seq for b in bs])
    i, j = 10, int(np.searchsorted(seq, seq[10] + 100))  # 100 samples = 1 s at 100 Hz
    turn = quat_mul(conj(q[i]), q[j])  # the rotation between them, in the body frame
    angle = 2 * math.acos(min(1.0, abs(turn[0])))
    axis = turn[1:] / np.linalg.norm(turn[1:]) * np.sign(turn[0])
    assert angle == pytest.approx(math.radians(30.0) * (seq[j] - seq[i]) / 100, abs=0.002)
    np.testing.assert_allclose(axis, [0.0, 0.0, 1.0], atol=0.01)


def test_the_fusion_tracks_the_true_orientation_and_gravity_agrees() -> None:
    rig = rig_run(
        "ndof", 4.0, {"seed": 4, "motion": {"kind": "tumble", "rate_dps": [90.0, 150.0, 60.0]}}
    )
    bs, truth = rig.batches(), rig.truth_batches()
    q = joined(bs, Channel.ORIENTATION)
    t = np.concatenate([b.t_ns for b in bs])
    tq = np.concatenate([b.channels[Channel.ORIENTATION] for b in truth]).astype(float)
    tt = np.concatenate([b.t_ns for b in truth])
    k = np.clip(np.searchsorted(tt, t) - 1, 0, len(tt) - 1)
    near = np.abs(tt[k] - t) < 5_000_000  # stamps within half a period of their truth
    err = [
        2 * math.acos(min(1.0, abs(float(np.dot(a, b)))))
        for a, b in zip(q[near], tq[k][near], strict=True)
    ]
    assert np.degrees(np.median(err)) < 5.0  # 4 deg at calibration 0 down to 0.25 at 3
    grv, lia, acc = (joined(bs, c) for c in (Channel.GRAVITY, Channel.LINEAR_ACCEL, Channel.ACCEL))
    np.testing.assert_allclose(np.linalg.norm(grv, axis=1), 9.80665, atol=0.02)
    np.testing.assert_allclose(acc - grv, lia, atol=0.02)  # LIA = accel - gravity


def test_calibration_rises_with_a_tumble_and_offsets_are_learned() -> None:
    rig = rig_run(
        "ndof",
        4.0,
        {
            "seed": 6,
            "motion": {"kind": "tumble", "rate_dps": [90.0, 150.0, 60.0]},
            "magnetic": {"hard_iron_ut": [12.0, -7.0, 4.0]},
        },
    )
    assert rig.driver.chip_status()["calibration"] == {"sys": 3, "gyro": 3, "accel": 3, "mag": 3}
    regs = bytes(rig.sim.p0[0x55:0x6B])
    words = np.frombuffer(regs, dtype="<i2")
    np.testing.assert_array_equal(words[3:6], [192, -112, 64])  # hard iron, 16 LSB per uT
    bias = rig.sim.errors.accel.bias  # m/s^2, learned as 100 LSB per m/s^2
    np.testing.assert_array_equal(words[0:3], np.rint(bias * 100))
    assert words[9] == 1000 and words[10] == 800  # radii: accel 1000, mag 50 uT * 16


def test_a_still_body_calibrates_only_its_gyro() -> None:
    rig = rig_run("ndof", 3.0, {"seed": 6})
    assert rig.driver.chip_status()["calibration"] == {"sys": 0, "gyro": 3, "accel": 0, "mag": 0}


def test_the_field_is_the_earths_plus_hard_iron_in_amg_mode() -> None:
    rig = rig_run(
        "amg",
        1.0,
        {
            "seed": 3,
            "magnetic": {
                "field_ut": 50.0,
                "inclination_deg": 60.0,
                "hard_iron_ut": [20.0, 0.0, 0.0],
                "noise_ut": 0.0,
            },
        },
    )
    mag = joined(rig.batches(), Channel.MAG)  # level, heading 0: (0, cos 60, -sin 60) * 50 uT
    np.testing.assert_allclose(mag.mean(axis=0), [20e-6, 25e-6, -43.30e-6], atol=0.1e-6)


def test_the_offsets_registers_round_trip_and_reset_to_zero() -> None:
    clock = VirtualClock()
    sim = Bno055Sim(SimSettings(), clock)
    profile = bytes(range(1, 23))
    assert sim.read(0x55, 22) == bytes(22)  # power-on: no calibration
    sim.write(0x55, profile)  # CONFIG mode after power-on: writable
    assert sim.read(0x55, 22) == profile
    sim.write(0x3D, bytes([0x0C]))  # NDOF
    clock.advance(20_000_000)
    sim.write(0x55, bytes(22))  # outside CONFIG mode the profile is not writable
    assert sim.read(0x55, 22) == profile
    sim.write(0x3F, bytes([0x20]))  # RST_SYS
    clock.advance(700_000_000)
    assert sim.read(0x55, 22) == bytes(22) and sim.read(0x00, 4) == b"\xa0\xfb\x32\x0f"


def test_a_restored_profile_counts_as_calibrated_when_fusion_starts() -> None:
    rig = rig_run(
        "ndof", 4.0, {"seed": 6, "motion": {"kind": "tumble", "rate_dps": [90.0, 150.0, 60.0]}}
    )
    profile = bytes(rig.sim.p0[0x55:0x6B])
    clock = VirtualClock()
    sim = Bno055Sim(SimSettings(seed=6), clock)  # still
    sim.write(0x55, profile)
    sim.write(0x3D, bytes([0x0C]))
    clock.advance(50_000_000)
    assert sim.read(0x35, 1) == b"\xff"


# --- UART front end ----------------------------------------------------------------------------
CHAR_NS = 10e9 / 115_200


def uart(**settings: Any) -> tuple[Any, VirtualClock]:
    clock = VirtualClock()
    sim = Bno055Sim(SimSettings(**settings), clock, serial_baud=115_200)
    return sim.uart, clock


def ask(die: Any, clock: VirtualClock, request: bytes, wait_ns: int = 10_000_000) -> bytes:
    """Send a request and pump the link as the pty does (every 0.5 ms) for `wait_ns`."""
    die.receive(request)
    out = b""
    for _ in range(wait_ns // 500_000):
        clock.advance(500_000)
        out += die.transmit(clock.now_ns())
    return out


@pytest.mark.parametrize(
    ("request_", "answer"),
    [
        (bytes([0xAA, 0x01, 0x00, 0x04]), bytes([0xBB, 0x04, 0xA0, 0xFB, 0x32, 0x0F])),
        (bytes([0xAA, 0x00, 0x3B, 0x01, 0x82]), bytes([0xEE, 0x01])),  # WRITE_SUCCESS
        (bytes([0xAA, 0x01, 0x70, 0x01]), bytes([0xEE, 0x04])),  # REGMAP_INVALID_ADDRESS
        (bytes([0xAA, 0x00, 0x00, 0x01, 0x00]), bytes([0xEE, 0x05])),  # CHIP_ID is read-only
        (bytes([0x55]), bytes([0xEE, 0x06])),  # WRONG_START_BYTE
        (bytes([0xAA, 0x01, 0x08, 0x81]), bytes([0xEE, 0x08])),  # MAX_LENGTH_ERROR (> 128)
        (bytes([0xAA, 0x01, 0x08, 0x00]), bytes([0xEE, 0x09])),  # MIN_LENGTH_ERROR
        (bytes([0xAA, 0x01]), bytes([0xEE, 0x0A])),  # RECEIVE_CHARACTER_TIMEOUT after 30 ms
    ],
)
def test_the_uart_answers(request_: bytes, answer: bytes) -> None:
    die, clock = uart()
    assert ask(die, clock, request_, 40_000_000) == answer


def test_bus_overrun_answers_come_with_nak_rate() -> None:
    die, clock = uart(nak_rate=1.0)
    assert ask(die, clock, bytes([0xAA, 0x01, 0x00, 0x01])) == bytes([0xEE, 0x07])


def test_the_reset_write_is_not_answered_and_the_chip_is_deaf_while_it_boots() -> None:
    die, clock = uart()
    assert ask(die, clock, bytes([0xAA, 0x00, 0x3F, 0x01, 0x20])) == b""
    assert ask(die, clock, bytes([0xAA, 0x01, 0x00, 0x01])) == b""  # lost: booting
    clock.advance(700_000_000)
    assert ask(die, clock, bytes([0xAA, 0x01, 0x00, 0x01])) == bytes([0xBB, 0x01, 0xA0])


def test_answers_leave_at_the_link_rate() -> None:
    die, clock = uart()
    die.receive(bytes([0xAA, 0x01, 0x00, 0x04]))
    clock.advance(int(4 * CHAR_NS) + 1)  # the request is in
    assert die.transmit(clock.now_ns()) == b""  # executed now; nothing sent yet
    clock.advance(int(2 * CHAR_NS) + 1)
    assert die.transmit(clock.now_ns()) == bytes([0xBB, 0x04])
    clock.advance(int(4 * CHAR_NS) + 1)
    assert die.transmit(clock.now_ns()) == bytes([0xA0, 0xFB, 0x32, 0x0F])


def test_serial_faults_damage_answers_and_are_counted() -> None:
    die, clock = uart(serial={"garbage_rate": 1.0, "garbage_bytes": 5})
    out = ask(die, clock, bytes([0xAA, 0x01, 0x00, 0x01]))
    assert len(out) == 5 + 3 and out[5:] == bytes([0xBB, 0x01, 0xA0])
    assert die.garbage_bursts == 1
