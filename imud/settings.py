"""Settings every `[[device]]` carries whatever its chip, for the stages after its driver.

They sit below the chips (a chip's config model derives from `imud.chips.api.DeviceBase`, which
holds them) and are read by the pipeline stage each belongs to.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


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
