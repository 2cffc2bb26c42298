"""A device's first minute in the quick start, start-up included: when its samples were lost.

Starts `imud run` on a copy of configs/sim.toml (a free loopback port, a fresh BNO055 offsets
file, as on a first start), subscribes to one device's stream at once and counts, per second
from launch, the samples it delivered and the samples each batch says were lost before it.
After `--seconds` it asks `imud status` for the device's own totals.

    .venv/bin/python bench/first_minute.py --device bno0
    PYTHONPATH=/tmp/before .venv/bin/python bench/first_minute.py --device bno0   # another tree

Scheduler-dependent: a measurement, never a test.
"""

from __future__ import annotations

import argparse
import collections
import signal
import sys
import tempfile
import time
from pathlib import Path

import zenoh
from common import imud_executable
from cpu_targets import ROOT, _started, env_for
from daemon_cpu import cli_status

import imud.client as ic
from imud.zsession import client_config


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="bno0")
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--tree", type=Path, default=ROOT, help="the source tree the daemon runs")
    args = p.parse_args()
    delivered: collections.Counter[int] = collections.Counter()
    lost: collections.Counter[int] = collections.Counter()
    with tempfile.TemporaryDirectory() as tmp:
        proc, endpoint = _started(ROOT / "configs/sim.toml", env_for(args.tree), Path(tmp))
        t0 = time.monotonic()
        try:
            while True:
                try:
                    # a client of that loopback endpoint only, multicast scouting off
                    session = zenoh.open(client_config(endpoint))
                    break
                except zenoh.ZError:
                    time.sleep(0.05)  # the daemon is not listening yet
            with session:
                while time.monotonic() - t0 < args.seconds:  # (a second without a batch ends
                    for b in ic.batches(session, args.device, timeout=1.0):  # the iteration)
                        second = int(time.monotonic() - t0)
                        delivered[second] += len(b.t_ns)
                        lost[second] += b.lost_before
                        if time.monotonic() - t0 > args.seconds:
                            break
            st = cli_status(imud_executable(), endpoint)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(20)
    print(" ".join(sys.argv))
    print(f"{args.device}, seconds from launch with a loss: delivered / lost")
    print("  " + "  ".join(f"{s}: {delivered[s]}/{lost[s]}" for s in sorted(lost) if lost[s]))
    print(f"  subscriber: delivered {sum(delivered.values())}, lost {sum(lost.values())}")
    if st is not None:
        d = next(d for d in st["devices"] if d["name"] == args.device)
        got, gone = d["samples"], d["lost_samples"]
        print(f"  status: samples {got}, lost {gone} ({gone / max(1, got + gone):.2%})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
