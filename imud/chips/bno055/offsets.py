"""The BNO055's calibration profile (22 bytes, 0x55-0x6A) and its file.

The chip has no EEPROM: after a power cycle its offsets are back to zero and it must be
calibrated again, unless the host writes a saved profile back in CONFIG mode (datasheet §3.11.4).
imud saves the profile once the chip reports itself fully calibrated and restores it at every
start. The file is human-readable TOML with the register values, their units and the chip's
unique id (a profile belongs to one chip), written atomically: a temporary file in the same
directory, fsync, rename over the old one, fsync of the directory. A crash at any point leaves
either the old file or the new one, never a torn one.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imud.atomicfile import write_atomic
from imud.chips.bno055.registers import OFFSETS_LEN

__all__ = ["Offsets", "OffsetsError", "load_offsets", "parse_offsets", "write_atomic"]

FORMAT = "imud-bno055-offsets"
VERSION = 1
_INT16 = (-32768, 32767)


class OffsetsError(ValueError):
    """An offsets file imud will not write to the chip (the message says why and what to do)."""


@dataclass(frozen=True, slots=True)
class Offsets:
    """ACC_OFFSET, MAG_OFFSET, GYR_OFFSET (x, y, z), ACC_RADIUS, MAG_RADIUS: int16 registers."""

    accel: tuple[int, int, int]
    mag: tuple[int, int, int]
    gyro: tuple[int, int, int]
    accel_radius: int
    mag_radius: int

    @classmethod
    def from_bytes(cls, data: bytes) -> Offsets:
        if len(data) != OFFSETS_LEN:
            raise OffsetsError(
                f"a BNO055 calibration profile is {OFFSETS_LEN} bytes (0x55-0x6A), got {len(data)}"
            )
        v = [int(x) for x in np.frombuffer(data, dtype="<i2")]
        return cls((v[0], v[1], v[2]), (v[3], v[4], v[5]), (v[6], v[7], v[8]), v[9], v[10])

    def to_bytes(self) -> bytes:
        words = [*self.accel, *self.mag, *self.gyro, self.accel_radius, self.mag_radius]
        return np.asarray(words, dtype="<i2").tobytes()

    def to_toml(self, device: str, uid: bytes, unit_sel: int, saved_at: str) -> str:
        """The file's text: the registers, with what they mean in SI units as comments."""

        def xyz(v: tuple[int, int, int], per_si: float, unit: str) -> str:
            return "".join(
                f"{k} = {n:<7d}# {n / per_si:+.4g} {unit}\n" for k, n in zip("xyz", v, strict=True)
            )

        return (
            "# BNO055 calibration offsets, saved by imud when the chip reported every\n"
            "# calibration status at 3 (CALIB_STAT = 0xFF). imud writes them back, in CONFIG\n"
            "# mode, at every start (datasheet §3.11.4), so the chip needs no re-calibration\n"
            "# after a power cycle. Delete this file to start from the chip's defaults.\n"
            f'format = "{FORMAT}"\n'
            f"version = {VERSION}\n"
            'chip = "bno055"\n'
            f'device = "{device}"\n'
            f'uid = "{uid.hex()}"  # the chip these offsets belong to (page 1, 0x50-0x5F)\n'
            f'saved_at = "{saved_at}"\n'
            f"unit_sel = 0x{unit_sel:02X}  # the units the offsets are in (UNIT_SEL, 0x3B)\n"
            "\n[accel_offset]  # ACC_OFFSET_X/Y/Z (0x55-0x5A): 1 LSB = 0.01 m/s^2\n"
            + xyz(self.accel, 100.0, "m/s^2")
            + "\n[mag_offset]  # MAG_OFFSET_X/Y/Z (0x5B-0x60): 1 LSB = 1/16 uT (hard iron)\n"
            + xyz(self.mag, 16.0, "uT")
            + "\n[gyro_offset]  # GYR_OFFSET_X/Y/Z (0x61-0x66): 1 LSB = 1/900 rad/s\n"
            + xyz(self.gyro, 900.0, "rad/s")
            + "\n[radius]  # ACC_RADIUS (0x67-0x68), MAG_RADIUS (0x69-0x6A), LSB\n"
            f"accel = {self.accel_radius}\n"
            f"mag = {self.mag_radius}\n"
        )


def _int16(table: dict[str, object], key: str, where: str) -> int:
    v = table.get(key)
    if not isinstance(v, int) or isinstance(v, bool) or not _INT16[0] <= v <= _INT16[1]:
        raise OffsetsError(f"{where}.{key} must be an int16 register value, got {v!r}")
    return v


def parse_offsets(text: str, unit_sel: int, uid: bytes | None) -> Offsets:
    """An offsets file's text to the profile, checked: format, chip, units, and (when `uid` is
    given) that it belongs to this chip."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise OffsetsError(f"not valid TOML: {e}") from None
    if raw.get("format") != FORMAT or raw.get("version") != VERSION:
        raise OffsetsError(
            f'not an imud BNO055 offsets file (format = "{FORMAT}", version = {VERSION})'
        )
    if raw.get("chip") != "bno055":
        raise OffsetsError(f"saved for chip {raw.get('chip')!r}, not a bno055")
    if raw.get("unit_sel") != unit_sel:
        raise OffsetsError(
            f"saved with UNIT_SEL {raw.get('unit_sel')!r}, imud uses 0x{unit_sel:02X}: the "
            "offsets would be in other units; delete the file and let the chip calibrate"
        )
    saved_uid = raw.get("uid")
    if uid is not None and isinstance(saved_uid, str) and saved_uid != uid.hex():
        raise OffsetsError(
            f"saved from another chip (uid {saved_uid}, this one is {uid.hex()}): its offsets "
            "do not fit this one; delete the file and let the chip calibrate"
        )
    tables = {}
    for name in ("accel_offset", "mag_offset", "gyro_offset", "radius"):
        t = raw.get(name)
        if not isinstance(t, dict):
            raise OffsetsError(f"missing the [{name}] table")
        tables[name] = t

    def vec(name: str) -> tuple[int, int, int]:
        t = tables[name]
        return (_int16(t, "x", name), _int16(t, "y", name), _int16(t, "z", name))

    r = tables["radius"]
    return Offsets(
        vec("accel_offset"),
        vec("mag_offset"),
        vec("gyro_offset"),
        _int16(r, "accel", "radius"),
        _int16(r, "mag", "radius"),
    )


def load_offsets(path: Path, unit_sel: int, uid: bytes | None) -> Offsets | None:
    """The saved profile, None when there is no file; `OffsetsError` (naming the file) when
    there is one imud will not use."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as e:
        raise OffsetsError(f"{path}: cannot read it: {e}") from None
    try:
        return parse_offsets(text, unit_sel, uid)
    except OffsetsError as e:
        raise OffsetsError(f"{path}: {e}") from None
