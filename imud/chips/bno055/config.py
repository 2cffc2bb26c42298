"""The `[[device]]` table of a BNO055: operating mode, where its calibration offsets are kept, the
axis remap, and the bus checks (UART at 115200 baud only, I2C at 0x28 or 0x29)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

from pydantic import Field, ValidationInfo, field_validator

from imud.buses import budget
from imud.buses.models import Bus, I2cBus
from imud.chips.api import DeviceBase
from imud.chips.bno055.registers import (
    DATA_BURST_LEN,
    FUSION_RATE_HZ,
    I2C_ADDRESSES,
    UART_BAUD,
    OprMode,
)

STATE_DIRECTORY = Path("/var/lib/imud")  # the systemd unit's StateDirectory
# address + register + address + data bytes, 9 bits each, 100 times a second, 25 % overhead
# a full read each sample: address + register + address, then the data bytes
READ_BYTES_PER_S = (3 + DATA_BURST_LEN) * FUSION_RATE_HZ

Mode = Literal["ndof", "ndof_fmc_off", "imu", "amg"]
MODES: dict[str, OprMode] = {
    "ndof": OprMode.NDOF,
    "ndof_fmc_off": OprMode.NDOF_FMC_OFF,
    "imu": OprMode.IMU,
    "amg": OprMode.AMG,
}
_AXES = re.compile(r"^([+-])([xyz])([+-])([xyz])([+-])([xyz])$")


def parse_axis_remap(text: str) -> tuple[tuple[int, int], tuple[int, int], tuple[int, int]]:
    """ "+x+y+z" style (which signed chip axis becomes the published x, y, z) to ((axis 0-2,
    sign +-1) for x, y, z). Only proper rotations: a mirror would make the frame left-handed."""
    m = _AXES.match(text.replace(" ", "").lower())
    if m is None:
        raise ValueError(
            f"axis_remap {text!r}: write three signed chip axes for the published x, y and z, "
            'e.g. "+x+y+z" (the chip\'s own axes) or "-y+x+z" (turned 90 degrees about z)'
        )
    g = m.groups()
    axes = tuple(("xyz".index(g[i + 1]), 1 if g[i] == "+" else -1) for i in (0, 2, 4))
    if sorted(a for a, _ in axes) != [0, 1, 2]:
        raise ValueError(f"axis_remap {text!r} uses a chip axis twice: each must appear once")
    perm_parity = _parity([a for a, _ in axes])
    det = perm_parity * axes[0][1] * axes[1][1] * axes[2][1]
    if det != 1:
        raise ValueError(
            f"axis_remap {text!r} is a mirror image (left-handed axes), which the chip's fusion "
            "cannot use: flip the sign of one more axis"
        )
    return axes[0], axes[1], axes[2]


def _parity(perm: list[int]) -> int:
    inversions = sum(1 for i in range(3) for j in range(i + 1, 3) if perm[i] > perm[j])
    return -1 if inversions % 2 else 1


class Bno055Config(DeviceBase):
    """A BNO055 on I2C or on its UART (PS1 high). Its outputs come at a fixed 100 Hz."""

    chip: Literal["bno055"]
    mode: Mode = Field(
        "ndof",
        description="ndof (9-axis absolute fusion), ndof_fmc_off (without fast magnetometer "
        "calibration), imu (accel + gyro, relative heading), amg (raw sensors, no fusion)",
    )
    odr_hz: float = Field(FUSION_RATE_HZ, description="100: the chip's only output rate")
    offsets_file: Path | None = Field(
        None,
        description="calibration offsets saved when the chip is fully calibrated and written "
        "back at every start; relative to the config; default "
        "/var/lib/imud/<name>.bno055-offsets.toml",
    )
    save_offsets: bool = Field(True, description="save the offsets once fully calibrated")
    axis_remap: str = Field("+x+y+z", description='mounting: e.g. "-y+x+z"; "+x+y+z" = as is')
    external_crystal: bool = Field(False, description="the board has a 32.768 kHz crystal")

    @field_validator("odr_hz")
    @classmethod
    def _fixed_rate(cls, v: float) -> float:
        if float(v) != FUSION_RATE_HZ:
            raise ValueError(
                f"the BNO055 outputs at a fixed {FUSION_RATE_HZ:g} Hz (datasheet Table 3-14); "
                f"odr_hz = {v:g} is not possible: remove odr_hz or set it to 100"
            )
        return float(v)

    @field_validator("offsets_file")
    @classmethod
    def _relative_offsets(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        base = (info.context or {}).get("base_dir")
        if v is not None and not v.is_absolute() and base is not None:
            return Path(base) / v
        return v

    @field_validator("axis_remap")
    @classmethod
    def _remap(cls, v: str) -> str:
        parse_axis_remap(v)
        return v

    @field_validator("bus")
    @classmethod
    def _bus(cls, v: Bus) -> Bus:
        if v.transport == "serial":
            if v.clock_hz != UART_BAUD:
                raise ValueError(
                    f"the BNO055's UART runs at {UART_BAUD} baud, 8N1 only (datasheet §4.7); "
                    f"bus.baud is {v.clock_hz}"
                )
            return v
        if isinstance(v, I2cBus) and v.address not in I2C_ADDRESSES:
            raise ValueError(
                f"the BNO055 answers at 0x28 (COM3 low) or 0x29 (COM3 high), not "
                f"0x{v.address:02x}: set bus.address"
            )
        why = budget.problem(
            v.transport,
            v.clock_hz,
            READ_BYTES_PER_S,
            f"a {DATA_BURST_LEN}-byte burst at {FUSION_RATE_HZ:g} Hz (before the chip's clock "
            "stretching)",
            "on a Raspberry Pi the 10 kHz clock-stretching workaround cannot carry it: use the "
            "i2c-gpio overlay or the UART",
        )
        if why:
            raise ValueError(why)
        return v

    @property
    def offsets_path(self) -> Path:
        """Where the calibration offsets live: `offsets_file`, or the state directory."""
        if self.offsets_file is not None:
            return self.offsets_file
        return STATE_DIRECTORY / f"{self.name}.bno055-offsets.toml"
