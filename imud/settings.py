"""Settings every `[[device]]` carries whatever its chip, for the stages after its driver.

They sit below the chips (a chip's config model derives from `imud.chips.api.DeviceBase`, which
holds them) and are read by the pipeline stage each belongs to.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, field_validator

from imud.rosnames import name_problem


class GyroBiasTracking(BaseModel):
    """`[device.gyro_bias_tracking]`: off unless `enabled = true`."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = False
    window_s: float = Field(
        1.0, gt=0.0, le=60.0, description="length of the windows stillness is judged on"
    )
    time_constant_s: float = Field(
        30.0, gt=0.0, description="of the average of still windows' gyro means"
    )
    confirm_s: float = Field(
        10.0,
        ge=0.0,
        description="a still window is learned only after this much more of the same still run",
    )
    max_rate_rad_s: float = Field(
        0.035,
        gt=0.0,
        description="a still window's mean gyro must be below this (after calibration): a "
        "steady turn slower than it about the vertical cannot be told from bias",
    )


class Orientation(BaseModel):
    """`[device.orientation]`: imud's orientation filter (imud.orient), off unless
    `enabled = true`. It publishes the `orientation` and `orientation_covariance` channels and
    the ROS 2 `imu/data` topic; docs/orientation.md."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = False
    update_hz: float = Field(
        10.0,
        gt=0.0,
        le=200.0,
        description="how often gravity (and the field) correct it; the gyro is integrated at "
        "every sample whatever this is",
    )
    magnetometer: bool = Field(
        True, description="correct the heading with the chip's magnetometer, when it has one"
    )
    declination_deg: float = Field(
        0.0, ge=-180.0, le=180.0, description="magnetic north's angle east of true north"
    )
    gyro_bias_sigma_rad_s: float = Field(
        0.01,
        gt=0.0,
        le=1.0,
        description="how far the gyro bias may be from zero at the start, after calibration "
        "(raise it for an uncalibrated chip: its datasheet's zero-rate offset)",
    )
    gyro_bias_walk: float = Field(
        2e-5, ge=0.0, description="how fast the bias wanders, rad/s per sqrt(s)"
    )
    linear_accel_max_m_s2: float = Field(
        0.2,
        gt=0.0,
        le=20.0,
        description="the most linear acceleration taken as the platform's own motion; beyond "
        "it, gravity's reading is rejected and the gyro carries the orientation (raise it for a "
        "platform that accelerates hard for long, at the price of tilt during it)",
    )
    start_s: float = Field(
        1.0,
        gt=0.0,
        le=60.0,
        description="seconds of samples the start averages for its first gravity (and field)",
    )


class DeviceRos2(BaseModel):
    """`[device.ros2]`: this device's ROS 2 topics, when `[ros2]` is on. Unset fields take
    `[ros2]`'s."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = True
    namespace: str | None = Field(
        None,
        description="where its topics go under [ros2] namespace: '/<namespace>/imu/data_raw' "
        "(default: the device's name)",
    )
    frame_id: str | None = Field(None, description="header.frame_id (default: [ros2] frame_id)")
    rate_hz: float | None = Field(
        None, gt=0.0, description="at most this many messages a second (default: [ros2] rate_hz)"
    )

    @field_validator("namespace")
    @classmethod
    def _namespace(cls, v: str | None) -> str | None:
        if v is not None:
            problem = name_problem("/" + v.strip("/") if v.strip("/") else "/", "namespace")
            if problem:
                raise ValueError(problem)
        return v

    @field_validator("frame_id")
    @classmethod
    def _frame_id(cls, v: str | None) -> str | None:
        if v is not None and ("\0" in v or not v.strip()):
            raise ValueError("frame_id must be a non-empty name without NUL, e.g. 'imu_link'")
        return v
