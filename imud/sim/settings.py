"""The `[device.sim]` table: motion profile, error model overrides, seed and ground truth."""

from __future__ import annotations

import math
from typing import Annotated, Literal, Self

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

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


# Six faces (gravity along +-x, +-y, +-z of the body) and six cube corners (gravity along
# (+-1, +-1, +-1)/sqrt(3), all but (1, -1, -1) and (-1, -1, -1)): the corners make every product
# of two axes non-zero, so the 9-parameter accel fit (upper-triangular matrix and bias) is well
# conditioned (its Jacobian's condition number is 3.6; six faces alone leave the off-diagonal
# terms unobservable). Ordered face, corner, face, ... so each move is a 55 degree tilt about a
# horizontal axis (79 degrees back to the start); yaw follows from those tilts, rounded.
DEFAULT_POSES: tuple[Vec3, ...] = (
    (0.0, 0.0, 0.0),
    (45.0, -35.0, -15.0),
    (0.0, -90.0, 30.0),
    (-45.0, -35.0, 75.0),
    (-90.0, 0.0, 90.0),
    (-45.0, 35.0, 105.0),
    (0.0, 90.0, 150.0),
    (135.0, 35.0, -75.0),
    (180.0, 0.0, -60.0),
    (135.0, -35.0, -45.0),
    (90.0, 0.0, -30.0),
    (45.0, 35.0, -45.0),
)


class PosesMotion(_Strict):
    """A calibration session without a human: still poses joined by smooth rotations, then a
    sweep through all directions for the magnetometer, then back to the first pose.

    Moves are the shortest rotation between two poses (plus `turns_between` whole turns about
    the same axis) on a minimum-jerk time profile: peak rate 1.875 x angle / `move_s` (the
    default poses: 74 deg/s). The sweep spins 5 turns about each body axis in turn while the
    spin axis tilts once: peak rate about 3 x 5.1 turns / (0.9 `sweep_s`), 102 deg/s for 60 s.
    """

    kind: Literal["poses"] = "poses"
    poses: list[Vec3] = Field(
        default_factory=lambda: list(DEFAULT_POSES),
        description="still orientations, (roll, pitch, yaw) in degrees, visited in order",
    )
    hold_s: float = Field(4.0, gt=0.0, description="time still in each pose")
    move_s: float = Field(2.0, gt=0.0, description="time of each rotation between poses")
    turns_between: int = Field(
        0, ge=0, le=10, description="whole extra turns about the rotation axis during a move"
    )
    sweep_s: float = Field(
        60.0, ge=0.0, description="rotation through all directions after the poses; 0: none"
    )
    repeat: bool = Field(True, description="loop forever; false: stay in the first pose after")

    @field_validator("poses")
    @classmethod
    def _some_finite_poses(cls, poses: list[Vec3]) -> list[Vec3]:
        if not poses:
            raise ValueError(
                "no poses: list at least one [roll, pitch, yaw] in degrees "
                "(a 9-parameter accel calibration needs 9 distinct orientations)"
            )
        for i, p in enumerate(poses):
            if not all(math.isfinite(a) for a in p):
                raise ValueError(f"pose {i} is {list(p)}: angles must be finite degrees")
        return poses


Motion = Annotated[StillMotion | TumbleMotion | PosesMotion, Field(discriminator="kind")]


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


class Outage(_Strict):
    """The device stops answering at `at_s` (seconds after it was wired) for `for_s` seconds: a
    loose connector or a brown-out. I2C transfers are not acknowledged, SPI reads float high
    (0xFF) and writes are lost."""

    at_s: float = Field(ge=0.0)
    for_s: float = Field(gt=0.0)


class SelfReset(_Strict):
    """The chip resets itself at `at_s` (seconds after the simulator started), as a brown-out
    does: registers back to their power-on defaults, FIFO emptied and off, the sample counter
    restarted; the chip is busy for its datasheet reset time as after a soft reset."""

    at_s: float = Field(ge=0.0)


class BusFaults(_Strict):
    """`[device.sim.faults]`: what goes wrong on the bus, per transfer, drawn from the seed.

    NAKs stay the top-level `nak_rate` (on SPI, which has no acknowledge, it reads as a floating
    MISO line, as `garble_rate` does)."""

    eio_rate: float = Field(0.0, ge=0.0, le=1.0, description="transfers failing with EIO")
    timeout_rate: float = Field(
        0.0, ge=0.0, le=1.0, description="transfers failing with ETIMEDOUT (a stuck controller)"
    )
    garble_rate: float = Field(
        0.0, ge=0.0, le=1.0, description="SPI reads answered all 0xFF (MISO floating)"
    )
    stall_rate: float = Field(
        0.0, ge=0.0, le=1.0, description="transfers that block the bus worker for stall_ms first"
    )
    stall_ms: float = Field(20.0, ge=0.0, le=10_000.0, description="length of one stall")
    outages: list[Outage] = Field(default_factory=list, description="device vanishing")
    resets: list[SelfReset] = Field(
        default_factory=list, description="the chip resetting itself (a brown-out)"
    )
    garbage_identity_s: float = Field(
        0.0,
        ge=0.0,
        le=3600.0,
        description="for this long after power-on the identity register reads garbage",
    )


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
    temperature_cycle_min: float = Field(
        0.0,
        ge=0.0,
        description="> 0: the temperature swings between the limits as a sine of this period"
        " (minutes), from temperature_c upward; 0: the linear ramp",
    )
    nak_rate: float = Field(0.0, ge=0.0, le=1.0, description="fraction of bus transfers NAKed")
    faults: BusFaults = Field(default_factory=BusFaults)
    errors: ErrorSettings = Field(default_factory=ErrorSettings)
    serial: SerialFaults = Field(default_factory=SerialFaults)
    magnetic: MagneticSettings = Field(default_factory=MagneticSettings)

    @model_validator(mode="after")
    def _one_temperature_profile(self) -> Self:
        if self.temperature_cycle_min > 0:
            lo, hi = self.temperature_limits_c
            if not hi > lo:
                raise ValueError(
                    f"temperature_cycle_min needs temperature_limits_c = [low, high] with "
                    f"high > low, not {[lo, hi]}"
                )
            if self.temperature_ramp_c_per_min != 0:
                raise ValueError(
                    "temperature_cycle_min and temperature_ramp_c_per_min both set: "
                    "the cycle replaces the ramp, set one of them"
                )
        return self
