"""The align stage (imud.align): a chip's dies merged onto one die's sample times, from
hand-made timelines whose interpolated values are known (ramps in time)."""

from __future__ import annotations

import numpy as np
import pytest

from imud.align import Aligned, Aligner
from imud.channels import Channel
from imud.chips.api import RawChannel

I64 = np.int64
ACCEL, GYRO = 0, 1  # the dies; the stream runs at the gyro's times


def _accel(p: Aligner, seq: list[int], t: list[int], invalid: tuple[int, ...] = ()) -> None:
    """Accel samples whose x value is a ramp in time (1 count per us), with a temperature that
    is a ramp too (1 degree per ms); `invalid`: positions whose temperature is not valid."""
    ta = np.asarray(t, dtype=I64)
    vals = np.zeros((len(t), 3), dtype=np.int32)
    vals[:, 0] = np.rint(ta / 1000).astype(np.int32)
    bad = np.zeros(len(t), dtype=bool)
    bad[list(invalid)] = True
    channels = {
        Channel.ACCEL: RawChannel(vals, 0.5, 32767),
        Channel.TEMPERATURE: RawChannel(ta / 1e6, invalid=bad if bad.any() else None),
    }
    p.add(ACCEL, np.asarray(seq, dtype=I64), ta, channels)


def _gyro(p: Aligner, first: int, t: list[int]) -> None:
    n = len(t)
    g = np.arange(3 * n, dtype=np.int32).reshape(n, 3)
    p.add(GYRO, first + np.arange(n, dtype=I64), np.asarray(t, dtype=I64),
          {Channel.GYRO: RawChannel(g, 0.25, 32767)})  # fmt: skip


def _valid(out: Aligned, ch: Channel = Channel.ACCEL) -> np.ndarray:
    inv = out.channels[ch].invalid
    return np.ones(out.n, dtype=bool) if inv is None else ~inv


def test_the_other_die_is_interpolated_at_the_primary_times() -> None:
    p = Aligner(GYRO, 2, 100_000_000)
    _accel(p, [0, 1, 2, 3], [0, 625_000, 1_250_000, 1_875_000])
    _gyro(p, 0, [100_000, 600_000, 1_100_000, 1_600_000])
    out = p.take()
    assert out is not None and out.n == 4 and _valid(out).all()
    # the ramp is 1 count per us: interpolation returns it exactly between samples
    np.testing.assert_allclose(out.channels[Channel.ACCEL].data[:, 0], [100, 600, 1100, 1600])
    np.testing.assert_allclose(out.channels[Channel.TEMPERATURE].data, [0.1, 0.6, 1.1, 1.6])
    np.testing.assert_array_equal(out.channels[Channel.GYRO].data, np.arange(12).reshape(4, 3))
    # each channel keeps its die's scale and full scale: SI comes after
    assert out.channels[Channel.ACCEL].scale == 0.5 and out.channels[Channel.GYRO].scale == 0.25


def test_a_primary_sample_newer_than_the_others_newest_waits_for_the_next_one() -> None:
    p = Aligner(GYRO, 2, 100_000_000)
    _accel(p, [0, 1], [0, 625_000])
    _gyro(p, 0, [100_000, 600_000, 1_100_000])
    out = p.take()
    assert out is not None and out.n == 2 and p.pending == 1
    _accel(p, [2], [1_250_000])
    out = p.take()
    assert out is not None and out.first_seq == 2 and out.lost_before == 0
    np.testing.assert_allclose(out.channels[Channel.ACCEL].data[:, 0], [1100])


def test_between_non_consecutive_samples_there_is_no_value() -> None:
    p = Aligner(GYRO, 2, 100_000_000)
    _accel(p, [0, 1, 5, 6], [0, 625_000, 3_125_000, 3_750_000])  # accel 2..4 lost
    _gyro(p, 0, [500_000, 1_000_000, 2_000_000, 3_500_000])
    out = p.take()
    assert out is not None
    # every gyro sample goes out (the gyro measured it), the two in the accel gap without an
    # accel value
    assert out.n == 4 and out.first_seq == 0 and out.lost_before == 0
    assert _valid(out).tolist() == [True, False, False, True]
    np.testing.assert_allclose(out.channels[Channel.ACCEL].data[[0, 3], 0], [500, 3500])


def test_each_channel_is_invalid_only_where_its_own_neighbours_are() -> None:
    """A temperature marked invalid at one accel sample takes the temperature of the two gyro
    samples beside it, not their accel."""
    p = Aligner(GYRO, 2, 100_000_000)
    _accel(p, [0, 1, 2, 3], [0, 625_000, 1_250_000, 1_875_000], invalid=[1])
    _gyro(p, 0, [300_000, 900_000, 1_500_000])
    out = p.take()
    assert out is not None and _valid(out).all()
    assert _valid(out, Channel.TEMPERATURE).tolist() == [False, False, True]


def test_a_primary_gap_ends_the_run_and_the_next_one_counts_it() -> None:
    p = Aligner(GYRO, 2, 100_000_000)
    _accel(p, list(range(10)), [i * 625_000 for i in range(10)])
    _gyro(p, 0, [500_000, 1_000_000])
    _gyro(p, 5, [3_000_000, 3_500_000])  # seq 2..4 lost
    first = p.take()
    assert first is not None and first.n == 2 and first.first_seq == 0
    second = p.take()
    assert second is not None and second.first_seq == 5 and second.lost_before == 3


def test_primary_samples_before_the_others_first_are_not_part_of_the_stream() -> None:
    p = Aligner(GYRO, 2, 100_000_000)
    _accel(p, [0, 1], [1_000_000, 1_625_000])
    _gyro(p, 0, [200_000, 700_000, 1_200_000])
    out = p.take()
    assert out is not None and out.first_seq == 2 and out.lost_before == 0 and out.n == 1


def test_the_primary_does_not_wait_forever_when_another_die_stops() -> None:
    p = Aligner(GYRO, 2, max_wait_ns=50_000_000)
    _accel(p, [0, 1], [0, 625_000])
    _gyro(p, 0, [500_000])
    assert p.take() is not None
    _gyro(p, 1, [1_000_000 + i * 500_000 for i in range(200)])  # 100 ms, no accel
    out = p.take()
    assert out is not None and not _valid(out).any()  # out with no accel value
    assert out.first_seq == 1 and out.lost_before == 0
    assert p.pending < 200


def test_a_resumed_stream_counts_the_gap_to_its_first_run() -> None:
    """A restarted worker continues a stream: the first run after it counts what it missed."""
    p = Aligner(GYRO, 2, 100_000_000)
    p.next_seq = 7
    _accel(p, [0, 1], [0, 625_000])
    _gyro(p, 10, [500_000])
    out = p.take()
    assert out is not None and out.first_seq == 10 and out.lost_before == 3


@pytest.mark.parametrize("new_accel_seq", [10, 2])
def test_restart_keeps_primary_samples_already_read_without_the_others_values(
    new_accel_seq: int,
) -> None:
    """A reinitialised chip: the gyro samples read before it are measurements all the same.
    Those no accel sample read before the restart brackets come out with no accel value; the
    accel history starts again, so nothing is interpolated across the restart, even when the
    new accel samples' seq happens to follow the old ones' (seq 2 after 1)."""
    p = Aligner(GYRO, 2, 100_000_000)
    _accel(p, [0, 1], [0, 625_000])
    _gyro(p, 0, [500_000, 1_000_000, 1_500_000])
    first = p.take()
    assert first is not None and first.n == 1 and p.pending == 2  # 1.0, 1.5 ms wait for accel
    p.restart()
    _accel(p, [new_accel_seq, new_accel_seq + 1], [5_000_000, 5_625_000])
    _gyro(p, 10, [5_500_000])  # the gyro's seq counted on across the restart: 3..9 lost
    kept = p.take()
    assert kept is not None and kept.first_seq == 1 and kept.lost_before == 0 and kept.n == 2
    assert not _valid(kept).any()
    np.testing.assert_array_equal(kept.t_ns, [1_000_000, 1_500_000])
    after = p.take()
    assert after is not None and after.first_seq == 10 and after.lost_before == 7
    assert _valid(after).all()
    np.testing.assert_allclose(after.channels[Channel.ACCEL].data[:, 0], [5500])


def test_three_dies_wait_for_the_slowest() -> None:
    """A chip of three clocks (none ships yet): the primary waits until both others have a
    sample after it, and takes each one's channels."""
    p = Aligner(0, 3, 100_000_000)
    p.add(0, np.arange(3, dtype=I64), np.array([100, 200, 300], I64),
          {Channel.GYRO: RawChannel(np.zeros((3, 3), np.int32))})  # fmt: skip
    p.add(1, np.arange(2, dtype=I64), np.array([0, 400], I64),
          {Channel.ACCEL: RawChannel(np.array([[0, 0, 0], [400, 0, 0]]))})  # fmt: skip
    p.add(2, np.arange(2, dtype=I64), np.array([0, 250], I64),
          {Channel.MAG: RawChannel(np.array([[0, 0, 0], [250, 0, 0]]))})  # fmt: skip
    out = p.take()
    assert out is not None and out.n == 2  # the third waits for die 2's next sample
    np.testing.assert_allclose(out.channels[Channel.ACCEL].data[:, 0], [100, 200])
    np.testing.assert_allclose(out.channels[Channel.MAG].data[:, 0], [100, 200])
