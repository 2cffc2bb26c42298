"""The `[[device]]` table of an ADIS16465: its model (gyro range), DEC_RATE and the output rate it
gives, the Bartlett filter, the delta outputs, and what the SPI bus can carry."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, model_validator

from imud.buses.models import Bus, SpiBus
from imud.chips.adis16465.decode import sample_frames
from imud.chips.adis16465.registers import (
    BURST_FRAME_BYTES,
    DEC_RATE_MAX,
    FILT_CTRL_MAX,
    GYRO_RANGES_DPS,
    INTERNAL_RATE_HZ,
    MAX_BURST_SCLK_HZ,
    MAX_SCLK_HZ,
    MIN_SCLK_HZ,
    READ_RATE_NS,
    READS_PER_DR,
    SPI_MODE,
    STALL_NS,
)
from imud.chips.api import DeviceBase

BUS_SHARE = 0.8  # of a sample period the reads may take: the rest for extra polls, the host
LOW_WORDS_SHARE = 0.4  # the optional low words only when the bus stays this idle with them
_REL = 2e-5  # an odr_hz within this of 2000 / (dec_rate + 1) names that rate (666.667 Hz)


def odr_of(dec_rate: int) -> float:
    return INTERNAL_RATE_HZ / (dec_rate + 1)


def bus_speed_hz(bus: Bus) -> int | None:
    """The SPI clock; None on another transport (the config's transport check rejects it)."""
    return bus.clock_hz if bus.transport == "spi" else None


def frame_speeds(speed_hz: int) -> tuple[int, int]:
    """SCLK of register frames and of the burst: the chip's limits, never above the bus's."""
    return min(MAX_SCLK_HZ, speed_hz), min(MAX_BURST_SCLK_HZ, speed_hz)


def bus_time_ns(speed_hz: int, frames: int) -> float:
    """Bus time of one new sample: the 176-bit burst, then `frames` register frames, each at
    least a stall after the one before."""
    reg_hz, burst_hz = frame_speeds(speed_hz)
    burst = BURST_FRAME_BYTES * 8e9 / burst_hz + STALL_NS
    return burst + frames * max(16e9 / reg_hz + STALL_NS, READ_RATE_NS)


def within_budget(frames: int, dec_rate: int, speed_hz: int, share: float = BUS_SHARE) -> bool:
    """Whether `frames` register reads after each burst stay within the reads the datasheet
    allows per data-ready period and within `share` of the sample period on the bus."""
    period = 1e9 / odr_of(dec_rate)
    reads_ok = frames <= READS_PER_DR * (dec_rate + 1)
    return reads_ok and bus_time_ns(speed_hz, frames) <= share * period


def _rates_near(odr: float) -> str:
    d = min(max(round(INTERNAL_RATE_HZ / odr - 1), 0), DEC_RATE_MAX)
    near = sorted({min(max(x, 0), DEC_RATE_MAX) for x in (d - 1, d, d + 1)})
    return ", ".join(f"{odr_of(x):.6g} Hz (dec_rate = {x})" for x in near)


class Adis16465Config(DeviceBase):
    """An ADIS16465 on SPI. `odr_hz` = 2000 / (`dec_rate` + 1) on the chip's own (+-3 %) clock:
    give either, or both if they agree."""

    chip: Literal["adis16465"]
    model: Literal[1, 2, 3] = Field(
        description="ADIS16465-1, -2 or -3 (RANG_MDL): gyro range +-125, +-500 or +-2000 deg/s"
    )
    dec_rate: int = Field(
        1, ge=0, le=DEC_RATE_MAX, description="DEC_RATE: averages dec_rate + 1 internal samples"
    )
    odr_hz: float = Field(1000.0, description="2000 / (dec_rate + 1): 2000, 1000, 666.667, 500 ...")
    filt_ctrl: int = Field(
        0,
        ge=0,
        le=FILT_CTRL_MAX,
        description="FILT_CTRL: Bartlett window of two 2^B-tap stages, B = 0 (off) ... 6",
    )
    deltas: bool = Field(
        True, description="read and publish delta angle and delta velocity (needs dec_rate >= 1)"
    )

    @model_validator(mode="before")
    @classmethod
    def _rate_from_either(cls, data: Any) -> Any:
        """Whichever of `dec_rate` and `odr_hz` is given sets the other."""
        if not isinstance(data, dict):
            return data
        dec, odr = data.get("dec_rate"), data.get("odr_hz")
        if isinstance(odr, int | float) and not isinstance(odr, bool):
            if odr <= 0:
                raise ValueError(f"odr_hz must be positive, not {odr:g}")
            d = round(INTERNAL_RATE_HZ / odr - 1)
            exact = 0 <= d <= DEC_RATE_MAX and abs(odr_of(d) - odr) <= _REL * odr
            if not exact:
                raise ValueError(
                    f"odr_hz = {odr:g} is not a rate of the ADIS16465, which runs at 2000 / "
                    f"(dec_rate + 1) Hz (dec_rate 0 ... {DEC_RATE_MAX}); nearest: "
                    f"{_rates_near(odr)}"
                )
            if dec is None:
                return {**data, "dec_rate": d, "odr_hz": odr_of(d)}
            if isinstance(dec, int) and dec != d:
                raise ValueError(
                    f"odr_hz = {odr:g} and dec_rate = {dec} disagree: dec_rate = {dec} gives "
                    f"{odr_of(dec):.6g} Hz, and {odr:g} Hz is dec_rate = {d}; give one of them"
                )
            return {**data, "odr_hz": odr_of(d)}
        if isinstance(dec, int) and not isinstance(dec, bool) and 0 <= dec <= DEC_RATE_MAX:
            return {**data, "odr_hz": odr_of(dec)}
        return data

    @model_validator(mode="after")
    def _bus_can_carry(self) -> Adis16465Config:
        bus = self.bus
        if isinstance(bus, SpiBus) and bus.mode != SPI_MODE:
            raise ValueError(
                f"the ADIS16465 needs SPI mode 3 (CPOL = 1, CPHA = 1); bus.mode is {bus.mode}"
            )
        speed = bus_speed_hz(bus)
        if speed is None:
            return self  # not SPI: the device check names the buses the chip takes
        if speed < MIN_SCLK_HZ:
            raise ValueError(
                f"the ADIS16465's SCLK runs at 0.1 MHz at least; bus.speed_hz is {speed:g} Hz"
            )
        frames = sample_frames(lows=False, deltas=self.deltas)
        allowed = READS_PER_DR * (self.dec_rate + 1)
        if frames > allowed:
            raise ValueError(
                f"deltas = true at {self.odr_hz:g} Hz (dec_rate = {self.dec_rate}): reading the "
                f"six 32-bit delta outputs takes {frames} register reads per sample, and the "
                f"datasheet allows {allowed} per data-ready period before a datapath overrun; "
                "set deltas = false for 2000 Hz, or keep the deltas with dec_rate >= 1 (1000 Hz: "
                "they then integrate over every internal sample, nothing is lost)"
            )
        if not within_budget(frames, self.dec_rate, speed):
            need, period = bus_time_ns(speed, frames), 1e9 / self.odr_hz
            d = next(
                (x for x in range(DEC_RATE_MAX + 1) if within_budget(frames, x, speed)),
                DEC_RATE_MAX,
            )
            reg_hz, burst_hz = frame_speeds(speed)
            regs = f", {frames} register frames at {reg_hz / 1e6:g} MHz with 16 us stalls"
            raise ValueError(
                f"at bus.speed_hz = {speed:g} Hz one sample takes {need / 1e3:.0f} us of bus "
                f"time (the 176-bit burst at {burst_hz / 1e6:g} MHz{regs if frames else ''}), "
                f"more than {BUS_SHARE:.0%} of the {period / 1e3:.0f} us sample period: use "
                f"dec_rate >= {d} ({odr_of(d):.6g} Hz){', deltas = false' if frames else ''} or "
                "a faster SCLK (up to 2 MHz; bursts run at 1 MHz at most)"
            )
        return self

    def low_words(self) -> bool:
        """Whether the gyro and accel low words are read: when DEC_RATE or FILT_CTRL puts bits
        in them and the bus has room to spare for them (with the deltas, if on): the reads
        after each sample then keep it busy at most 40 % of a period."""
        if not (self.dec_rate or self.filt_ctrl):
            return False
        speed = bus_speed_hz(self.bus) or MAX_BURST_SCLK_HZ
        frames = sample_frames(True, self.deltas)
        return within_budget(frames, self.dec_rate, speed, LOW_WORDS_SHARE)

    @property
    def gyro_range_dps(self) -> int:
        return GYRO_RANGES_DPS[self.model]
