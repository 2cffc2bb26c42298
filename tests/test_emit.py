"""The emitter: losses and the flag that says a loss count is an estimate reach the batch that
carries them, whatever holes the batches had."""

from __future__ import annotations

import numpy as np

from imud.channels import Channel
from imud.emit import Emitter
from imud.pipeline import SampleBatch
from imud.wire import FLAG_GAP_UNCERTAIN, FLAG_RESYNC, Batch, decode


def _batch(
    first_seq: int, n: int, lost: int, flags: int, hole: list[bool] | None = None
) -> SampleBatch:
    t = 1_000_000 * (first_seq + np.arange(n, dtype=np.int64))
    gyro = np.ones((n, 3))
    return SampleBatch(
        first_seq,
        lost,
        flags,
        t,
        {Channel.GYRO: gyro},
        None,
        None if hole is None else np.array(hole),
    )


def _emitter() -> tuple[Emitter, list[Batch]]:
    out: list[Batch] = []
    return Emitter("imu0", 0, lambda p: out.append(decode(p)), lambda n, now: None), out


def test_an_estimated_gap_is_flagged_on_the_run_that_carries_it_only() -> None:
    e, out = _emitter()
    e.emit(_batch(0, 4, 0, 0), 0)
    # 3 lost (an estimate), then a batch whose middle sample has no valid value: two runs
    e.emit(_batch(7, 5, 3, FLAG_RESYNC | FLAG_GAP_UNCERTAIN, [False, False, True, False, False]), 0)
    assert [(b.first_seq, b.lost_before) for b in out] == [(0, 0), (7, 3), (10, 1)]
    assert [bool(b.flags & FLAG_GAP_UNCERTAIN) for b in out] == [False, True, False]
    assert e.uncertain_gaps == 1


def test_an_estimated_gap_before_a_batch_of_holes_goes_with_the_next_published_batch() -> None:
    e, out = _emitter()
    e.emit(_batch(0, 2, 0, 0), 0)
    e.emit(_batch(5, 2, 3, FLAG_RESYNC | FLAG_GAP_UNCERTAIN, [True, True]), 0)  # nothing out
    e.emit(_batch(7, 2, 0, 0), 0)
    assert [(b.first_seq, b.lost_before) for b in out] == [(0, 0), (7, 5)]
    assert bool(out[1].flags & FLAG_GAP_UNCERTAIN) and bool(out[1].flags & FLAG_RESYNC)
    assert e.uncertain_gaps == 1
