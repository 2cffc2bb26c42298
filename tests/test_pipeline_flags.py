"""Per-sample flags (`imud.pipeline.sample_flags`) against their definition, on batches of
every length around the size below which saturation is checked in plain Python."""

from __future__ import annotations

import numpy as np
import pytest

from imud.channels import Channel, SampleFlag
from imud.chips.api import FifoRead, RawBatch, RawChannel
from imud.pipeline import sample_flags

FULL_SCALE = 32768


@pytest.mark.parametrize("n", range(1, 10))
def test_a_sample_is_flagged_saturated_exactly_when_a_value_reaches_full_scale(n: int) -> None:
    rng = np.random.default_rng(n)
    for _ in range(50):
        accel = rng.integers(-FULL_SCALE + 1, FULL_SCALE, size=(n, 3))
        gyro = rng.integers(-FULL_SCALE + 1, FULL_SCALE, size=(n, 3))
        for data in (accel, gyro):  # a few values at either end of the range
            k = int(rng.integers(0, 3))
            data.flat[rng.choice(data.size, size=k, replace=False)] = rng.choice(
                [-FULL_SCALE, FULL_SCALE], size=k
            )
        raw = RawBatch(
            n,
            {
                Channel.ACCEL: RawChannel(accel, 1e-3, FULL_SCALE),
                Channel.GYRO: RawChannel(gyro, 1e-3, FULL_SCALE),
                Channel.TEMPERATURE: RawChannel(np.full(n, 40000), 0.01),  # no full scale
            },
            FifoRead(0, 1),
        )
        want = (np.abs(accel) >= FULL_SCALE).any(axis=1) * int(SampleFlag.ACCEL_SATURATED) | (
            np.abs(gyro) >= FULL_SCALE
        ).any(axis=1) * int(SampleFlag.GYRO_SATURATED)
        got = sample_flags(raw)
        if not want.any():
            assert got is None
        else:
            assert got is not None
            np.testing.assert_array_equal(got, want)
