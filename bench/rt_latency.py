"""How late this machine wakes a real-time thread: the floor under any FIFO-polling daemon.

A SCHED_FIFO thread (priority 20, like imud's bus workers) sleeps 1 ms at a time for `--seconds`
and records how much later than asked each sleep ends. No Python work happens in between, so
what it sees is the platform: timer resolution, the kernel scheduler and, on a VM, the hypervisor
taking the vCPU away. A poll that comes this late finds a FIFO that filled this much longer;
the ICM-42688-P's FIFO lasts 4 ms at 32 kHz, so wake-ups later than ~3 ms (4 ms less imud's 1 ms
poll interval) overflow it whatever the daemon does.

    .venv/bin/python bench/rt_latency.py --seconds 60      # needs root or CAP_SYS_NICE

A chip without a FIFO has one period less the read's time: the ADIS16465 at 2 kHz, polled just
after each sample, loses one to any wake-up later than about 0.45 ms:

    .venv/bin/python bench/rt_latency.py --seconds 300 --sleep-ms 0.3 --limits 0.45,1,3
"""

from __future__ import annotations

import argparse
import gc
import os
import shlex
import sys
import time

import numpy as np


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--priority", type=int, default=20)
    p.add_argument("--sleep-ms", type=float, default=1.0, help="each sleep asks for this long")
    p.add_argument("--limits", default="1,2,3,4", help="count wake-ups later than these (ms)")
    args = p.parse_args()
    print("command:", shlex.join([sys.executable, *sys.argv]))
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.priority))
    except PermissionError:
        print("cannot set SCHED_FIFO: run as root or with CAP_SYS_NICE", file=sys.stderr)
        return 2
    gc.freeze()
    gc.disable()
    ask_ns = int(args.sleep_ms * 1e6)
    late = np.zeros(int(args.seconds * 1.1e9 / ask_ns) + 10, dtype=np.int64)
    n = 0
    end = time.monotonic_ns() + int(args.seconds * 1e9)
    while n < late.size:
        t0 = time.monotonic_ns()
        if t0 > end:
            break
        time.sleep(ask_ns / 1e9)
        late[n] = time.monotonic_ns() - t0 - ask_ns
        n += 1
    x = late[:n] / 1e6
    q = np.percentile(x, [50, 99, 99.9, 99.99])
    print(f"{n} sleeps of {args.sleep_ms:g} ms in {args.seconds:g} s, lateness in ms:")
    print(f"  median {q[0]:.3f}  p99 {q[1]:.3f}  p99.9 {q[2]:.3f}  p99.99 {q[3]:.3f}  "
          f"max {x.max():.3f}")  # fmt: skip
    for limit in (float(v) for v in args.limits.split(",")):
        k = int((x > limit).sum())
        print(f"  later than {limit:g} ms: {k} ({k / args.seconds * 60:.1f} per minute)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
