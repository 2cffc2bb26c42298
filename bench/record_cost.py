"""What recording costs and what replay keeps up with, on the real daemon and the real CLI.

record: the quick start's config (configs/sim.toml, its listen endpoint moved to a free loopback
port) runs; `imud record -o FILE.mcap` records it for --seconds; the recorder's CPU is its
process's utime+stime over that window (/proc/<pid>/stat), its file's size is scaled to an hour,
and split per device by each device's share of the messages' bytes (ROS 2 messages with their
device's).

replay: an ICM-42688-P at 32 kHz is recorded for --seconds, then `imud replay --rate 10 --wait`
publishes it while a subscriber here counts the samples it gets: the replay's wall time against
the recording's span / 10, and the samples received against those in the file.

    .venv/bin/python bench/record_cost.py --seconds 20

Everything listens on 127.0.0.1 only.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

from common import free_port, imud_executable
from config_cpu import CLK_TCK, ticks
from daemon_cpu import wait_ready

ROOT = Path(__file__).resolve().parent.parent
FAST = """
[zenoh]
listen = ["{endpoint}"]

[[device]]
name = "fast0"
chip = "icm42688p"
bus = {{ kind = "sim", bus = "spiB", transport = "spi", cs = 0, speed_hz = 24_000_000 }}
odr_hz = 32000
"""


def run_daemon(text: str, tmp: Path, imud: str, endpoint: str) -> subprocess.Popen[bytes]:
    cfg = tmp / "imud.toml"
    cfg.write_text(text)
    log = (tmp / "imud.log").open("wb")
    proc = subprocess.Popen([imud, "run", "--config", str(cfg)], stdout=log, stderr=log)
    n = len(re.findall(r"^\[\[device\]\]", text, re.M))
    wait_ready(proc, imud, endpoint, n, timeout=90)
    return proc


def record(imud: str, endpoint: str, out: Path, seconds: float) -> tuple[float, float, str]:
    """(CPU seconds the recorder used once running, over how many seconds, its summary): its
    ticks from its first progress line (start-up done) to just before it exits."""
    p = subprocess.Popen(
        [imud, "record", "--connect", endpoint, "-o", str(out), "--duration", str(seconds)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert p.stderr is not None
    p.stderr.readline()  # the first progress line
    c0, t0 = ticks(p.pid), time.monotonic()
    c1, t1 = c0, t0
    reader = threading.Thread(target=p.stderr.read, daemon=True)
    reader.start()
    while p.poll() is None:  # its ticks just before it exits, as near as this can sample them
        c, t = ticks(p.pid), time.monotonic()
        if c >= c1:
            c1, t1 = c, t
        time.sleep(0.05)
    summary = p.stdout.read() if p.stdout else ""
    return (c1 - c0) / CLK_TCK, t1 - t0, summary


def per_device_bytes(path: Path) -> Counter[str]:
    from mcap.reader import make_reader

    out: Counter[str] = Counter()
    with open(path, "rb") as f:
        for _, ch, m in make_reader(f).iter_messages():
            if ch is None:
                continue
            parts = ch.topic.strip("/").split("/")
            device = parts[1] if parts[-1] == "batch" else parts[0]
            out[device] += len(m.data)
    return out


def bench_record(imud: str, seconds: float) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    text = re.sub(
        r"listen = \[[^\]]*\]", f'listen = ["{endpoint}"]', (ROOT / "configs/sim.toml").read_text()
    )
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        proc = run_daemon(text, tmp, imud, endpoint)
        try:
            time.sleep(3.0)
            out = tmp / "quick.mcap"
            cpu, window, summary = record(imud, endpoint, out, seconds)
            size = out.stat().st_size
            shares = per_device_bytes(out)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(20)
    total = sum(v for k, v in shares.items() if k != "diagnostics")
    print(f"record configs/sim.toml for {seconds:g} s ({os.cpu_count()} CPUs, load "
          f"{os.getloadavg()[0]:.2f}):")  # fmt: skip
    print(f"  recorder CPU {cpu:.2f} s over {window:.1f} s running = {cpu / window:.1%} of a core")
    print(f"  file {size / 1e6:.2f} MB = {size / seconds * 3600 / 1e6:.0f} MB an hour")
    for device, b in sorted(shares.items()):
        if device == "diagnostics":
            continue
        mb_h = size * b / total / seconds * 3600 / 1e6
        print(f"    {device:8s} {mb_h:7.1f} MB an hour")
    print("  " + summary.strip().replace("\n", "\n  "))


def bench_replay(imud: str, seconds: float) -> None:
    import imud.client as ic

    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        proc = run_daemon(FAST.format(endpoint=endpoint), tmp, imud, endpoint)
        try:
            time.sleep(2.0)
            out = tmp / "fast.mcap"
            _, _, summary = record(imud, endpoint, out, seconds)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(20)
        from imud.recording.reader import open_recording
        from imud.wire import peek

        rec = open_recording(out)
        spans = [(peek(w)[1], peek(w)[2], peek(w)[3]) for _, _, w in rec.batches()]
        in_file = sum(n for n, _, _ in spans)
        span_s = (spans[-1][2] - spans[0][1]) / 1e9
        rport = free_port()
        rend = f"tcp/127.0.0.1:{rport}"
        player = subprocess.Popen(
            [imud, "replay", str(out), "--rate", "10", "--wait", "--listen", rend],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        got = 0
        first = last = 0.0
        done = threading.Event()
        try:
            time.sleep(1.0)
            with ic.open_session(rend) as s:

                def on(sample: object) -> None:
                    nonlocal got, first, last
                    n = peek(sample.payload.to_bytes())[1]  # type: ignore[attr-defined]
                    now = time.monotonic()
                    first = first or now
                    last = now
                    got += n
                    if got >= in_file:
                        done.set()

                sub = s.declare_subscriber(ic.data_key("fast0"), on)
                player.wait(timeout=span_s + 60)
                done.wait(2.0)
                sub.undeclare()
        finally:
            player.kill()
    wall = last - first
    print(f"replay of a 32 kHz ICM-42688-P at 10x ({span_s:.1f} s recorded, {in_file:,} samples):")
    print(f"  wall {wall:.2f} s against {span_s / 10:.2f} s due; received {got:,} of {in_file:,} "
          f"({got / max(1, in_file):.2%}), {got / max(wall, 1e-9):,.0f} samples/s")  # fmt: skip
    print("  recorded: " + summary.strip().replace("\n", "; "))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--only", choices=["record", "replay"])
    args = p.parse_args(argv)
    imud = imud_executable()
    if args.only in (None, "record"):
        bench_record(imud, args.seconds)
    if args.only in (None, "replay"):
        bench_replay(imud, min(args.seconds, 10.0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
