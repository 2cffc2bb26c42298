"""What `imud noise` costs.

In memory (the Allan sums alone): --hours of six axes at 1 kHz of synthetic white noise, fed in
chunks of 131,072 samples as a reader would, CPU time and peak RSS, and allantools' oadev on one
axis of the same length for comparison (--allantools):

    .venv/bin/python bench/noise_allan.py --hours 1 --allantools

From files (the whole command, reading included): --make writes a still recording of
--file-hours at 1 kHz into DIR once (an MCAP file as `imud record` writes it, 20-sample batches
of an MPU6050's gyro, accelerometer and temperature, and imud's documented CSV of the same
samples: timestamp_ns,ax,ay,az,gx,gy,gz; existing files are kept, so they are generated once and
reused), and --measure runs `imud noise FILE --json` on each file in a child process and reports
its wall time, CPU and peak RSS (the child's own, from getrusage), and which CSV parser ran:

    .venv/bin/python bench/noise_allan.py --make /tmp/imud-noise --file-hours 24
    .venv/bin/python bench/noise_allan.py --measure /tmp/imud-noise/still-24h.mcap \\
        /tmp/imud-noise/still-24h.csv

Generated data stays out of the repository (it is GBs: a day is 3.7 GB of MCAP, 8.5 GB of CSV).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from imud.noise.allan import StreamingAllan, lags

RATE = 1000.0
BATCH = 20  # samples a batch: an MPU6050 at 1 kHz drains its FIFO about every 20 ms
BLOCK = 1_000_000  # samples generated at once (both files from the same blocks)
START_NS = 1_772_360_525_000_000_000
CONFIG = """[zenoh]
listen = ["tcp/127.0.0.1:7450"]

[[device]]
name = "imu0"
chip = "mpu6050"
bus = { kind = "sim", bus = "sim0", address = 0x68 }
odr_hz = 1000
dlpf_hz = 188
"""


def in_memory(hours: float, with_allantools: bool) -> None:
    n = int(hours * 3600 * RATE)
    chunk = 1 << 17
    block = np.random.default_rng(0).normal(0.0, 0.01, (chunk, 6))
    acc = StreamingAllan(RATE, 6, lags(n))
    c0, w0 = time.process_time(), time.monotonic()
    fed = 0
    while fed < n:
        acc.feed(block)
        fed += chunk
    r = acc.result()
    cpu, wall = time.process_time() - c0, time.monotonic() - w0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"imud: {hours:g} h x 6 axes at 1 kHz ({fed:,} samples an axis, {r.m.size} taus): "
          f"CPU {cpu:.1f} s, wall {wall:.1f} s, peak RSS {rss:.0f} MB")  # fmt: skip
    if with_allantools:
        import allantools

        y = np.random.default_rng(1).normal(0.0, 0.01, n)
        c0 = time.process_time()
        allantools.oadev(y, rate=RATE, data_type="freq", taus=r.tau_s)
        cpu = time.process_time() - c0
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"allantools oadev, one axis, the same taus: CPU {cpu:.1f} s, peak RSS {rss:.0f} MB")


def _blocks(n: int) -> object:
    """(t_ns, accel, gyro, temp) a block at a time: white noise (MPU6050-like: 0.05 deg/s and
    4 mg a sample), a gyro random walk, gravity on z, a temperature drifting slowly; float32
    as the daemon carries them."""
    rng = np.random.default_rng(22)
    walk = np.zeros(3)
    for i0 in range(0, n, BLOCK):
        k = min(BLOCK, n - i0)
        t = START_NS + np.arange(i0, i0 + k, dtype=np.int64) * 1_000_000
        rw = walk + np.cumsum(rng.normal(0.0, 2e-7, (k, 3)), axis=0)
        walk = rw[-1]
        bias = np.array([0.01, -0.004, 0.002])
        gyro = (rng.normal(0.0, 8.7e-4, (k, 3)) + rw + bias).astype(np.float32)
        accel = (rng.normal(0.0, 0.04, (k, 3)) + np.array([0.05, -0.1, 9.81])).astype(np.float32)
        temp = (30.0 + 5.0 * np.sin((i0 + np.arange(k)) / (RATE * 7200.0))).astype(np.float32)
        yield t, accel, gyro, temp


def make(out: Path, hours: float) -> tuple[Path, Path]:
    from imud.calib.csvio import CsvWriter
    from imud.channels import Channel
    from imud.recording.mcapfile import Attachment, McapOut
    from imud.recording.recorder import native_topic
    from imud.recording.schemas import BATCH as BATCH_TYPE
    from imud.recording.schemas import batch_cdr
    from imud.wire import encode

    out.mkdir(parents=True, exist_ok=True)
    n = int(hours * 3600 * RATE) // BATCH * BATCH
    stem = f"still-{hours:g}h"
    mcap, csv = out / f"{stem}.mcap", out / f"{stem}.csv"
    info = {"name": "imu0", "chip": "mpu6050", "odr_hz": RATE, "chip_rate_hz": RATE}
    w0 = time.monotonic()
    if not mcap.exists():
        topic = native_topic("imud", "imu0")
        now = [0.0]  # the recording's clock: a chunk a second of data, as `imud record` closes
        real_fsync = os.fsync  # its chunks (each also fsynced there: skipped here, the layout
        os.fsync = lambda fd: None  # is what is measured, not the disk)
        try:
            with McapOut(mcap, [Attachment("imud.toml", "application/toml", CONFIG.encode())],
                         {"imud.devices": {"imu0": json.dumps(info)}},
                         clock=lambda: now[0]) as m:  # fmt: skip
                for t, accel, gyro, temp in _blocks(n):  # type: ignore[attr-defined]
                    seq0 = int((t[0] - START_NS) // 1_000_000)
                    per_s = int(RATE)
                    for j0 in range(0, t.shape[0], per_s):
                        msgs = []
                        for j in range(j0, min(j0 + per_s, t.shape[0]), BATCH):
                            s = slice(j, j + BATCH)
                            chans = {Channel.ACCEL: accel[s], Channel.GYRO: gyro[s],
                                     Channel.TEMPERATURE: temp[s]}  # fmt: skip
                            msgs.append(batch_cdr(encode("imu0", seq0 + j, t[s], chans)))
                        log = t[j0 + BATCH - 1 : j0 + per_s : BATCH].astype(np.int64)
                        now[0] = (int(log[-1]) - START_NS) / 1e9
                        m.add_many(topic, BATCH_TYPE, log, b"".join(msgs), len(msgs[0]))
        finally:
            os.fsync = real_fsync
        print(f"{mcap}: {mcap.stat().st_size / 1e9:.2f} GB in {time.monotonic() - w0:.0f} s")
    w0 = time.monotonic()
    if not csv.exists():
        with CsvWriter(csv, comments={"device": "imu0", "chip": "mpu6050"}) as w:
            for t, accel, gyro, _ in _blocks(n):  # type: ignore[attr-defined]
                w.write(t, accel, gyro)
        print(f"{csv}: {csv.stat().st_size / 1e9:.2f} GB in {time.monotonic() - w0:.0f} s")
    return mcap, csv


def measure(path: Path) -> None:
    """`imud noise PATH --json` in a child: its wall time, CPU and peak RSS."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    w0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "imud", "noise", str(path), "--json"],
                       capture_output=True, text=True)  # fmt: skip
    wall = time.monotonic() - w0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    if r.returncode != 0:
        print(f"{path}: exit {r.returncode}: {r.stderr.strip()}")
        return
    out = json.loads(r.stdout)
    reader = out.get("reader") or {}
    size = os.path.getsize(path) / 1e9
    print(f"{path} ({size:.2f} GB): {out['samples']:,} samples, {len(out['tau_s'])} taus up to "
          f"{out['tau_s'][-1]:.0f} s; wall {wall:.1f} s, CPU {cpu:.1f} s, peak RSS "
          f"{after.ru_maxrss / 1024:.0f} MB; reader {reader.get('parser')} "
          f"({reader.get('read_s', 0):.1f} s reading)")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--hours", type=float, default=1.0, help="in memory: this long a record")
    p.add_argument("--allantools", action="store_true")
    p.add_argument("--make", type=Path, metavar="DIR", help="write still-<H>h.mcap and .csv")
    p.add_argument("--file-hours", type=float, default=24.0)
    p.add_argument("--measure", type=Path, nargs="+", metavar="FILE")
    args = p.parse_args(argv)
    if args.make is None and args.measure is None:
        in_memory(args.hours, args.allantools)
    if args.make is not None:
        make(args.make, args.file_hours)
    for path in args.measure or []:
        measure(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
