"""What the ROS 2 output costs the daemon per device: CPU seconds a second of stream, at 1, 2 and
8 kHz, averaged to 200 messages a second (the default) and every sample as a message.

The output runs in this process as in the daemon (imud.ros2.output.Ros2Output on a real Zenoh
session on loopback, with a second session subscribed to its keys the way rmw_zenoh subscribes)
and is fed 10 ms wire batches as the daemon's relay hands them over, as fast as it takes them.

    .venv/bin/python bench/ros2_output.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np
import zenoh

from imud.channels import Channel
from imud.config import parse_config
from imud.ros2.output import Ros2Output
from imud.wire import encode

_SPI = {"kind": "sim", "transport": "spi", "speed_hz": 24_000_000}
CHIPS = {
    1000: ("mpu6050", {"dlpf_hz": 188, "bus": {"kind": "sim"}}),
    2000: ("icm42688p", {"bus": _SPI}),
    8000: ("icm42688p", {"bus": _SPI}),
}


SUBSCRIBER = """
import json, os, sys, zenoh
conf = {"mode": "client", "connect": {"endpoints": [sys.argv[1]]},
        "scouting": {"multicast": {"enabled": False}}}
s = zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))
n = [0]
sub = s.declare_subscriber("0/imu0/**", lambda x: n.__setitem__(0, n[0] + 1))
print("ready", flush=True)
sys.stdin.read()
print(n[0], flush=True)
os._exit(0)  # no orderly close of the session: nothing is left to receive
"""


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run(odr: int, rate_hz: float, seconds: float, port: int) -> float:
    chip, extra = CHIPS[odr]
    cfg = parse_config(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{port}"]},
            "ros2": {"enabled": True, "rate_hz": rate_hz, "domain_id": 0},
            "device": [{"name": "imu0", "chip": chip, "odr_hz": odr, **extra}],
        }
    )
    conf = {"mode": "peer", "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
            "scouting": {"multicast": {"enabled": False}}}  # fmt: skip
    pub_session = zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))
    # the subscriber in a process of its own: its receiving is not the output's cost
    sub = subprocess.Popen(
        [sys.executable, "-c", SUBSCRIBER, f"tcp/127.0.0.1:{port}"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert sub.stdout is not None and sub.stdout.readline().strip() == "ready"
    out = Ros2Output(cfg, pub_session)
    n = odr // 100  # a 10 ms batch
    rng = np.random.default_rng(1)
    chans = {
        Channel.ACCEL: rng.normal(size=(n, 3)).astype(np.float32),
        Channel.GYRO: rng.normal(size=(n, 3)).astype(np.float32),
        Channel.TEMPERATURE: np.full(n, 25.0, np.float32),
    }
    period = 1_000_000_000 // odr
    batches = [
        encode("imu0", i * n, 1_764_000_000_000_000_000 + period * (i * n + np.arange(n)), chans)
        for i in range(int(seconds * 100))
    ]
    time.sleep(0.5)  # the subscriber's declaration reaches the publisher
    start = _cpu()
    for b in batches:
        out.batch("imu0", b)
    used = _cpu() - start
    time.sleep(0.5)
    received, _ = sub.communicate("", timeout=30)
    out.close()
    pub_session.close()
    assert int(received) > 0, "the subscriber received nothing"
    return used / seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=20.0)
    args = ap.parse_args()
    port = 17490
    run(1000, 200.0, 1.0, port)  # warm-up: imports, first declarations
    print(f"{args.seconds:g} s of stream per case; % of one core (CPU s per stream s)")
    for odr in (1000, 2000, 8000):
        for rate in (200.0, float(odr)):
            port += 1
            share = run(odr, rate, args.seconds, port)
            label = "every sample" if rate == odr else f"averaged to {rate:g} Hz"
            print(f"  {odr:5d} Hz, {label:22s} {100 * share:5.1f} %")


if __name__ == "__main__":
    main()
