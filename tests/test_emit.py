"""The emitter: losses and the flag that says a loss count is an estimate reach the batch that
carries them, whatever holes the batches had."""

from __future__ import annotations

import numpy as np

from imud.channels import Channel
from imud.emit import MERGE_NS, Emitter
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
    e.flush()  # (small batches this close are held to go out together)
    assert [(b.first_seq, b.lost_before) for b in out] == [(0, 0), (7, 5)]
    assert bool(out[1].flags & FLAG_GAP_UNCERTAIN) and bool(out[1].flags & FLAG_RESYNC)
    assert e.uncertain_gaps == 1


def _one(seq: int, period_ns: int, lost: int = 0) -> SampleBatch:
    """One sample of a stream at `period_ns`, as a chip read once a sample gives them."""
    t = np.array([period_ns * seq], dtype=np.int64)
    return SampleBatch(seq, lost, 0, t, {Channel.GYRO: np.full((1, 3), float(seq))}, None)


def test_one_sample_batches_of_a_fast_stream_go_out_together() -> None:
    """2 kHz, a sample a read: held until 2.5 ms of them are in (MERGE_NS / 2), then one batch
    with every sample in order; the published count follows."""
    e, out = _emitter()
    for k in range(12):
        e.emit(_one(k, 500_000), now=k * 500_000)
    assert [(b.first_seq, len(b.t_ns)) for b in out] == [(0, 1), (1, 6)]
    assert out[1].t_ns.tolist() == [500_000 * k for k in range(1, 7)]
    assert out[1].channels[Channel.GYRO][:, 0].tolist() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert e.samples == 7
    e.flush()
    assert [(b.first_seq, len(b.t_ns)) for b in out][2:] == [(7, 5)] and e.samples == 12


def test_a_gap_ends_what_is_held_and_is_counted_on_the_batch_after_it() -> None:
    e, out = _emitter()
    for k in (0, 1, 2):
        e.emit(_one(k, 500_000), now=k * 500_000)
    e.emit(_one(5, 500_000, lost=2), now=5 * 500_000)
    e.flush()
    assert [(b.first_seq, len(b.t_ns), b.lost_before) for b in out] == [
        (0, 1, 0),
        (1, 2, 0),
        (5, 1, 2),
    ]
    assert bool(out[2].flags & FLAG_RESYNC)


def test_what_is_held_goes_out_after_merge_ns_even_if_nothing_follows() -> None:
    e, out = _emitter()
    e.emit(_one(0, 500_000), now=0)
    e.emit(_one(1, 500_000), now=500_000)  # held
    e.flush_due(500_000 + MERGE_NS - 1)
    assert len(out) == 1
    e.flush_due(500_000 + MERGE_NS)
    assert [(b.first_seq, len(b.t_ns)) for b in out] == [(0, 1), (1, 1)]


def test_a_slow_stream_is_published_at_once() -> None:
    """100 Hz (a BNO055): a sample every 10 ms is never held."""
    e, out = _emitter()
    for k in range(5):
        e.emit(_one(k, 10_000_000), now=k * 10_000_000)
    assert [b.first_seq for b in out] == [0, 1, 2, 3, 4]


def test_a_poll_that_found_nothing_does_not_end_what_is_held() -> None:
    e, out = _emitter()
    empty = SampleBatch(
        2, 0, 0, np.zeros(0, dtype=np.int64), {Channel.GYRO: np.zeros((0, 3))}, None
    )
    for b in (_one(0, 500_000), _one(1, 500_000), empty, _one(2, 500_000)):
        e.emit(b, now=0)
    e.flush()
    assert [(b.first_seq, len(b.t_ns)) for b in out] == [(0, 1), (1, 2)]
