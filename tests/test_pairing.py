"""Accel samples aligned to gyro times (imud.chips.bmi088.pairing), from hand-made timelines."""

from __future__ import annotations

import numpy as np
import pytest

from imud.chips.bmi088.pairing import DiePairer

I64 = np.int64


def _accel(pairer: DiePairer, seq: list[int], t: list[int], slope: float = 1.0) -> None:
    """Accel samples whose x value is a linear ramp in time (counts = slope * t / 1000)."""
    ta = np.asarray(t, dtype=I64)
    vals = np.zeros((len(t), 3), dtype=np.int32)
    vals[:, 0] = np.rint(slope * ta / 1000).astype(np.int32)
    pairer.add_accel(np.asarray(seq, dtype=I64), ta, vals)


def _gyro(pairer: DiePairer, first: int, t: list[int]) -> None:
    n = len(t)
    g = np.arange(3 * n, dtype=np.int32).reshape(n, 3)
    pairer.add_gyro(first + np.arange(n, dtype=I64), np.asarray(t, dtype=I64), g)


def test_accel_is_interpolated_at_gyro_times() -> None:
    p = DiePairer()
    _accel(p, [0, 1, 2, 3], [0, 625_000, 1_250_000, 1_875_000])
    _gyro(p, 0, [100_000, 600_000, 1_100_000, 1_600_000])
    out = p.take()
    assert out is not None and out.n == 4 and out.valid.all()
    # the ramp is 1 count per us: interpolation returns it exactly between samples
    np.testing.assert_allclose(out.accel[:, 0], [100, 600, 1100, 1600], atol=1e-9)
    np.testing.assert_array_equal(out.gyro, np.arange(12).reshape(4, 3))


def test_gyro_newer_than_the_newest_accel_waits_for_the_next_one() -> None:
    p = DiePairer()
    _accel(p, [0, 1], [0, 625_000])
    _gyro(p, 0, [100_000, 600_000, 1_100_000])
    out = p.take()
    assert out is not None and out.n == 2 and p.pending == 1
    _accel(p, [2], [1_250_000])
    out = p.take()
    assert out is not None and out.first_seq == 2 and out.lost_before == 0
    np.testing.assert_allclose(out.accel[:, 0], [1100])


def test_gyro_between_non_consecutive_accel_samples_has_no_accel_value() -> None:
    p = DiePairer()
    _accel(p, [0, 1, 5, 6], [0, 625_000, 3_125_000, 3_750_000])  # accel 2..4 lost
    _gyro(p, 0, [500_000, 1_000_000, 2_000_000, 3_500_000])
    out = p.take()
    assert out is not None
    # every gyro sample is emitted (the gyro measured it), the two in the accel gap without
    # an accel value
    assert out.n == 4 and out.first_seq == 0 and out.lost_before == 0
    assert out.valid.tolist() == [True, False, False, True]
    np.testing.assert_allclose(out.accel[[0, 3], 0], [500, 3500], atol=1e-9)


def test_a_gyro_gap_ends_the_batch_and_the_next_one_counts_it() -> None:
    p = DiePairer()
    _accel(p, list(range(10)), [i * 625_000 for i in range(10)])
    _gyro(p, 0, [500_000, 1_000_000])
    _gyro(p, 5, [3_000_000, 3_500_000])  # seq 2..4 lost
    first = p.take()
    assert first is not None and first.n == 2 and first.first_seq == 0
    second = p.take()
    assert second is not None and second.first_seq == 5 and second.lost_before == 3


def test_gyro_before_the_first_accel_sample_is_not_part_of_the_stream() -> None:
    p = DiePairer()
    _accel(p, [0, 1], [1_000_000, 1_625_000])
    _gyro(p, 0, [200_000, 700_000, 1_200_000])
    out = p.take()
    assert out is not None and out.first_seq == 2 and out.lost_before == 0 and out.n == 1


def test_gyro_does_not_wait_forever_when_the_accel_die_stops() -> None:
    p = DiePairer(max_wait_ns=50_000_000)
    _accel(p, [0, 1], [0, 625_000])
    _gyro(p, 0, [500_000])
    assert p.take() is not None
    _gyro(p, 1, [1_000_000 + i * 500_000 for i in range(200)])  # 100 ms, no accel
    out = p.take()
    assert out is not None and not out.valid.any()  # emitted with no accel value
    assert out.first_seq == 1 and out.lost_before == 0
    assert p.pending < 200


def test_reset_drops_pending_gyro_and_the_next_batch_counts_them() -> None:
    p = DiePairer()
    _accel(p, [0, 1], [0, 625_000])
    _gyro(p, 0, [500_000, 1_000_000, 1_500_000])
    assert p.take() is not None and p.pending == 2
    p.reset()
    _accel(p, [10, 11], [5_000_000, 5_625_000])
    _gyro(p, 10, [5_500_000])
    out = p.take()
    assert out is not None and out.first_seq == 10 and out.lost_before == 9


@pytest.mark.parametrize("new_accel_seq", [10, 2])
def test_restart_keeps_gyro_samples_already_read_without_an_accel_value(
    new_accel_seq: int,
) -> None:
    """A reinitialised chip: the gyro samples read before it are measurements all the same.
    Those no accel sample read before the restart brackets come out with no accel value; the
    accel history starts again, so nothing is interpolated across the restart, even when the
    new accel samples' seq happens to follow the old ones' (seq 2 after 1)."""
    p = DiePairer()
    _accel(p, [0, 1], [0, 625_000])
    _gyro(p, 0, [500_000, 1_000_000, 1_500_000])
    first = p.take()
    assert first is not None and first.n == 1 and p.pending == 2  # 1.0, 1.5 ms wait for accel
    p.restart()
    _accel(p, [new_accel_seq, new_accel_seq + 1], [5_000_000, 5_625_000])
    _gyro(p, 10, [5_500_000])  # the gyro's seq counted on across the restart: 3..9 lost
    kept = p.take()
    assert kept is not None and kept.first_seq == 1 and kept.lost_before == 0 and kept.n == 2
    assert not kept.valid.any()
    np.testing.assert_array_equal(kept.t_ns, [1_000_000, 1_500_000])
    after = p.take()
    assert after is not None and after.first_seq == 10 and after.lost_before == 7
    assert after.valid.all()
    np.testing.assert_allclose(after.accel[:, 0], [5500], atol=1e-9)
