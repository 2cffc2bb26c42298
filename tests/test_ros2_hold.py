"""`[ros2] batch_ms`: the output holds a device's batches until that much of its stream has
arrived (by the samples' own stamps) and then publishes them in one step; what it publishes does
not depend on the hold. Real Zenoh sessions on loopback."""

from __future__ import annotations

import itertools
import json
import time

import numpy as np
import zenoh

from imud.channels import Channel
from imud.config import parse_config
from imud.ros2.output import Ros2Output
from imud.wire import encode
from tests.helpers import free_port

ODR = 1000
N = 7  # samples a batch: 7 ms of stream


def _batches(count: int) -> list[bytes]:
    rng = np.random.default_rng(3)
    out = []
    for i in range(count):
        seq = i * N + np.arange(N)
        t = 1_764_000_000_000_000_000 + 1_000_000 * seq
        chans = {
            Channel.ACCEL: rng.normal(size=(N, 3)).astype(np.float32),
            Channel.GYRO: rng.normal(size=(N, 3)).astype(np.float32),
            Channel.TEMPERATURE: np.full(N, 25.0, np.float32),
        }
        out.append(encode("imu0", i * N, t, chans))
    return out


def _run(batch_ms: float, batches: list[bytes]) -> tuple[list[int], list[bytes]]:
    """(messages received after each batch was fed, the messages' CDR as received)."""
    port = free_port()
    cfg = parse_config(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{port}"]},
            "ros2": {"enabled": True, "rate_hz": 200, "domain_id": 0, "connect": [],
                     "batch_ms": batch_ms},
            "device": [{"name": "imu0", "chip": "mpu6050", "odr_hz": ODR, "dlpf_hz": 188,
                        "bus": {"kind": "sim"}}],
        }
    )  # fmt: skip
    conf = {"mode": "peer", "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
            "scouting": {"multicast": {"enabled": False}}}  # fmt: skip
    got: list[bytes] = []
    with zenoh.open(zenoh.Config.from_json5(json.dumps(conf))) as s:
        sub = s.declare_subscriber(
            "0/imu0/imu/data_raw/**", lambda m: got.append(m.payload.to_bytes())
        )
        out = Ros2Output(cfg, s)
        after = []
        for b in batches:
            out.batch("imu0", b)
            after.append(out.messages()["/imu0/imu/data_raw"])
        end = time.monotonic() + 10  # a bound for a broken output, not a measurement
        while len(got) < after[-1] and time.monotonic() < end:
            time.sleep(0.01)
        out.close()
        sub.undeclare()
    return after, got


def test_held_steps_send_the_same_messages_as_every_batch() -> None:
    batches = _batches(40)  # 280 samples: 56 messages of 5
    every, msgs_every = _run(0, batches)
    held, msgs_held = _run(30, batches)
    # seq 279 ends group 55: every group is complete
    assert every[-1] == held[-1] == 56
    assert len(msgs_every) == len(msgs_held) == 56
    assert msgs_held == msgs_every
    # with no hold, each batch's completed groups go out with it
    assert every[0] == 1 and every[1] == 2  # seq 0-6: group 0; seq 7-13: group 1 (10-14 open)
    # a 30 ms hold: nothing until a batch ends 30 ms or more after the first held sample
    # (batch 4 ends at 34 ms), then everything complete so far at once
    assert held[:4] == [0, 0, 0, 0]
    assert held[4] == 7  # seq 0-34: groups 0-6
    steps = [b for a, b in itertools.pairwise(held) if b != a]
    assert len(steps) < len(batches) / 3
