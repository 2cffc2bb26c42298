"""The BNO055 calibration profile file: register layout, round trip, refusals, atomic write.

Layout (data sheet BST-BNO055-DS000-14 §3.6.4, pp. 31-33; Linux bno055.c CALDATA 0x55-0x6A):
22 bytes, int16 little-endian: ACC_OFFSET x y z (0x55-0x5A), MAG_OFFSET x y z (0x5B-0x60),
GYR_OFFSET x y z (0x61-0x66), ACC_RADIUS (0x67-0x68), MAG_RADIUS (0x69-0x6A)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from imud.chips.bno055.offsets import (
    Offsets,
    OffsetsError,
    load_offsets,
    parse_offsets,
    write_atomic,
)

# flynneva/bno055's example profile: ACC [0xFFEC, 0x00A5, 0xFFE8], MAG [0xFFB4, 0xFE9E, 0x027D],
# GYR [0x0002, 0xFFFF, 0xFFFF], ACC radius 0x3E8, MAG radius 0
EXAMPLE = Offsets((-20, 165, -24), (-76, -354, 637), (2, -1, -1), 1000, 0)
EXAMPLE_BYTES = bytes.fromhex(
    "ecff a500 e8ff b4ff 9efe 7d02 0200 ffff ffff e803 0000".replace(" ", "")
)
UID = bytes(range(16))


def test_the_profile_bytes_are_the_registers_in_order() -> None:
    assert EXAMPLE.to_bytes() == EXAMPLE_BYTES
    assert Offsets.from_bytes(EXAMPLE_BYTES) == EXAMPLE


def test_a_profile_that_is_not_22_bytes_is_refused() -> None:
    with pytest.raises(OffsetsError, match="22 bytes"):
        Offsets.from_bytes(EXAMPLE_BYTES[:20])


def test_the_file_round_trips_and_reads_as_what_it_means() -> None:
    text = EXAMPLE.to_toml("imu", UID, 0x82, "2025-01-01T00:00:00Z")
    assert parse_offsets(text, 0x82, UID) == EXAMPLE
    assert "x = -20    # -0.2 m/s^2" in text  # 1 LSB = 0.01 m/s^2 (Table 3-17)
    assert "z = 637    # +39.81 uT" in text  # 1 LSB = 1/16 uT
    assert "x = 2      # +0.002222 rad/s" in text  # 1 LSB = 1/900 rad/s (Table 3-22)
    assert f'uid = "{UID.hex()}"' in text


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace('chip = "bno055"', 'chip = "mpu6050"'), "not a bno055"),
        (lambda t: t.replace("unit_sel = 0x82", "unit_sel = 0x83"), "other units"),
        (lambda t: t.replace("x = -20 ", "x = 40000 "), "int16"),
        (lambda t: t.replace("[radius]", "[radii]"), "[radius]"),
        (lambda t: t.replace("version = 1", "version = 7"), "not an imud BNO055 offsets file"),
        (lambda t: t + "\n[[[", "not valid TOML"),
    ],
)
def test_a_file_imud_will_not_write_to_the_chip_says_why(edit: object, message: str) -> None:
    text = edit(EXAMPLE.to_toml("imu", UID, 0x82, "x"))  # type: ignore[operator]
    with pytest.raises(OffsetsError, match=message.replace("[", r"\[").replace("]", r"\]")):
        parse_offsets(text, 0x82, UID)


def test_a_profile_from_another_chip_is_refused() -> None:
    text = EXAMPLE.to_toml("imu", UID, 0x82, "x")
    with pytest.raises(OffsetsError, match="another chip"):
        parse_offsets(text, 0x82, bytes(16))


def test_no_file_is_none_and_a_bad_file_names_itself(tmp_path: Path) -> None:
    assert load_offsets(tmp_path / "none.toml", 0x82, UID) is None
    bad = tmp_path / "bad.toml"
    bad.write_text("format = 3\n")
    with pytest.raises(OffsetsError, match=str(bad)):
        load_offsets(bad, 0x82, UID)


def test_the_write_is_atomic_and_durable(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "state" / "imu.bno055-offsets.toml"
    synced: list[int] = []
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        synced.append(fd)
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    write_atomic(path, "old = 1\n")
    assert path.read_text() == "old = 1\n"
    assert len(synced) == 2  # the file's data, then the directory holding the rename
    # a failure before the rename leaves the old file whole and no temporary behind
    monkeypatch.setattr(os, "replace", lambda *a: (_ for _ in ()).throw(OSError(28, "full")))
    with pytest.raises(OSError):
        write_atomic(path, "new = 2\n")
    assert path.read_text() == "old = 1\n"
    assert sorted(p.name for p in path.parent.iterdir()) == [path.name]
