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
from dataclasses import dataclass, field
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


@dataclass
class Process:
    share: float  # of a core, from /proc
    devices: list[str]
    sim: float | None = None  # the simulators' part, from the bus process's own reports
    own: float | None = None
    own_us: float | None = None  # imud's own CPU per sample, us


@dataclass
class Device:
    rate: float  # samples/s
    lost: int
    lost_share: float


@dataclass
class Cost:
    load: float  # the machine's 1-minute load average at the end
    window_s: float
    processes: dict[str, Process] = field(default_factory=dict)
    devices: dict[str, Device] = field(default_factory=dict)

    @property
    def total(self) -> float:
        return sum(p.share for p in self.processes.values())

    @property
    def sim_total(self) -> float:
        return sum(p.sim or 0.0 for p in self.processes.values())


def measure(
    config: Path, seconds: float, warmup: float = 5.0, env: dict[str, str] | None = None
) -> Cost:
    """Run `imud run` on a copy of `config` (listening on a free loopback port; `env` for the
    daemon, e.g. PYTHONPATH naming another source tree) and measure a window of `seconds`."""
    imud = imud_executable()
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    text = re.sub(r"listen = \[[^\]]*\]", f'listen = ["{endpoint}"]', config.read_text())
    n = len(re.findall(r"^\[\[device\]\]", text, re.M))
    with tempfile.TemporaryDirectory() as tmp:
        cfg = Path(tmp) / config.name
        cfg.write_text(text)
        log = (Path(tmp) / "imud.log").open("wb")
        proc = subprocess.Popen(
            [imud, "run", "--config", str(cfg)], stdout=log, stderr=log, env=env
        )
        try:
            wait_ready(proc, imud, endpoint, n, timeout=60)
            time.sleep(warmup)
            s0 = cli_status(imud, endpoint)
            assert s0 is not None, "no status"
            pids: dict[str, int | None] = {"daemon": proc.pid}
            pids |= {b["bus"]: b["pid"] for b in s0.get("buses", [])}
            c0, t0 = {k: ticks(v) for k, v in pids.items()}, time.monotonic()
            time.sleep(seconds)
            c1, t1 = {k: ticks(v) for k, v in pids.items()}, time.monotonic()
            s1 = cli_status(imud, endpoint)
            assert s1 is not None, "no status"
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(20)
    return cost(s0, s1, pids, c0, c1, t1 - t0)


def cost(
    s0: dict[str, Any],
    s1: dict[str, Any],
    pids: dict[str, int | None],
    c0: dict[str, int],
    c1: dict[str, int],
    dt: float,
) -> Cost:
    out = Cost(os.getloadavg()[0], dt)
    before = {d["name"]: d for d in s0["devices"]}
    span = s1["uptime_s"] - s0["uptime_s"]  # between the two answers, by the daemon's clock
    buses0 = {b["bus"]: b for b in s0.get("buses", [])}
    buses1 = {b["bus"]: b for b in s1.get("buses", [])}
    for key in pids:
        devs = [d for d in s1["devices"] if on_bus(key, d["bus"])]
        p = Process((c1[key] - c0[key]) / CLK_TCK / dt, [d["name"] for d in devs])
        b0, b1 = buses0.get(key, {}), buses1.get(key, {})
        if b0.get("sim_cpu_s") is not None and b1.get("sim_cpu_s") is not None:
            # both from the bus process's own reports, so they cover the same span
            cpu = (b1["cpu_s"] - b0["cpu_s"]) / span
            p.sim = (b1["sim_cpu_s"] - b0["sim_cpu_s"]) / span
            p.own = cpu - p.sim
            got = sum(d["samples"] - before[d["name"]]["samples"] for d in devs)
            p.own_us = p.own * span / max(got, 1) * 1e6
        out.processes[key] = p
    for d in s1["devices"]:
        b = before[d["name"]]
        got = d["samples"] - b["samples"]
        lost = d["lost_samples"] - b["lost_samples"]
        out.devices[d["name"]] = Device(got / span, lost, lost / max(1, got + lost))
    return out


def report(config: Path, warmup: float, c: Cost) -> None:
    print(f"{config}: {c.window_s:.0f} s window after {warmup:g} s, "
          f"{os.cpu_count()} CPUs, load {c.load:.2f}")  # fmt: skip
    print("  % of a core: process (from /proc) | simulators | imud's own, and its us a sample")
    for key, p in c.processes.items():
        split = ""
        if p.sim is not None and p.own is not None and p.own_us is not None:
            split = f" | sim {p.sim:6.1%} | own {p.own:6.1%}, {p.own_us:5.1f} us a sample"
        print(f"  {p.share:6.1%}{split}  {key:12s} {', '.join(p.devices)}")
    print(f"  {c.total:6.1%} of a core in all, of which simulators {c.sim_total:.1%}")
    for name, d in c.devices.items():
        print(f"  {name:8s} {d.rate:10.1f} samples/s  lost {d.lost} ({d.lost_share:.2%})")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", type=Path, required=True)
    p.add_argument("--seconds", type=float, default=15.0, help="measurement window")
    p.add_argument("--warmup", type=float, default=5.0, help="seconds between ready and window")
    args = p.parse_args(argv)
    report(args.config, args.warmup, measure(args.config, args.seconds, args.warmup))
    return 0


if __name__ == "__main__":
    sys.exit(main())
