"""`wire.gather`: a batch's channels side by side in one matrix, against the arrays encoded."""

from __future__ import annotations

import numpy as np
import pytest

from imud.channels import Channel
from imud.wire import KIND_SAMPLES, WireError, encode, gather


@pytest.mark.parametrize("n", [1, 7, 35])
def test_columns_hold_the_picked_components(n: int) -> None:
    rng = np.random.default_rng(n)
    accel = rng.normal(size=(n, 3)).astype(np.float32)
    quat = rng.normal(size=(n, 4)).astype(np.float32)  # w, x, y, z on the wire
    temp = rng.normal(size=n).astype(np.float32)
    t = 1_764_000_000_000_000_000 + 125_000 * np.arange(n)
    buf = encode("dev", 41, t, {Channel.ACCEL: accel, Channel.ORIENTATION: quat,
                                Channel.TEMPERATURE: temp})  # fmt: skip
    picks = (
        (Channel.TEMPERATURE, 0),
        (Channel.ORIENTATION, 1), (Channel.ORIENTATION, 2), (Channel.ORIENTATION, 3),
        (Channel.ORIENTATION, 0),
        (Channel.MAG, 0),  # not in the batch
        (Channel.ACCEL, 2),
    )  # fmt: skip
    kind, first, stamps, v = gather(buf, picks)
    assert (kind, first) == (KIND_SAMPLES, 41)
    np.testing.assert_array_equal(stamps, t)
    assert v.shape == (n, 7)
    np.testing.assert_array_equal(v[:, 0], temp)
    np.testing.assert_array_equal(v[:, 1:5], quat[:, [1, 2, 3, 0]])
    assert np.isnan(v[:, 5]).all()
    np.testing.assert_array_equal(v[:, 6], accel[:, 2])


def test_a_cut_batch_is_refused_naming_the_sizes() -> None:
    buf = encode("dev", 0, [1, 2], {Channel.GYRO: np.zeros((2, 3))})
    with pytest.raises(WireError, match="needs"):
        gather(buf[:-4], ((Channel.GYRO, 0),))
    with pytest.raises(WireError, match="too short"):
        gather(buf[:10], ((Channel.GYRO, 0),))
