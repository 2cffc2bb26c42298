"""The orientation stage in the device runner, against simulated chips at virtual time: what the
batches carry, how it shares the gyro bias with the tracker, status, config errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rich.console import Console

from imud.channels import INVALID_MASK, Channel
from imud.cli.status_view import status_view
from imud.config import parse_config
from imud.errors import ConfigError
from imud.orient import metrics as M
from imud.rotations import quat_from_euler_zyx
from imud.wire import Batch
from tests.helpers import make_rig

BIAS_DPS = (0.5, -0.3, 0.2)
TILT = (20.0, -10.0, 35.0)  # roll, pitch, yaw (deg)
# no deterministic error but the gyro's bias: the accelerometer's own bias would tilt the
# answer by as much as it is wrong (60 mg: 3.4 deg), which is the calibration's business
EXACT = {
    "accel_bias_mg": [0.0, 0.0, 0.0],
    "accel_scale_error": [0.0, 0.0, 0.0],
    "gyro_scale_error": [0.0, 0.0, 0.0],
    "misalignment_deg": 0.0,
    "accel_temp_drift_mg_per_c": [0.0, 0.0, 0.0],
    "gyro_temp_drift_dps_per_c": [0.0, 0.0, 0.0],
    "gyro_bias_instability_dph": 0.0,
    "accel_bias_instability_ug": 0.0,
    "gyro_bias_dps": list(BIAS_DPS),
}
TRACKED = {"enabled": True, "window_s": 0.5, "time_constant_s": 3.0, "confirm_s": 2.0}


def joined(batches: list[Batch], ch: Channel) -> np.ndarray:
    return np.concatenate([b.channels[ch] for b in batches]).astype(np.float64)


def test_a_still_tilted_chip_gets_its_orientation_and_one_gyro_bias() -> None:
    roll, pitch, yaw = TILT
    sim = {"seed": 3, "motion": {"kind": "still", "roll_deg": roll, "pitch_deg": pitch,
                                 "yaw_deg": yaw}, "errors": EXACT}  # fmt: skip
    rig = make_rig(
        {"odr_hz": 200, "dlpf_hz": 42, "gyro_bias_tracking": TRACKED,
         "orientation": {"enabled": True}},
        sim,
    )  # fmt: skip
    rig.run(30.0)
    batches = rig.batches()
    q = joined(batches, Channel.ORIENTATION)
    cov = joined(batches, Channel.ORIENTATION_COVARIANCE)
    flags = np.concatenate([b.sample_flags for b in batches])
    # its start: a second of samples without an orientation (NaN), not counted as invalid:
    # their accelerometer and gyro are as good as any (an export or a calibration keeps them)
    unset = np.isnan(q[:, 0])
    assert 150 <= unset.sum() <= 260 and unset[:150].all() and not unset[-1]
    assert not np.any(flags & INVALID_MASK) and rig.runner.status().invalid_samples == 0
    q, cov = q[~unset], cov[~unset]
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)  # float32 on the wire
    # gravity's direction is the simulator's pose; the heading is the start's (no magnetometer)
    truth = np.broadcast_to(quat_from_euler_zyx(roll, pitch, yaw), q.shape)
    tilt = M.tilt_error_deg(q, truth)
    assert tilt[-1000:].max() < 0.2
    # the covariance: positive tilt variances, the heading's growing only while the bias is
    # unknown; its tilt sigma covers the error
    assert np.all(cov[:, 0] > 0) and np.all(cov[:, 3] > 0)
    assert tilt[-1] < 3 * math.degrees(math.sqrt(cov[-1, 0] + cov[-1, 3]))
    # one bias: the filter learned it from the tracker's still windows, the tracker holds it,
    # the published gyro is corrected by it
    st = rig.runner.status()
    o, t = st.orientation, st.gyro_bias_tracking
    assert o is not None and t is not None
    want = np.radians(BIAS_DPS)
    np.testing.assert_allclose(o["bias_rad_s"], want, atol=math.radians(0.02))
    np.testing.assert_allclose(t["bias_rad_s"], o["bias_rad_s"], atol=1e-6)
    assert o["still_updates"] >= 40 and t["learned_windows"] == o["still_updates"]
    gyro = joined(batches, Channel.GYRO)
    assert np.abs(gyro[-1000:].mean(axis=0)).max() < math.radians(0.02)
    # the heading holds once the vertical bias is known (a still chip: only the still windows
    # teach it)
    yaw_est = M.yaw_deg(q)
    assert abs(yaw_est[-1] - yaw_est[-2000]) < 0.1
    # `imud status`
    console = Console(width=220, record=True)
    for r in status_view({"devices": [st.to_json()]}, "tcp/127.0.0.1:7450", console):
        console.print(r)
    assert "t0 orientation: running, heading relative to the start" in console.export_text()
    assert "orientation" in st.channels and "orientation_covariance" in st.channels


def test_without_tracking_the_gyro_is_published_as_measured() -> None:
    sim = {"seed": 5, "motion": {"kind": "still"}, "errors": EXACT}
    # tracking off, its stillness settings still used by the filter's own tests
    off = {**TRACKED, "enabled": False}
    rig = make_rig(
        {"odr_hz": 200, "gyro_bias_tracking": off, "orientation": {"enabled": True}}, sim
    )
    rig.run(20.0)
    st = rig.runner.status()
    assert st.gyro_bias_tracking is None and st.orientation is not None
    # the filter learned the bias from its own stillness tests...
    np.testing.assert_allclose(
        st.orientation["bias_rad_s"], np.radians(BIAS_DPS), atol=math.radians(0.03)
    )
    # ...and the gyro stream is left alone: it still carries the bias
    gyro = joined(rig.batches(), Channel.GYRO)
    np.testing.assert_allclose(gyro[-1000:].mean(axis=0), np.radians(BIAS_DPS), atol=1e-3)


def test_a_tumbling_chip_keeps_a_unit_orientation_and_a_sane_covariance() -> None:
    sim = {"seed": 6, "motion": {"kind": "tumble", "rate_dps": [40.0, -25.0, 60.0]}}
    rig = make_rig({"odr_hz": 1000, "orientation": {"enabled": True}}, sim)
    rig.run(5.0)
    q = joined(rig.batches(), Channel.ORIENTATION)
    cov = joined(rig.batches(), Channel.ORIENTATION_COVARIANCE)
    ok = ~np.isnan(q[:, 0])
    assert ok.sum() > 3000
    assert np.allclose(np.linalg.norm(q[ok], axis=1), 1.0, atol=1e-6)
    assert np.isfinite(cov[ok]).all() and (cov[ok][:, [0, 3, 5]] >= 0).all()


@pytest.mark.parametrize(
    ("device", "words"),
    [
        (
            {"chip": "bno055", "orientation": {"enabled": True}},
            ["orientation.enabled", "own orientation", "enabled = false"],
        ),
        ({"chip": "mpu6050", "orientation": {"enabled": True, "update_hz": 0}}, ["update_hz"]),
        ({"chip": "mpu6050", "orientation": {"enable": True}}, ["orientation", "enable"]),
    ],
)
def test_config_errors_name_the_field(device: dict[str, object], words: list[str]) -> None:
    with pytest.raises((ConfigError, ValueError)) as e:
        parse_config({"device": [{"name": "t0", "bus": {"kind": "sim"}, **device}]})
    for w in words:
        assert w in str(e.value)


def test_imu_data_carries_the_orientation_and_its_covariance_per_message() -> None:
    """The ROS 2 side: a device with the filter gets imu/data (sensor_msgs/Imu) beside
    imu/data_raw; each message's orientation is x, y, z, w of the wire's w, x, y, z and its
    orientation_covariance the wire's six values as a symmetric row-major 3 x 3 (parsed by the
    hand-written CDR reader of the rmw_zenoh test)."""
    from imud.ros2.messages import Ros2Messages
    from imud.wire import encode
    from tests.test_ros2_daemon import parse_imu

    cfg = parse_config(
        {
            "ros2": {"enabled": True, "rate_hz": 1000, "connect": []},
            "device": [{"name": "imu0", "chip": "mpu6050", "odr_hz": 1000, "dlpf_hz": 188,
                        "bus": {"kind": "sim"}, "orientation": {"enabled": True}}],
        }
    )  # fmt: skip
    got: dict[str, list[bytes]] = {}
    msgs = Ros2Messages(
        cfg, lambda topic, p: got.setdefault(topic.name, []).extend(p), diagnostics=False
    )
    n = 4
    rng = np.random.default_rng(1)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[0] = np.nan  # the filter's start: no orientation for this sample
    cov = rng.uniform(1e-6, 1e-5, size=(n, 6))
    chans = {
        Channel.ACCEL: rng.normal(size=(n, 3)),
        Channel.GYRO: rng.normal(size=(n, 3)),
        Channel.TEMPERATURE: np.full(n, 25.0),
        Channel.ORIENTATION: q,
        Channel.ORIENTATION_COVARIANCE: cov,
    }
    t = 1_764_000_000_000_000_000 + 1_000_000 * np.arange(n)
    msgs.batch("imu0", encode("imu0", 0, t, {c: a.astype(np.float32) for c, a in chans.items()}))
    msgs.flush()
    raw = [parse_imu(b) for b in got["/imu0/imu/data_raw"]]
    fused = [parse_imu(b) for b in got["/imu0/imu/data"]]
    assert len(raw) == n and len(fused) == n - 1  # none for the sample without one
    assert all(m["orientation_covariance"][0] == -1.0 for m in raw)
    for m, i in zip(fused, range(1, n), strict=True):
        w, x, y, z = q[i].astype(np.float32)
        np.testing.assert_allclose(m["orientation"], [x, y, z, w], rtol=1e-6)
        xx, xy, xz, yy, yz, zz = cov[i].astype(np.float32)
        want = [xx, xy, xz, xy, yy, yz, xz, yz, zz]
        np.testing.assert_allclose(m["orientation_covariance"], want, rtol=1e-6)
