"""When a simulated FIFO chip latches (imud/sim/chip.py, `_latch_at_end`): silicon's count holds
every sample its clock produced by the instant the bus reads it. A simulator's own work takes
host time, so the samples it holds at the end of an access must be those due by the end of that
work, not by some clock read before it: a sample that came due while the simulator was handing
the FIFO an earlier one would otherwise be missing from a read that ended after it, only in the
reads that found a new sample, and every host-side stamp would come out late (issue 10: the
MPU6050's daemon stamps were +22 us late from exactly this).

Here the hand-over is made to cost host time explicitly (a virtual clock advanced inside it, as
real time passes inside Python), and after every access of the driver's reads the chip's newest
latched sample must be the newest its grid has at the access's end."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from imud.sim.chip import Encoded, SampledChip
from tests.helpers import make_rig

SPI = {"kind": "sim", "transport": "spi", "cs": 0, "speed_hz": 10_000_000}
HANDOVER_NS = 40_000  # what handing samples over took in Python before it was prepared ahead


@pytest.mark.parametrize(
    "device",
    [{"chip": "mpu6050", "odr_hz": 1000}, {"chip": "icm42688p", "odr_hz": 1000, "bus": SPI}],
    ids=["mpu6050", "icm42688p"],
)
def test_an_access_ends_holding_every_sample_due_by_its_end(device: dict[str, Any]) -> None:
    rig = make_rig(device, {"seed": 3, "errors": {"ideal": True}})
    rig.run(0.5)
    chip: SampledChip = rig.sim  # type: ignore[assignment]
    hand_over = chip._emit_rows

    def slow(enc: Encoded, i: int, j: int) -> None:
        hand_over(enc, i, j)
        rig.clock.advance(HANDOVER_NS)

    chip._emit_rows = slow  # type: ignore[method-assign]
    answer = chip.read
    missing: list[int] = []

    def read(register: int, length: int) -> bytes:
        out: bytes = answer(register, length)
        period = 1e9 / chip.rate_hz
        due = math.floor((rig.clock.now_ns() - chip.grid_origin_ns) / period)
        missing.append(due - (chip.next_k - 1))
        return out

    chip.read = read  # type: ignore[method-assign]
    rng = np.random.default_rng(1)
    for _ in range(3000):
        rig.runner.step()
        rig.clock.advance(int(rng.integers(0, 2_000_000)))
    assert rig.runner.state == "running" and rig.runner.lost_samples == 0
    # the reads met samples coming due during a hand-over (40 us of each 1 ms period)...
    assert len(missing) > 3000
    # ...and none of them ended without it
    assert max(missing) == 0 and min(missing) == 0
