"""The chip registry: one entry per chip. Adding a chip is its folder plus one line here.

`register` also takes chips defined elsewhere (a test's toy chip, a plugin) at run time; the
config loader builds its model from whatever is registered when it runs.
"""

from __future__ import annotations

from typing import Any, get_args

from imud.chips.adis16465.spec import SPEC as ADIS16465
from imud.chips.api import ChipSpec
from imud.chips.bmi088.spec import SPEC as BMI088
from imud.chips.bno055.spec import SPEC as BNO055
from imud.chips.icm42688p.spec import SPEC as ICM42688P
from imud.chips.mpu6050.spec import SPEC as MPU6050
from imud.chips.stim300.spec import SPEC as STIM300

CHIPS: dict[str, ChipSpec[Any]] = {}
generation = 0  # bumped by every registration: config models built before are stale


def register(spec: ChipSpec[Any]) -> None:
    """Add a chip. Its config model must narrow `chip` to its name and declare `odr_hz`."""
    global generation
    fields = spec.config_model.model_fields
    if "odr_hz" not in fields:
        raise TypeError(f"{spec.name}: its config model must declare odr_hz, the published rate")
    chip = fields.get("chip")
    if chip is None or get_args(chip.annotation) != (spec.name,):
        raise TypeError(f"{spec.name}: its config model must declare chip: Literal[{spec.name!r}]")
    CHIPS[spec.name] = spec
    generation += 1


def unregister(name: str) -> None:
    global generation
    del CHIPS[name]
    generation += 1


for _spec in (MPU6050, ICM42688P, BMI088, STIM300, ADIS16465, BNO055):
    register(_spec)
