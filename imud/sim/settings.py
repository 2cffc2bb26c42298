"""The `[device.sim]` table: motion profile, error model overrides, seed and ground truth."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

Vec3 = tuple[float, float, float]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class StillMotion(_Strict):
    """At rest in a fixed orientation (ZYX Euler angles, REP-103 body axes, ENU world)."""

    kind: Literal["still"] = "still"
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0


class TumbleMotion(_Strict):
    """Constant body-frame angular rate from an initial orientation, e.g. a slow tumble."""

    kind: Literal["tumble"] = "tumble"
    rate_dps: Vec3 = (20.0, 35.0, 10.0)
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0


Motion = Annotated[StillMotion | TumbleMotion, Field(discriminator="kind")]


class ErrorSettings(_Strict):
    """Error-model overrides. `None` means: draw from the chip's datasheet figures with the seed.

    Set a figure to 0 to switch that error off; `ideal = true` switches off every deterministic
    error (bias, drift, scale, misalignment, clock error) and keeps only noise and quantisation.
    """

    ideal: bool = False
    accel_noise_ug_rthz: float | None = Field(None, ge=0)
    gyro_noise_dps_rthz: float | None = Field(None, ge=0)
    accel_bias_mg: Vec3 | None = None
    gyro_bias_dps: Vec3 | None = None
    accel_bias_instability_ug: float | None = Field(None, ge=0)
    gyro_bias_instability_dph: float | None = Field(None, ge=0)
    accel_scale_error: Vec3 | None = None
    gyro_scale_error: Vec3 | None = None
    misalignment_deg: float | None = Field(None, ge=0)
    accel_temp_drift_mg_per_c: Vec3 | None = None
    gyro_temp_drift_dps_per_c: Vec3 | None = None


class SerialFaults(_Strict):
    """Damage a simulated serial link does to the bytes a chip sends (each draw from the seed).

    The chip's simulator applies them and counts what it damaged, so a test can check that the
    driver counts exactly that."""

    corrupt_rate: float = Field(0.0, ge=0.0, le=1.0, description="per byte: one bit flipped")
    drop_rate: float = Field(0.0, ge=0.0, le=1.0, description="per byte: never arrives")
    garbage_rate: float = Field(
        0.0, ge=0.0, le=1.0, description="per message: a burst of random bytes before it"
    )
    garbage_bytes: int = Field(16, ge=1, le=4096, description="length of a garbage burst")


class MagneticSettings(_Strict):
    """The Earth's field where the simulated board is, and the board's own magnetic errors, for
    a chip with a magnetometer: hard iron (a constant offset from magnetised parts nearby) and
    soft iron (a matrix from ferrous material that bends the field), m = A b + h + noise."""

    field_ut: float = Field(50.0, ge=0.0, le=100.0, description="total intensity, microtesla")
    inclination_deg: float = Field(
        60.0, ge=-90.0, le=90.0, description="dip below horizontal (positive: northern hemisphere)"
    )
    declination_deg: float = Field(
        0.0, ge=-180.0, le=180.0, description="magnetic north, degrees east of true north"
    )
    hard_iron_ut: Vec3 = (0.0, 0.0, 0.0)
    soft_iron: tuple[Vec3, Vec3, Vec3] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    noise_ut: float = Field(0.3, ge=0.0, description="white noise per sample and axis, rms")


class SimSettings(_Strict):
    """How a simulated device behaves; only allowed on a device whose bus has `kind = "sim"`."""

    seed: int = 0
    motion: Motion = Field(default_factory=StillMotion)
    truth: bool = False
    clock_error: float | None = Field(
        None,
        ge=-0.1,
        le=0.1,
        description="chip oscillator error as a fraction; None: drawn in +-1.5%",
    )
    temperature_c: float = 25.0
    temperature_ramp_c_per_min: float = 0.0
    temperature_limits_c: tuple[float, float] = (-40.0, 85.0)
    nak_rate: float = Field(0.0, ge=0.0, le=1.0, description="fraction of bus transfers NAKed")
    errors: ErrorSettings = Field(default_factory=ErrorSettings)
    serial: SerialFaults = Field(default_factory=SerialFaults)
    magnetic: MagneticSettings = Field(default_factory=MagneticSettings)
