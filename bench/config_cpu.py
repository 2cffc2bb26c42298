"""What a config costs: CPU per bus process, delivery and loss per device, of the real daemon.

Copies the config with its Zenoh listen endpoint moved to a free loopback port, starts `imud run`
on it, waits until every device runs, lets it settle, then over the window reads each process's
utime+stime from /proc/<pid>/stat (the daemon and each bus process, whose pids and buses the
status queryable names) and each device's samples and lost samples from `imud status --json`.
Simulators run inside the bus processes; each bus process reports its CPU time and the
simulators' part of it (`imud/sim/cpu.py`), so the table splits each process into the two and
gives imud's own cost per sample.

    .venv/bin/python bench/config_cpu.py --config configs/sim.toml
    .venv/bin/python bench/config_cpu.py --config configs/sim-all.toml --seconds 20

Run as root for the configs' real-time bus workers (as an ordinary user the daemon says so and
runs them at normal priority). Everything listens on 127.0.0.1 only.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from common import free_port, imud_executable
from daemon_cpu import cli_status, wait_ready

CLK_TCK = os.sysconf("SC_CLK_TCK")


def ticks(pid: int | None) -> int:
    """utime + stime of one process, all its threads (fields 14 and 15 of /proc/<pid>/stat)."""
    if pid is None:
        return 0
    try:
        f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0
    return int(f[11]) + int(f[12])


def on_bus(key: str, described: str) -> bool:
    """Whether a device whose status describes its buses as `described` (e.g. "sim-spi:spi1@cs0
    + sim-spi:spi1@cs1") is on the bus worker `key` (e.g. "sim:spi1")."""
    return key.split(":", 1)[-1] in re.findall(r":([^@+ ]+)", described)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", type=Path, required=True)
    p.add_argument("--seconds", type=float, default=15.0, help="measurement window")
    p.add_argument("--warmup", type=float, default=5.0, help="seconds between ready and window")
    args = p.parse_args(argv)
    imud = imud_executable()
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    text = re.sub(r"listen = \[[^\]]*\]", f'listen = ["{endpoint}"]', args.config.read_text())
    n = len(re.findall(r"^\[\[device\]\]", text, re.M))
    with tempfile.TemporaryDirectory() as tmp:
        cfg = Path(tmp) / args.config.name
        cfg.write_text(text)
        log = (Path(tmp) / "imud.log").open("wb")
        proc = subprocess.Popen([imud, "run", "--config", str(cfg)], stdout=log, stderr=log)
        try:
            wait_ready(proc, imud, endpoint, n, timeout=60)
            time.sleep(args.warmup)
            s0 = cli_status(imud, endpoint)
            assert s0 is not None, "no status"
            pids: dict[str, int | None] = {"daemon": proc.pid}
            pids |= {b["bus"]: b["pid"] for b in s0.get("buses", [])}
            c0, t0 = {k: ticks(v) for k, v in pids.items()}, time.monotonic()
            time.sleep(args.seconds)
            c1, t1 = {k: ticks(v) for k, v in pids.items()}, time.monotonic()
            s1 = cli_status(imud, endpoint)
            assert s1 is not None, "no status"
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(20)
    report(args, s0, s1, pids, c0, c1, t1 - t0)
    return 0


def report(
    args: argparse.Namespace,
    s0: dict[str, Any],
    s1: dict[str, Any],
    pids: dict[str, int | None],
    c0: dict[str, int],
    c1: dict[str, int],
    dt: float,
) -> None:
    print(f"{args.config}: {args.seconds:g} s window after {args.warmup:g} s, "
          f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}")  # fmt: skip
    total = sim_total = 0.0
    before = {d["name"]: d for d in s0["devices"]}
    span = s1["uptime_s"] - s0["uptime_s"]  # between the two answers, by the daemon's clock
    buses0 = {b["bus"]: b for b in s0.get("buses", [])}
    buses1 = {b["bus"]: b for b in s1.get("buses", [])}
    print("  % of a core: process (from /proc) | simulators | imud's own, and its us a sample")
    for key in pids:
        share = (c1[key] - c0[key]) / CLK_TCK / dt
        total += share
        devs = [d for d in s1["devices"] if on_bus(key, d["bus"])]
        names = ", ".join(d["name"] for d in devs)
        split = ""
        b0, b1 = buses0.get(key, {}), buses1.get(key, {})
        if b0.get("sim_cpu_s") is not None and b1.get("sim_cpu_s") is not None:
            # both from the bus process's own reports, so they cover the same span
            cpu = (b1["cpu_s"] - b0["cpu_s"]) / span
            sim = (b1["sim_cpu_s"] - b0["sim_cpu_s"]) / span
            sim_total += sim
            got = sum(d["samples"] - before[d["name"]]["samples"] for d in devs)
            per = (cpu - sim) * span / max(got, 1) * 1e6
            split = f" | sim {sim:6.1%} | own {cpu - sim:6.1%}, {per:5.1f} us a sample"
        print(f"  {share:6.1%}{split}  {key:12s} {names}")
    print(f"  {total:6.1%} of a core in all, of which simulators {sim_total:.1%}")
    for d in s1["devices"]:
        b = before[d["name"]]
        got = d["samples"] - b["samples"]
        lost = d["lost_samples"] - b["lost_samples"]
        share = lost / max(1, got + lost)
        print(f"  {d['name']:8s} {got / span:10.1f} samples/s  lost {lost} ({share:.2%})")


if __name__ == "__main__":
    sys.exit(main())
