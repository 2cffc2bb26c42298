"""Types of the compiled accel FIFO walk (_fifo.c)."""

import numpy as np
import numpy.typing as npt

HEADER_MASK: int
HDR_ACCEL: int
HDR_SKIP: int
HDR_SENSORTIME: int
HDR_INPUT_CONFIG: int
HDR_SAMPLE_DROP: int
HDR_OVER_READ: int
ACCEL_FRAME: int

def decode_accel(
    data: bytes, accel: npt.NDArray[np.int32]
) -> tuple[int, list[tuple[int, int]], int | None, bool, int | None]: ...
