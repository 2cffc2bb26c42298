"""Where the BNO055's stamps over its UART come from: how closely the reads bound each sample.

Runs the driver and the pipeline on the virtual UART link of tests/test_bno055_uartpoll.py
(request in, the chip's snapshot 1-1.3 ms later, the answer and a 1 ms adapter frame after it;
each sample's index written into the accelerometer's x word). For every published sample k it
takes the bracket the sample clock was given and measures, against the link's true instants g_k:

- from above: t_after - g_k (the read says sample k came no later than t_after);
- from below: g_(k+1) - t_before (it says sample k+1 came no earlier than t_before).

The clock puts the stamps in the middle of what all reads allow together, so over a window of
reads the stamps sit about (closest from above - closest from below) / 2 off the truth: the
table prints both closest bounds per window, that half-difference, and the stamps' own error.

    .venv/bin/python bench/bno055_uart_bounds.py --seed 5 --period-ns 10280000 --seconds 60

Virtual time: the same figures on every run and machine.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--period-ns", type=int, default=10_280_000)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--windows", type=int, default=15)
    args = ap.parse_args()
    sys.path.insert(0, str(REPO))
    from imud.channels import Channel
    from tests.test_bno055_uartpoll import PHASE_NS, Rig

    rig = Rig(args.seed, args.period_ns)
    rows: list[tuple[int, int, int]] = []
    stamps: dict[int, int] = {}
    run = rig.pipe.run

    def spying(raw: Any) -> Any:
        out = run(raw)
        b = raw
        while b is not None:
            if b.n:
                k = round(float(b.channels[Channel.ACCEL].data[0, 0]))
                rows.append((k, b.timing.t_before_ns, b.timing.t_after_ns))
            b = b.then
        for s in out:
            if s.n:
                stamps[round(float(s.channels[Channel.ACCEL][0, 0]) * 100)] = int(s.t_ns[0])
        return out

    rig.pipe.run = spying  # type: ignore[method-assign]
    rig.run_until(args.seconds * 1e9)
    a = np.array(rows, dtype=np.float64)
    k, tb, ta = a.T
    period = args.period_ns
    g = PHASE_NS + k * period
    above, below = ta - g, g + period - tb
    err = np.array([stamps.get(int(x), np.nan) for x in k]) - g
    t = g / 1e9
    step = args.seconds / args.windows
    print(f"seed {args.seed}, period {period} ns, {len(k)} samples; µs:")
    print(" window       closest above  closest below  (above-below)/2  stamp error mean / max")
    for w0 in np.arange(0.0, args.seconds, step):
        m = (t > w0) & (t <= w0 + step)
        if not m.any():
            continue
        up, lo = above[m].min() / 1e3, below[m].min() / 1e3
        e = err[m] / 1e3
        print(
            f" {w0:5.1f}-{w0 + step:5.1f} s  {up:13.0f}  {lo:13.0f}  {(up - lo) / 2:15.0f}  "
            f"{np.nanmean(e):10.0f} / {np.nanmax(np.abs(e)):5.0f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
