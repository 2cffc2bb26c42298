"""What a sensor_msgs/Imu message costs to serialise: imud's batch encoder (imud.ros2.cdr)
against rosbags' `serialize_cdr` one message at a time, for batches of the sizes a device hands
over (a 1 kHz chip read every 10 ms: 10; 8 kHz: 80).

    .venv/bin/python bench/ros2_cdr.py            # needs rosbags (the dev extra)
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from rosbags.typesys import Stores, get_typestore

from imud.ros2.cdr import layout, messages


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--messages", type=int, default=20_000)
    args = ap.parse_args()
    store = get_typestore(Stores.ROS2_JAZZY)
    t = store.types
    lay = layout("sensor_msgs/msg/Imu", "imu_link")
    cov = np.eye(3).ravel() * 1e-4
    for batch in (1, 10, 80):
        n = args.messages
        t_ns = 1_764_000_000_000_000_000 + 1_000_000 * np.arange(batch, dtype=np.int64)
        gyro = np.random.default_rng(1).normal(size=(batch, 3))
        accel = gyro + 9.8
        fields = {
            "orientation": np.zeros(4),
            "orientation_covariance": np.r_[-1.0, np.zeros(8)],
            "angular_velocity": gyro,
            "angular_velocity_covariance": cov,
            "linear_acceleration": accel,
            "linear_acceleration_covariance": cov,
        }
        start = time.perf_counter()
        for _ in range(n // batch):
            out = messages(lay, t_ns, fields)
            _ = [r.tobytes() for r in out]  # one bytes object a message, as published
        ours = (time.perf_counter() - start) / n * 1e6

        header = t["std_msgs/msg/Header"]
        stamp = t["builtin_interfaces/msg/Time"]
        vec, quat = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Quaternion"]
        imu = t["sensor_msgs/msg/Imu"]
        start = time.perf_counter()
        for _ in range(n // batch):
            for i in range(batch):
                sec, ns = divmod(int(t_ns[i]), 10**9)
                msg = imu(
                    header=header(stamp=stamp(sec=sec, nanosec=ns), frame_id="imu_link"),
                    orientation=quat(0.0, 0.0, 0.0, 0.0),
                    orientation_covariance=fields["orientation_covariance"],
                    angular_velocity=vec(*map(float, gyro[i])),
                    angular_velocity_covariance=cov,
                    linear_acceleration=vec(*map(float, accel[i])),
                    linear_acceleration_covariance=cov,
                )
                bytes(store.serialize_cdr(msg, "sensor_msgs/msg/Imu"))
        theirs = (time.perf_counter() - start) / n * 1e6
        print(f"batch {batch:3d}: imud.ros2.cdr {ours:6.2f} us/msg   rosbags {theirs:6.2f} us/msg")


if __name__ == "__main__":
    main()
