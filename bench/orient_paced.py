"""The orientation stage's own cost a sample, paced as the daemon runs it, for source trees side
by side: bench/bus_stages.py on one bus (default: bench/configs/orient1k.toml, an MPU6050 at
1 kHz with the filter on, batches of ~22 samples), the stage wrapped, each tree in its own
process (its `imud` first on the path), the trees taking turns for `--rounds` rounds so a
change in the machine's load falls on both.

    git worktree add /tmp/before HEAD~1      # and build its kernels (docs/performance.md)
    .venv/bin/python bench/orient_paced.py /tmp/before . --rounds 4 --seconds 10

Prints each round's microseconds a sample (the stage's thread CPU less the simulators', with
the wrapper's ~1 us a call), their median per tree, and the load average.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
STAGE = "imud.orient.stage:OrientationStage.run"


def has_kernels(tree: Path) -> bool:
    """Whether `tree` has its compiled kernels built (else it would run its NumPy twins)."""
    return any((tree / "imud").glob("_kernels*.so"))


def one(tree: Path, config: Path, bus: str, seconds: float) -> float:
    env = dict(os.environ, PYTHONPATH=str(tree.resolve()))
    cmd = [sys.executable, str(HERE / "bus_stages.py"), "--config", str(config), "--bus", bus]
    cmd += ["--seconds", str(seconds), "--wrap", STAGE]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
    row = re.search(re.escape(STAGE) + r"\s+([\d.]+)\s+(\d+)\s+([\d.]+)\s+([\d.]+)", out)
    if row is None:
        raise SystemExit(f"{tree}: no stage row in bus_stages' output:\n{out}")
    return float(row.group(4))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("trees", nargs="+", type=Path)
    p.add_argument("--config", type=Path, default=HERE / "configs" / "orient1k.toml")
    p.add_argument("--bus", default="sim:sim0")
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--rounds", type=int, default=4)
    a = p.parse_args()
    for t in a.trees:
        if not has_kernels(t):
            print(f"{t}: no compiled kernels built, it runs its NumPy twins (docs/performance.md,")
            print("  'Compiled kernels': building them in a worktree)")
    runs: dict[Path, list[float]] = {t: [] for t in a.trees}
    for _ in range(a.rounds):
        for t in a.trees:
            runs[t].append(one(t, a.config, a.bus, a.seconds))
    print(" ".join(sys.argv), f"(load average {os.getloadavg()[0]:.2f})")
    print(f"  {'tree':30s} {'us a sample, each round':36s} {'median':>7s}")
    for t, r in runs.items():
        each = " ".join(f"{x:.2f}" for x in r)
        print(f"  {t!s:30s} {each:36s} {statistics.median(r):7.2f}")


if __name__ == "__main__":
    main()
