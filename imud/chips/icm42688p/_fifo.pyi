"""Types of the compiled FIFO decode (_fifo.c)."""

import numpy as np
import numpy.typing as npt

HDR_EMPTY: int
HDR_ACCEL: int
HDR_GYRO: int
HDR_20: int
INVALID_16: int
INVALID_20: int
INVALID_TEMP_8: int
TIMESTAMP_MODULO: int

def decode(
    data: bytes,
    hires: bool,
    break_over: float,
    accel: npt.NDArray[np.int32],
    gyro: npt.NDArray[np.int32],
    temp: npt.NDArray[np.float64],
    ts: npt.NDArray[np.int64],
    bad: npt.NDArray[np.bool_],
) -> tuple[int, bool, list[int]]: ...
