"""The `[[device]]` table of an MPU6050: ranges, DLPF bandwidth and the output rate it allows."""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, ValidationInfo, field_validator

from imud.chips.api import DeviceBase
from imud.chips.mpu6050.registers import GYRO_RATE_DLPF_OFF_HZ, GYRO_RATE_DLPF_ON_HZ

MAX_ODR_HZ = 1000.0  # the accel samples at 1 kHz: faster rates would repeat accel values


def internal_rate_hz(dlpf_hz: int) -> float:
    return GYRO_RATE_DLPF_OFF_HZ if dlpf_hz == 256 else GYRO_RATE_DLPF_ON_HZ


def allowed_odrs_hz(dlpf_hz: int) -> list[float]:
    """Every rate internal/(1 + SMPLRT_DIV) that is at most 1 kHz."""
    base = internal_rate_hz(dlpf_hz)
    return [base / (1 + d) for d in range(256) if base / (1 + d) <= MAX_ODR_HZ + 1e-9]


def divider_for(odr_hz: float, dlpf_hz: int) -> int | None:
    base = internal_rate_hz(dlpf_hz)
    d = round(base / odr_hz - 1)
    ok = 0 <= d <= 255 and math.isclose(base / (1 + d), odr_hz, rel_tol=1e-4)
    return d if ok and odr_hz <= MAX_ODR_HZ else None


def _fmt_rates(rates: list[float]) -> str:
    return ", ".join(f"{r:.6g}" for r in rates)


class Mpu6050Config(DeviceBase):
    """An MPU6050. `dlpf_hz` is the gyro DLPF bandwidth (256 = off, gyro sampling at 8 kHz)."""

    chip: Literal["mpu6050"]
    gyro_range_dps: Literal[250, 500, 1000, 2000] = 500
    accel_range_g: Literal[2, 4, 8, 16] = 4
    dlpf_hz: Literal[256, 188, 98, 42, 20, 10, 5] = 188
    odr_hz: float = Field(
        1000.0, gt=0, strict=True, description="internal/(1+SMPLRT_DIV), at most 1 kHz"
    )

    @field_validator("odr_hz")
    @classmethod
    def _reachable(cls, v: float, info: ValidationInfo) -> float:
        dlpf = info.data.get("dlpf_hz")
        if dlpf is None:  # dlpf_hz itself failed; its own error says why
            return v
        if divider_for(v, dlpf) is None:
            rates = allowed_odrs_hz(dlpf)
            nearest = min(rates, key=lambda r: abs(r - v))
            base = internal_rate_hz(dlpf)
            raise ValueError(
                f"the MPU6050 cannot produce {v:g} Hz with dlpf_hz = {dlpf}: allowed are "
                f"{base:g}/(1+n) Hz up to 1000 Hz, i.e. {_fmt_rates(rates[:8])}, ... "
                f"{_fmt_rates(rates[-2:])}; nearest is {nearest:.6g}"
            )
        return v

    @property
    def smplrt_div(self) -> int:
        d = divider_for(self.odr_hz, self.dlpf_hz)
        assert d is not None  # guaranteed by validation
        return d
