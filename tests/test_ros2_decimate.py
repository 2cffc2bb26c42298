"""Averaging down to the ROS 2 rate: against sums worked out here sample by sample."""

from __future__ import annotations

import numpy as np
import pytest

from imud.ros2.decimate import Decimator, factor


def _stream(n: int, lost: set[int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    seq = np.array([s for s in range(n) if s not in (lost or set())], dtype=np.int64)
    t = 1_764_000_000_000_000_000 + 1_000_000 * seq  # 1 kHz, near today's epoch
    gyro = np.stack([seq * 0.01, np.sin(seq), -seq * 1.0], axis=1)
    return seq, t, gyro


def _expected(seq: np.ndarray, t: np.ndarray, gyro: np.ndarray, k: int) -> tuple[list, list]:
    """Group by hand: every k consecutive sequence numbers, the mean of those present."""
    ts, gs = [], []
    for g in sorted(set((seq // k).tolist())):
        m = seq // k == g
        members = [int(x) for x in t[m]]  # Python ints: exact
        ts.append(sum(members) // len(members))  # the mean instant, to the ns below
        gs.append(gyro[m].mean(axis=0))
    return ts, gs


@pytest.mark.parametrize(
    ("odr", "rate", "k"),
    [(1000, 200, 5), (1000, 1000, 1), (1125, 200, 6), (32000, 200, 160), (100, 200, 1)],
)
def test_the_factor_brings_the_rate_to_at_most_rate_hz(odr: float, rate: float, k: int) -> None:
    assert factor(odr, rate) == k
    assert odr / k <= rate


@pytest.mark.parametrize("splits", [[1000], [3, 7, 990], [5] * 200, [1] * 1000, [499, 1, 500]])
def test_messages_do_not_depend_on_how_reads_split_the_stream(splits: list[int]) -> None:
    seq, t, gyro = _stream(1000, lost={17, 18, 19, 20, 21, 22, 500, 501})
    d = Decimator(5)
    got_t: list[int] = []
    got_g: list[np.ndarray] = []
    at = 0
    for size in splits:
        part = slice(at, min(at + size, len(seq)))
        at += size
        out = d.feed(seq[part], t[part], gyro[part])
        got_t += out.t_ns.tolist()
        got_g += list(out.values)
    want_t, want_g = _expected(seq, t, gyro, 5)
    # seq 17-22 lost: group 3 (15-19) has two members, group 4 (20-24) two; all else five;
    # the last group (995-999) is complete when 999 arrives
    assert got_t == want_t
    np.testing.assert_allclose(np.array(got_g), np.array(want_g), rtol=1e-12, atol=1e-12)


def test_an_invalid_value_is_left_out_of_its_mean_only() -> None:
    seq = np.arange(10, dtype=np.int64)
    t = seq * 1_000_000
    accel = np.ones((10, 3))
    accel[2] = np.nan
    gyro = np.full((10, 3), 2.0)
    accel[5:10] = np.nan  # a whole group without a valid accel
    out = Decimator(5).feed(seq, t, np.hstack((accel, gyro)))
    np.testing.assert_array_equal(out.values[0, :3], [1.0, 1.0, 1.0])
    assert np.isnan(out.values[1, :3]).all()
    np.testing.assert_array_equal(out.values[:, 3:], np.full((2, 3), 2.0))
    assert out.members.tolist() == [5, 5]


def test_an_orientation_is_averaged_on_one_hemisphere_and_normalised() -> None:
    # a slow turn about z; every other quaternion given with the opposite sign (same rotation)
    ang = np.linspace(0.0, 0.04, 4)
    q = np.stack([np.zeros(4), np.zeros(4), np.sin(ang / 2), np.cos(ang / 2)], axis=1)
    q[1::2] *= -1
    out = Decimator(4, quat=slice(0, 4)).feed(np.arange(4, dtype=np.int64), np.arange(4) * 10, q)
    mean = out.values[0]
    assert np.linalg.norm(mean) == pytest.approx(1.0)
    # the mean rotation: 0.02 rad about z (to the averaging's second order)
    assert 2 * np.arctan2(abs(mean[2]), abs(mean[3])) == pytest.approx(0.02, abs=1e-6)


@pytest.mark.parametrize("seed", range(5))
def test_groups_split_across_batches_average_as_one(seed: int) -> None:
    """A group spread over batches (kept as running sums between them) gives what averaging
    its samples in one piece gives: stamps, NaNs left out, quaternions on one hemisphere."""
    rng = np.random.default_rng(seed)
    k = 7
    seq = np.sort(rng.choice(400, size=330, replace=False)).astype(np.int64)
    t = 1_764_000_000_000_000_000 + 1_250_000 * seq + rng.integers(-20_000, 20_000, seq.size)
    ang = 0.001 * seq
    q = np.stack([np.zeros_like(ang), np.zeros_like(ang), np.sin(ang / 2), np.cos(ang / 2)], 1)
    q[rng.random(seq.size) < 0.5] *= -1
    accel = rng.normal(size=(seq.size, 3))
    accel[rng.random(seq.size) < 0.2, 1] = np.nan
    values = np.hstack((accel, q))
    d = Decimator(k, quat=slice(3, 7))
    got_t: list[int] = []
    got_v: list[np.ndarray] = []
    at = 0
    while at < seq.size:
        size = int(rng.integers(1, 20))
        out = d.feed(seq[at : at + size], t[at : at + size], values[at : at + size])
        at += size
        got_t += out.t_ns.tolist()
        got_v += list(out.values)
    want_t, want_v = [], []
    for g in sorted(set((seq // k).tolist())):
        m = seq // k == g
        members = [int(x) for x in t[m]]
        want_t.append(sum(members) // len(members))
        a = accel[m]
        am = [float(np.mean(col[~np.isnan(col)])) if (~np.isnan(col)).any() else np.nan
              for col in a.T]  # fmt: skip
        qs = q[m]
        qs = np.where((qs @ qs[0] < 0)[:, None], -qs, qs)
        qm = qs.mean(axis=0)
        want_v.append(np.r_[am, qm / np.linalg.norm(qm)])
    if seq[-1] % k != k - 1:  # the last group waits for members that may still come
        want_t, want_v = want_t[:-1], want_v[:-1]
    assert got_t == want_t
    np.testing.assert_allclose(np.array(got_v), np.array(want_v), rtol=1e-12, atol=1e-12)
