"""Calibration files and their live application: corrected = T @ (raw - bias) per sensor.

Version 1 holds a bias and either a full 3x3 matrix (misalignment and scale) or a diagonal scale,
per sensor. Later versions add temperature polynomials and the magnetometer ellipsoid.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, ValidationError, model_validator

F64 = npt.NDArray[np.float64]
Vec3 = tuple[float, float, float]


class SensorCalibration(BaseModel):
    model_config = ConfigDict(extra="forbid")

    bias: Vec3 = (0.0, 0.0, 0.0)
    scale: Vec3 | None = None
    matrix: tuple[Vec3, Vec3, Vec3] | None = None

    @model_validator(mode="after")
    def _one_of(self) -> SensorCalibration:
        if self.scale is not None and self.matrix is not None:
            raise ValueError("give either 'scale' or 'matrix', not both (matrix includes scale)")
        return self

    def transform(self) -> F64:
        if self.matrix is not None:
            return np.asarray(self.matrix, dtype=np.float64)
        return np.diag(np.asarray(self.scale if self.scale is not None else (1.0, 1.0, 1.0)))


class CalibrationFile(BaseModel):
    """accel bias in m/s^2, gyro bias in rad/s; matrices are dimensionless."""

    model_config = ConfigDict(extra="forbid")

    version: Literal[1] = 1
    accel: SensorCalibration | None = None
    gyro: SensorCalibration | None = None


@dataclass(frozen=True)
class Calibration:
    path: Path
    accel_bias: F64
    accel_t: F64
    gyro_bias: F64
    gyro_t: F64

    def apply(self, accel: F64, gyro: F64) -> tuple[F64, F64]:
        """Pure: returns new arrays."""
        return (accel - self.accel_bias) @ self.accel_t.T, (gyro - self.gyro_bias) @ self.gyro_t.T


class CalibrationError(ValueError):
    pass


def load_calibration(path: Path) -> Calibration:
    try:
        with open(path, "rb") as f:
            raw = tomllib.load(f)
    except FileNotFoundError as e:
        raise CalibrationError(f"calibration file {path} does not exist") from e
    except tomllib.TOMLDecodeError as e:
        raise CalibrationError(f"calibration file {path}: TOML syntax error: {e}") from e
    except UnicodeDecodeError as e:
        raise CalibrationError(f"calibration file {path}: not UTF-8 text (byte {e.start})") from e
    except OSError as e:  # a directory, no permission, ...
        raise CalibrationError(f"calibration file {path}: cannot read: {e.strerror}") from e
    try:
        cf = CalibrationFile.model_validate(raw)
    except ValidationError as e:
        msgs = "; ".join(
            f"{'.'.join(str(p) for p in err['loc'])}: {err['msg']}" for err in e.errors()
        )
        raise CalibrationError(f"calibration file {path}: {msgs}") from e
    a = cf.accel or SensorCalibration()
    g = cf.gyro or SensorCalibration()
    return Calibration(path, np.asarray(a.bias), a.transform(), np.asarray(g.bias), g.transform())
