"""Types of the compiled kernels (imud/_kernels.c)."""

from typing import Any

import numpy as np
import numpy.typing as npt

def stamps(
    out: npt.NDArray[np.int64],
    s: float,
    b: float,
    k0: int,
    period: float,
    corr: float,
    last_ts: int | None,
    follow: bool,
    slew_room: float,
) -> None: ...
def tick_steps(ticks: npt.NDArray[np.int64], modulo: int) -> tuple[int, int]: ...
def reaches(data: npt.NDArray[Any], full_scale: float) -> bool: ...
