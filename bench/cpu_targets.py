"""Issue 23's targets, before and after, in one run: two source trees measured in turn.

For each target the same measurement runs once with each tree's `imud` (the daemon started with
PYTHONPATH naming the tree, so its bus processes import it too), one after the other, and the
table prints both side by side with the machine's load average at each:

- the quick start (configs/sim.toml): CPU in all and the simulators' part (target <= 40 % of a
  core), and imud's own CPU per sample on each FIFO chip's bus (target <= 2 us at >= 1 kHz);
- all six chips at their top rates (configs/sim-all.toml): imud's own CPU without the
  simulators (target <= 15 % of a core), and the ICM-42688-P's bus process at 32 kHz with its
  simulator (target <= 20 %);
- the quick start's BNO055 over its UART over its first minute, start-up included: samples lost
  (target <= 1 %);
- the ADIS16465 alone at 2 kHz: samples lost (target 0 on an idle machine; the platform's floor
  is `bench/rt_latency.py --sleep-ms 0.3 --limits 0.45`);
- `imud status` wall time on the idle quick start (target <= 0.3 s) and with four busy processes
  beside it (target <= 2 s).

    git worktree add /tmp/before <commit>
    .venv/bin/python bench/cpu_targets.py --before /tmp/before --after . --seconds 20
    .venv/bin/python bench/cpu_targets.py --before . --after . --pure-before   # the kernels' part

Scheduler-dependent: a measurement, never a test (docs/performance.md section 19).
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from common import free_port, imud_executable
from config_cpu import Cost, measure
from daemon_cpu import cli_status, wait_ready

ROOT = Path(__file__).resolve().parent.parent
ADIS_ONLY = """\
[daemon]
realtime_priority = 20

[zenoh]
mode = "peer"
listen = ["tcp/127.0.0.1:7450"]
prefix = "imud"

[[device]]
name = "adis0"
chip = "adis16465"
bus = { kind = "sim", bus = "spi2", transport = "spi", cs = 0, speed_hz = 2_000_000 }
model = 3
dec_rate = 0
odr_hz = 2000
deltas = false

[device.sim]
seed = 7
motion = { kind = "tumble", rate_dps = [0.0, 0.0, 100.0] }
"""
Row = tuple[str, str, str]  # what, before, after


def env_for(tree: Path, pure: bool = False) -> dict[str, str]:
    """The environment that runs `tree`'s imud; `pure`: with the NumPy twins of its compiled
    kernels (imud.compiled)."""
    env = {**os.environ, "PYTHONPATH": str(tree.resolve())}
    env.pop("IMUD_PURE_PYTHON", None)
    return {**env, "IMUD_PURE_PYTHON": "1"} if pure else env


def _started(config: Path, env: dict[str, str], tmp: Path) -> tuple[subprocess.Popen[bytes], str]:
    """`imud run` on a copy of `config` on a free loopback port, its offsets files fresh (the
    first minute of a first start)."""
    imud = imud_executable()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    text = config.read_text().replace("tcp/127.0.0.1:7450", endpoint)
    text = text.replace("/tmp/imud-bno0.bno055-offsets.toml", str(tmp / "bno0-offsets.toml"))
    cfg = tmp / config.name
    cfg.write_text(text)
    log = (tmp / "imud.log").open("wb")
    proc = subprocess.Popen([imud, "run", "--config", str(cfg)], stdout=log, stderr=log, env=env)
    return proc, endpoint


def first_minute(env: dict[str, str], device: str, seconds: float = 60.0) -> tuple[int, int]:
    """(delivered, lost) of `device` over the quick start's first `seconds` from launch."""
    with tempfile.TemporaryDirectory() as tmp:
        proc, endpoint = _started(ROOT / "configs/sim.toml", env, Path(tmp))
        try:
            time.sleep(seconds)
            st = cli_status(imud_executable(), endpoint)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(20)
    assert st is not None, "no status"
    d = next(d for d in st["devices"] if d["name"] == device)
    return int(d["samples"]), int(d["lost_samples"])


def status_wall(env: dict[str, str], busy: int, asks: int = 10) -> list[float]:
    """Wall seconds of `imud status` on the running quick start, with `busy` spinning processes
    beside it."""
    imud = imud_executable()
    spin = [sys.executable, "-c", "while True: pass"]
    with tempfile.TemporaryDirectory() as tmp:
        proc, endpoint = _started(ROOT / "configs/sim.toml", env, Path(tmp))
        spinners: list[subprocess.Popen[bytes]] = []
        try:
            wait_ready(proc, imud, endpoint, 5, timeout=60)
            spinners = [subprocess.Popen(spin) for _ in range(busy)]
            time.sleep(3.0)
            walls = []
            for _ in range(asks):
                t0 = time.perf_counter()
                subprocess.run([imud, "status", "--connect", endpoint], capture_output=True)
                walls.append(time.perf_counter() - t0)
                time.sleep(0.3)
        finally:
            for s in spinners:
                s.kill()
            proc.send_signal(signal.SIGTERM)
            proc.wait(20)
    return walls


Tree = tuple[Path, bool]  # a source tree, and whether it runs its kernels' NumPy twins


def pair(what: Callable[[dict[str, str]], Any], trees: list[Tree]) -> list[tuple[Any, float]]:
    """`what` measured with each tree in turn, with the load average after each."""
    return [(what(env_for(t, pure)), os.getloadavg()[0]) for t, pure in trees]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", type=Path, required=True, help="the tree before (a worktree)")
    p.add_argument("--after", type=Path, default=ROOT)
    p.add_argument("--seconds", type=float, default=20.0, help="each CPU window")
    p.add_argument("--adis-seconds", type=float, default=60.0)
    p.add_argument(
        "--pure-before",
        action="store_true",
        help="the before tree runs its compiled kernels' NumPy twins (IMUD_PURE_PYTHON=1): "
        "with --before . --after ., the kernels' own effect",
    )
    args = p.parse_args()
    trees: list[Tree] = [(args.before, args.pure_before), (args.after, False)]
    rows: list[Row] = []

    def cell(v: str, load: float) -> str:
        return f"{v} (load {load:.1f})"

    qs: list[tuple[Cost, float]] = pair(
        lambda env: measure(ROOT / "configs/sim.toml", args.seconds, env=env), trees
    )
    rows.append(
        (
            "quick start: % of a core (simulators)",
            *(cell(f"{c.total:.1%} ({c.sim_total:.1%})", ld) for c, ld in qs),
        )
    )
    for key in qs[0][0].processes:
        if key == "daemon":
            continue
        names = ", ".join(qs[0][0].processes[key].devices)
        vals = []
        for c, ld in qs:
            pr = c.processes.get(key)
            us = "-" if pr is None or pr.own_us is None else f"{pr.own_us:.1f} us"
            vals.append(cell(us, ld))
        rows.append((f"quick start {names}: own CPU a sample", *vals))
    everything: list[tuple[Cost, float]] = pair(
        lambda env: measure(ROOT / "configs/sim-all.toml", args.seconds, env=env), trees
    )
    rows.append(
        (
            "all six at top rate: imud's own, % of a core",
            *(cell(f"{c.total - c.sim_total:.1%}", ld) for c, ld in everything),
        )
    )
    vals = []
    for c, ld in everything:
        icm = next(v for v in c.processes.values() if "icm0" in v.devices)
        vals.append(cell(f"{icm.share:.1%}", ld))
    rows.append(("ICM-42688-P at 32 kHz: its bus process, % of a core", *vals))
    vals = []
    for (got, lost), ld in pair(lambda env: first_minute(env, "bno0"), trees):
        vals.append(cell(f"lost {lost} of {got + lost} ({lost / max(1, got + lost):.2%})", ld))
    rows.append(("BNO055 over its UART, quick start's first minute", *vals))
    with tempfile.TemporaryDirectory() as tmp:
        adis = Path(tmp) / "adis.toml"
        adis.write_text(ADIS_ONLY)
        vals = []
        for c, ld in pair(lambda env: measure(adis, args.adis_seconds, env=env), trees):
            d = c.devices["adis0"]
            vals.append(cell(f"lost {d.lost} in {c.window_s:.0f} s ({d.lost_share:.3%})", ld))
        rows.append(("ADIS16465 alone at 2 kHz", *vals))
    for busy in (0, 4):
        vals = []
        for walls, ld in pair(lambda env, b=busy: status_wall(env, b), trees):
            vals.append(cell(f"median {statistics.median(walls):.2f} s, max {max(walls):.2f}", ld))
        rows.append((f"`imud status` wall, {busy} busy processes beside", *vals))
    print(" ".join(sys.argv))
    pure = ", NumPy twins" if args.pure_before else ""
    print(f"| target | before ({args.before}{pure}) | after ({args.after}) |")
    print("|---|---|---|")
    for what, before, after in rows:
        print(f"| {what} | {before} | {after} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
