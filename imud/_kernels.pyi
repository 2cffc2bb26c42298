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
def bracket(
    a_t: npt.NDArray[np.int64],
    seq: npt.NDArray[np.int64],
    t: npt.NDArray[np.int64],
    jj: npt.NDArray[np.int64],
    w: npt.NDArray[np.float64],
    base: npt.NDArray[np.bool_],
) -> int: ...
def lerp(
    v: npt.NDArray[np.float64],
    inv: npt.NDArray[np.bool_],
    jj: npt.NDArray[np.int64],
    w: npt.NDArray[np.float64],
    base: npt.NDArray[np.bool_],
    out: npt.NDArray[np.float64],
    bad: npt.NDArray[np.bool_],
) -> bool: ...
def pack(
    prefix: bytes,
    t: npt.NDArray[np.int64],
    sample_flags: npt.NDArray[np.uint32] | None,
    channels: tuple[npt.NDArray[Any], ...],
) -> bytes: ...
def orient_chunk(
    gyro: npt.NDArray[np.float64],
    b: npt.NDArray[np.float64],
    dt: float,
    q: npt.NDArray[np.float64],
    accel: npt.NDArray[np.float64] | None,
    steps: float,
    q_out: npt.NDArray[np.float64],
    qq: npt.NDArray[np.float64],
    qqa: npt.NDArray[np.float64],
    kqqa: npt.NDArray[np.float64],
) -> tuple[float, float, float, float, float, int]: ...
