"""ADIS16465 decoding at the byte level: burst frames with good and bad checksums (the expected
numbers worked out here from the datasheet's formula and scale factors), DATA_CNTR duplicates
and gaps, the delta outputs' 32-bit words, and the scale factors of each model.

The driver talks to a scripted chip that answers exactly the bytes written in each test."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from imud.channels import Channel
from imud.chips.adis16465 import decode as d
from imud.chips.adis16465.config import Adis16465Config
from imud.chips.adis16465.driver import Adis16465Driver
from imud.chips.api import FifoRead, RawBatch
from imud.clock import VirtualClock
from imud.errors import BusError, RegisterMismatch

G = 9.80665

# A burst at rest on an ADIS16465-2, by hand: DIAG_STAT 0; gyro X = +40 LSB (+1 deg/s at
# 40 LSB/(deg/s)), Y = -40 (0xFFD8), Z = 4000 (0x0FA0, 100 deg/s); accel X = Y = 0, Z = 4000
# (1 g at 4000 LSB/g); TEMP_OUT 250 (0x00FA, 25.0 degC at 0.1 degC/LSB); DATA_CNTR 0x1234.
# Checksum = sum of the 18 bytes as unsigned 8-bit values (datasheet):
# 0x00+0x00 +0x00+0x28 +0xFF+0xD8 +0x0F+0xA0 +0x00+0x00 +0x00+0x00 +0x0F+0xA0 +0x00+0xFA
# +0x12+0x34 = 40+255+216+15+160+15+160+250+18+52 = 1181 = 0x049D
GOOD = bytes.fromhex("0000 0028 FFD8 0FA0 0000 0000 0FA0 00FA 1234 049D".replace(" ", ""))


def _frame(counter: int, diag: int = 0, gz: int = 4000) -> bytes:
    """The frame above with another DATA_CNTR (and DIAG_STAT, gyro Z): its checksum summed
    here byte by byte, as the datasheet defines it."""
    words = [diag, 40, -40 & 0xFFFF, gz & 0xFFFF, 0, 0, 4000, 250, counter]
    body = b"".join(w.to_bytes(2, "big") for w in words)
    return body + (sum(body) & 0xFFFF).to_bytes(2, "big")


def test_the_hand_made_frame_is_what_the_helper_builds() -> None:
    assert _frame(0x1234) == GOOD


def test_a_good_burst_decodes_to_the_datasheet_values() -> None:
    b = d.decode_burst(GOOD)
    assert b.checksum == 0x049D == d.checksum(GOOD)
    assert (b.diag_stat, b.gyro, b.accel, b.temp, b.data_cntr) == (
        0, (40, -40, 4000), (0, 0, 4000), 250, 0x1234,
    )  # fmt: skip


@pytest.mark.parametrize("at", [0, 3, 9, 16, 17, 18, 19])
def test_one_changed_byte_fails_the_checksum(at: int) -> None:
    bad = bytearray(GOOD)
    bad[at] ^= 0x01
    with pytest.raises(ValueError, match="checksum"):
        d.decode_burst(bytes(bad))


def test_the_checksum_is_the_full_16_bit_sum() -> None:
    """ArduPilot compares only the low byte; the datasheet's checksum is 16 bits: a frame whose
    low byte matches but high byte does not is bad."""
    bad = bytearray(GOOD)
    bad[18] ^= 0x01  # checksum 0x059D: same low byte
    with pytest.raises(ValueError):
        d.decode_burst(bytes(bad))
    # 18 bytes of 0xFF sum to 4590 = 0x11EE
    assert d.checksum(b"\xff" * 18) == 0x11EE


def test_scale_factors_of_each_model() -> None:
    # gyro: 160 / 40 / 10 LSB per deg/s (-1 / -2 / -3)
    assert d.gyro_scale_rads(1) == pytest.approx(math.radians(1 / 160), rel=1e-12)
    assert d.gyro_scale_rads(2) == pytest.approx(math.radians(1 / 40), rel=1e-12)
    assert d.gyro_scale_rads(3) == pytest.approx(math.radians(1 / 10), rel=1e-12)
    # accel: 4000 LSB/g = 0.25 mg per LSB, every model
    assert d.accel_scale_ms2() == pytest.approx(0.25e-3 * G, rel=1e-12)
    # delta angle: +-360 / 720 / 2160 deg over 2^15 counts of the _OUT word (2^31 of 32 bits);
    # one _OUT LSB = 0.010986328125 / 0.02197265625 / 0.06591796875 deg
    for model, deg in ((1, 0.010986328125), (2, 0.02197265625), (3, 0.06591796875)):
        assert d.delta_angle_scale_rad(model) * 65536 == pytest.approx(math.radians(deg))
    # delta velocity: +-100 m/s over 2^15: 0.0030517578125 m/s per _OUT LSB
    assert d.delta_velocity_scale_ms() * 65536 == pytest.approx(0.0030517578125, rel=1e-12)
    assert d.TEMP_C_PER_LSB == 0.1


def test_32_bit_outputs_from_their_two_words() -> None:
    assert d.join32(0x0001, 0x0000) == 65536
    assert d.join32(0x0000, 0xFFFF) == 65535
    assert d.join32(0xFFFF, 0xFFFF) == -1
    assert d.join32(0x8000, 0x0000) == -(2**31)
    assert d.join32(0x7FFF, 0xFFFF) == 2**31 - 1


def test_rang_mdl_names_the_model() -> None:
    # RANG_MDL[3:2]: 00 = +-125 (-1), 01 = +-500 (-2), 11 = +-2000 (-3); [1:0] read 11
    assert [d.model_from_rang_mdl(v) for v in (0x0003, 0x0007, 0x000F)] == [1, 2, 3]
    assert d.model_from_rang_mdl(0x000B) is None  # 10: no model
    assert d.model_from_rang_mdl(0x0004) is None  # [1:0] not 11
    assert d.model_from_rang_mdl(0xFFFF) is None  # a floating MISO line


# --- the driver against a scripted chip -------------------------------------------------------
class ScriptedChip:
    """Each poll sees the next scripted burst frame: a burst returns it, a DATA_CNTR register
    read its counter (unless `regs` says otherwise), other registers come from `regs`; register
    answers are pipelined into the next frame, as on the chip."""

    def __init__(self, frames: Sequence[bytes], regs: dict[int, int] | None = None) -> None:
        self.frames = list(frames)
        self.regs = regs or {}
        self.current = bytes(20)
        self.pending = 0
        self.speeds: list[tuple[int, int]] = []  # (frame bytes, speed_hz)
        self.mode = 3
        self.max_speed_hz = 2_000_000

    def poll(self, drv: Adis16465Driver) -> RawBatch:
        self.current = self.frames.pop(0)
        return drv.read()

    def xfer2(
        self, values: list[int], speed_hz: int = 0, delay_usecs: int = 0, bits_per_word: int = 0
    ) -> list[int]:
        self.speeds.append((len(values), speed_hz))
        if len(values) == 22:
            assert values[:2] == [0x68, 0x00]  # the burst command
            return [0, 0, *self.current]
        reg = values[0] & 0x7E
        value = self.regs.get(reg, int.from_bytes(self.current[16:18], "big") if reg == 0x22 else 0)
        answer, self.pending = self.pending, value
        return [answer >> 8, answer & 0xFF]

    def close(self) -> None:
        pass


def _driver(chip: ScriptedChip, clock: Any = None, **cfg: Any) -> Adis16465Driver:
    """At 2000 Hz without deltas unless told: one burst per sample, 16-bit words."""
    c = Adis16465Config.model_validate(
        {"chip": "adis16465", "name": "a", "model": 2, "deltas": False, "dec_rate": 0,
         "bus": {"kind": "spi", "path": "/dev/spidev0.0", "speed_hz": 2_000_000}, **cfg}
    )  # fmt: skip
    return Adis16465Driver(c, chip, clock or VirtualClock())


def test_driver_publishes_a_good_burst_in_si_units() -> None:
    chip = ScriptedChip([GOOD])
    drv = _driver(chip)
    b = chip.poll(drv)
    assert b.n == 1 and b.alarm is None
    si = {c: rc.data.astype(np.float64) * rc.scale for c, rc in b.channels.items()}
    np.testing.assert_allclose(si[Channel.GYRO], [[math.radians(1), -math.radians(1),
                                                   math.radians(100)]], rtol=1e-12)  # fmt: skip
    np.testing.assert_allclose(si[Channel.ACCEL], [[0.0, 0.0, G]], rtol=1e-12)
    np.testing.assert_allclose(si[Channel.TEMPERATURE], [25.0], rtol=1e-12)
    assert isinstance(b.timing, FifoRead) and b.timing.counter is not None
    assert b.timing.counter.values.tolist() == [0x1234] and b.timing.counter.modulo == 65536
    # DATA_CNTR polled (a read and the frame that clocks it out) at 2 MHz, then the burst at
    # 1 MHz on a 2 MHz bus
    assert chip.speeds == [(2, 2_000_000), (2, 2_000_000), (22, 1_000_000)]


def test_a_bad_checksum_is_a_counted_bus_error_and_never_published() -> None:
    bad = bytearray(_frame(7))
    bad[7] ^= 0x10
    chip = ScriptedChip([_frame(6), bytes(bad), b"\xff" * 20, _frame(8)])
    drv = _driver(chip)
    assert chip.poll(drv).n == 1
    with pytest.raises(BusError, match="checksum word"):
        chip.poll(drv)
    with pytest.raises(BusError, match="all ones"):
        chip.poll(drv)
    assert drv.counters.bad_transfers == 2 and drv.counters.chip["checksum_errors"] == 2
    b = chip.poll(drv)  # counter 8 after 6: sample 7 (the bad frame's) is lost, and counted
    assert b.n == 1 and isinstance(b.timing, FifoRead) and b.timing.resync
    assert drv.chip_status()["samples_skipped"] == 1


def test_an_all_zero_burst_is_no_answer() -> None:
    # every frame all zeros, PROD_ID too: nothing answers (a chip resetting is silent for
    # 198 ms, a disconnected one for ever): re-initialise, which finds out which
    chip = ScriptedChip([bytes(20)])
    drv = _driver(chip)
    with pytest.raises(RegisterMismatch, match="not answering"):
        chip.poll(drv)


def test_data_cntr_duplicates_and_gaps_are_counted_exactly() -> None:
    counters = [0xFFFD, 0xFFFD, 0xFFFE, 0xFFFE, 0xFFFE, 0x0003, 0x0004]
    chip = ScriptedChip([_frame(c) for c in counters])
    drv = _driver(chip)
    batches: list[RawBatch] = [chip.poll(drv) for _ in counters]
    assert [b.n for b in batches] == [1, 0, 1, 0, 0, 1, 1]
    resync = [isinstance(b.timing, FifoRead) and b.timing.resync for b in batches]
    assert resync == [False, False, False, False, False, True, False]
    # 0xFFFE -> 0x0003 across the wrap: 0xFFFF, 0, 1, 2 were never read
    st = drv.chip_status()
    assert (st["duplicate_reads"], st["counter_gaps"], st["samples_skipped"]) == (3, 1, 4)


def test_diag_stat_bits_are_kept_and_mark_the_sample() -> None:
    # 0x000A = datapath overrun (bit 1) + SPI communication error (bit 3); the next burst is
    # a duplicate carrying bit 3 again: it marks the next new sample. With the deltas read the
    # poll is the burst itself (500 Hz here), so the duplicate's DIAG_STAT is seen.
    chip = ScriptedChip([_frame(1, diag=0x000A), _frame(1, diag=0x0008), _frame(2), _frame(3)])
    drv = _driver(chip, deltas=True, dec_rate=3)
    alarms = [chip.poll(drv).alarm for _ in range(4)]
    assert alarms[0] is not None and alarms[0].tolist() == [True]
    assert alarms[1] is None  # the duplicate: nothing published
    assert alarms[2] is not None and alarms[2].tolist() == [True]
    assert alarms[3] is None
    st = drv.chip_status()
    assert st["diag_stat"] == "0x000a"
    assert st["diag_stat_counts"] == {"datapath_overrun": 1, "spi_communication_error": 2}


def test_low_and_delta_words_read_after_the_burst_and_checked_by_data_cntr() -> None:
    from imud.chips.adis16465.registers import Register as Reg

    # at dec_rate 3 (500 Hz) the low words carry bits, and a 2 MHz bus has room to read them
    # with the deltas (a burst and 20 frames: 672 us of 2 ms): X_GYRO_LOW 0x8000 makes gyro X
    # 40.5 LSB (1.0125 deg/s at 40 LSB/(deg/s)); Z_ACCL_LOW 0x4000: accel Z 4000.25 LSB
    # (1.0000625 g).
    # X delta angle: _OUT 0x0001, _LOW 0x8000 = 98304 counts = 1.5 _OUT LSB; at -2
    # (+-720 deg over 2^31) that is 98304 * 720 / 2^31 deg = 0.032958984375 deg.
    # Z delta velocity: _OUT 0xFFFF, _LOW 0x0000 = -65536 = -100 / 32768 m/s.
    regs = {Reg.X_GYRO_LOW: 0x8000, Reg.Z_ACCL_LOW: 0x4000,
            Reg.X_DELTANG_OUT: 0x0001, Reg.X_DELTANG_LOW: 0x8000,
            Reg.Z_DELTVEL_OUT: 0xFFFF, Reg.Z_DELTVEL_LOW: 0x0000, Reg.DATA_CNTR: 5}  # fmt: skip
    chip = ScriptedChip([_frame(5), _frame(6)], regs)
    drv = _driver(chip, deltas=True, dec_rate=3)
    b = chip.poll(drv)
    si = {c: rc.data.astype(np.float64) * rc.scale for c, rc in b.channels.items()}
    assert si[Channel.GYRO][0, 0] == pytest.approx(math.radians(1.0125), rel=1e-12)
    assert si[Channel.GYRO][0, 1] == pytest.approx(math.radians(-1.0), rel=1e-12)
    assert si[Channel.ACCEL][0, 2] == pytest.approx(1.0000625 * G, rel=1e-12)
    da, dv = b.channels[Channel.DELTA_ANGLE], b.channels[Channel.DELTA_VELOCITY]
    assert da.invalid is None and dv.invalid is None
    assert float(da.data[0, 0] * da.scale) == pytest.approx(math.radians(0.032958984375))
    assert float(dv.data[0, 2] * dv.scale) == pytest.approx(-100 / 32768)
    # 6 low words, 12 delta words, DATA_CNTR and the frame that clocks it out, at 2 MHz
    assert chip.speeds == [(22, 1_000_000)] + [(2, 2_000_000)] * 20
    assert drv.chip_status()["gyro_accel_bits"] == 32
    b = chip.poll(drv)  # DATA_CNTR still reads 5 after burst 6: a new sample came meanwhile
    assert b.channels[Channel.DELTA_ANGLE].invalid is not None
    assert drv.chip_status()["delta_races"] == 1
    # the low words of that read are not this sample's: their midpoint, not a mix
    si = {c: rc.data.astype(np.float64) * rc.scale for c, rc in b.channels.items()}
    assert si[Channel.GYRO][0, 0] == pytest.approx(math.radians(40.5 / 40), rel=1e-12)
    assert si[Channel.ACCEL][0, 2] == pytest.approx(4000.5 / 4000 * G, rel=1e-12)


def test_without_room_for_the_low_words_their_midpoint_is_used() -> None:
    """On a 1 MHz bus at 1000 Hz with deltas, a burst and 20 frames (832 us) would keep the bus
    busy more than the 40 % of a period imud allows the optional low words: the 16-bit words
    are published with half a code added (a high word alone is the floor of the 32-bit value),
    unbiased."""
    chip = ScriptedChip([_frame(5)], {})
    drv = _driver(chip, deltas=True, dec_rate=1,
                  bus={"kind": "spi", "path": "/dev/spidev0.0", "speed_hz": 1_000_000})  # fmt: skip
    b = chip.poll(drv)
    si = {c: rc.data.astype(np.float64) * rc.scale for c, rc in b.channels.items()}
    assert si[Channel.GYRO][0, 2] == pytest.approx(math.radians(4000.5 / 40), rel=1e-12)
    assert drv.chip_status()["gyro_accel_bits"] == 16
    assert chip.speeds == [(22, 1_000_000)] + [(2, 1_000_000)] * 14


def test_a_sample_whose_reads_fail_midway_counts_as_lost() -> None:
    """The sample is only consumed once all its words are in: a transfer that fails during the
    delta reads leaves it to the next burst's DATA_CNTR step, which counts it as lost."""

    class Failing(ScriptedChip):
        fail_at = 0

        def xfer2(self, values: list[int], speed_hz: int = 0, delay_usecs: int = 0,
                  bits_per_word: int = 0) -> list[int]:  # fmt: skip
            if len(self.speeds) + 1 == self.fail_at:
                self.fail_at = 0
                raise OSError(5, "Input/output error")
            return super().xfer2(values, speed_hz, delay_usecs, bits_per_word)

    chip = Failing([_frame(c) for c in (1, 2, 3)])
    drv = _driver(chip, deltas=True, dec_rate=1)
    assert chip.poll(drv).n == 1  # sample 1: the burst and 14 frames
    chip.fail_at = len(chip.speeds) + 6  # the 5th register frame after the next burst
    with pytest.raises(BusError, match="Input/output error"):
        chip.poll(drv)
    b = chip.poll(drv)
    assert b.n == 1 and isinstance(b.timing, FifoRead) and b.timing.resync
    assert drv.chip_status()["samples_skipped"] == 1


def test_the_stall_between_frames_is_kept() -> None:
    """On the host's clock the driver waits out the chip's stall between frames (a lower bound:
    a busy machine only adds to it); at virtual time the wait takes no time of the test's."""
    import time

    from imud.clock import MonotonicClock

    chip = ScriptedChip([_frame(1)], {})
    drv = _driver(chip, MonotonicClock(), deltas=True, dec_rate=1)
    t0 = time.monotonic_ns()
    chip.poll(drv)
    # a burst and 14 register frames: at least 14 gaps of 16 us (24 us read to read)
    assert time.monotonic_ns() - t0 >= 14 * 24_000
