"""What the streamed Allan deviation costs: --hours of six axes at 1 kHz (synthetic white noise,
fed in chunks of 131,072 samples as a recording's reader would), CPU time and peak RSS, and
allantools' oadev on one axis of the same length for comparison (--allantools).

    .venv/bin/python bench/noise_allan.py --hours 1 --allantools
"""

from __future__ import annotations

import argparse
import resource
import sys
import time

import numpy as np

from imud.noise.allan import StreamingAllan, lags


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--hours", type=float, default=1.0)
    p.add_argument("--allantools", action="store_true")
    args = p.parse_args(argv)
    n = int(args.hours * 3600 * 1000)
    chunk = 1 << 17
    block = np.random.default_rng(0).normal(0.0, 0.01, (chunk, 6))
    acc = StreamingAllan(1000.0, 6, lags(n))
    c0, w0 = time.process_time(), time.monotonic()
    fed = 0
    while fed < n:
        acc.feed(block)
        fed += chunk
    r = acc.result()
    cpu, wall = time.process_time() - c0, time.monotonic() - w0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"imud: {args.hours:g} h x 6 axes at 1 kHz ({fed:,} samples an axis, {r.m.size} taus): "
          f"CPU {cpu:.1f} s, wall {wall:.1f} s, peak RSS {rss:.0f} MB")  # fmt: skip
    if args.allantools:
        import allantools

        y = np.random.default_rng(1).normal(0.0, 0.01, n)
        c0 = time.process_time()
        allantools.oadev(y, rate=1000.0, data_type="freq", taus=r.tau_s)
        cpu = time.process_time() - c0
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"allantools oadev, one axis, the same taus: CPU {cpu:.1f} s, peak RSS {rss:.0f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
