"""The orientation filter's cost per sample, for one or more source trees side by side (each in
its own process, so each imports its own `imud`): the reference scenario's 60 s at 1 kHz fed in
batches of 1, 8, 32 and 128, best of 3 by process time.

    git worktree add /tmp/before HEAD~1
    .venv/bin/python bench/orient_cost.py /tmp/before .
"""

from __future__ import annotations

import subprocess
import sys

CHILD = r"""
import sys, time
sys.path.insert(0, sys.argv[1])
from imud.orient.ekf import NoiseModel, OrientationFilter
from imud.sim import scenarios
s = scenarios.reference(seed=0)
row = []
for batch in (1, 8, 32, 128):
    n = len(s.t_s) if batch > 1 else 20000
    best = float("inf")
    for _ in range(3):
        f = OrientationFilter(NoiseModel(s.gyro_density, s.accel_density))
        t0 = time.process_time()
        for i in range(0, n, batch):
            f.step(s.gyro[i : i + batch], s.accel[i : i + batch], s.dt)
        best = min(best, (time.process_time() - t0) / n * 1e6)
    row.append(f"{best:.2f}")
print(" | ".join(row))
"""


def main(argv: list[str]) -> int:
    trees = argv or ["."]
    print("| tree | µs a sample, batches of 1 | 8 | 32 | 128 |")
    print("|---|---|---|---|---|")
    for tree in trees:
        out = subprocess.run(
            [sys.executable, "-c", CHILD, tree], capture_output=True, text=True, check=True
        ).stdout.strip()
        print(f"| {tree} | {out} |")
    with open("/proc/loadavg") as f:
        print(f"\n1-minute load average after: {f.read().split()[0]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
