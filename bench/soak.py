"""Soak: the real daemon (`imud run`, one process per bus) on every simulated chip at its top
rate with faults on, for a long time (30 minutes by default), checking that every sample is
either delivered or counted as lost, that it recovers from every fault, and that its memory
does not grow.

The config is bench/configs/soak.toml (its comments say what each fault does); the bench moves
its Zenoh listener to a free loopback port. Every `--interval` seconds (10) it asks the daemon
for its status (the `<prefix>/daemon/status` query `imud status --json` makes, on the bench's own
Zenoh session) and reads the VmRSS of the daemon and of every bus process (`buses[].pid`) from
/proc/PID/status. A subscriber in this process takes every device's batches and keeps only their
headers (first seq, count, lost_before), so it costs little CPU.

Loss accounting, exact at every poll: the daemon counts a sample as published (`samples`) or
lost (`lost_samples`), and a batch's seq continues after the losses before it, so at any status
snapshot `mark = samples + lost_samples` is where the next batch's seq starts (a snapshot taken
mid-batch still lands on a batch boundary: the counts change only around whole batches). Between
two marks the seq numbers the subscriber never received are the losses on the wire; they must
equal the growth of `lost_samples` (batches dropped on the way to Zenoh, `publish_dropped`, are
the one other cause, and are reported). The bench checks this at every pair of polls once the
wire has passed the later mark, and over the whole run from the first poll to the last.

At the end it stops the daemon (SIGTERM), then prints and writes (`--out`, markdown) per device:
samples received, seq gaps on the wire, lost_samples, whether they agree, restarts, chip resets,
bus errors by kind; per bus: process restarts and their last error; per process: RSS at the start
(first poll with every device running), after warm-up (`--warmup`, 120 s) and at the end, and
how much of the growth is anonymous memory (RssAnon: heaps, not mapped files). The load average
(start, end) is printed too. bench/memwatch.py breaks one process's RSS down further (glibc's
heaps, other anonymous mappings).

Run from the repository root:

    .venv/bin/python bench/soak.py                          # 30 minutes
    .venv/bin/python bench/soak.py --minutes 2 --out /tmp/soak.md
    nohup .venv/bin/python bench/soak.py > /tmp/soak.log 2>&1 &

Everything listens on 127.0.0.1 only; multicast scouting is off.
"""

from __future__ import annotations

import argparse
import itertools
import os
import re
import shlex
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from array import array
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from common import free_port, imud_executable

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import imud.client as ic  # noqa: E402

DEFAULT_CONFIG = Path(__file__).resolve().parent / "configs" / "soak.toml"
PREFIX = "imud"
HEAD = struct.Struct("<4sBBHQII I")  # magic, version, kind, name_len, first_seq, count, flags, lost


@dataclass
class Stream:
    """The headers of one device's batches, in arrival order."""

    first: array[int] = field(default_factory=lambda: array("q"))
    count: array[int] = field(default_factory=lambda: array("q"))
    lost_before: int = 0  # summed over the batches
    out_of_order: int = 0  # a batch whose seq starts before the previous one ended
    lock: threading.Lock = field(default_factory=threading.Lock)

    def add(self, payload: bytes) -> None:
        _, _, _, _, first, n, _, lost = HEAD.unpack_from(payload)
        with self.lock:
            if self.first and first < self.first[-1] + self.count[-1]:
                self.out_of_order += 1
            self.first.append(first)
            self.count.append(n)
            self.lost_before += lost

    def on_sample(self, sample: Any) -> None:
        """A Zenoh callback (its thread): keep the header only."""
        self.add(sample.payload.to_bytes())

    def end(self) -> int:
        with self.lock:
            return self.first[-1] + self.count[-1] if self.first else -1

    def received_between(self, a: int, b: int) -> int:
        """Samples received with seq in [a, b)."""
        with self.lock:
            first = np.frombuffer(self.first, dtype=np.int64).copy()
            count = np.frombuffer(self.count, dtype=np.int64).copy()
        return int(np.clip(np.minimum(first + count, b) - np.maximum(first, a), 0, None).sum())

    def samples(self) -> int:
        with self.lock:
            return sum(self.count)


@dataclass
class Poll:
    t: float  # seconds since the daemon started
    status: dict[str, Any]
    rss_kb: dict[str, tuple[int, int]]  # process ("daemon" or bus key) -> (pid, VmRSS kB)
    anon_kb: dict[str, int] = field(default_factory=dict)  # process -> RssAnon kB


def anon_kb(pid: int) -> int | None:
    """RssAnon: the heaps, stacks and mmapped buffers, not the mapped files (libraries)."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    m = re.search(r"^RssAnon:\s+(\d+) kB", text, re.M)
    return int(m.group(1)) if m else None


def rss_kb(pid: int) -> int | None:
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    m = re.search(r"^VmRSS:\s+(\d+) kB", text, re.M)
    return int(m.group(1)) if m else None


def rewrite_listen(text: str, endpoint: str) -> str:
    """The config with its [zenoh] listener moved to `endpoint` (loopback, a free port)."""
    new, n = re.subn(r"(?m)^listen\s*=.*$", f'listen = ["{endpoint}"]', text, count=1)
    if n != 1:
        raise SystemExit("the soak config needs a `listen = [...]` line in its [zenoh] table")
    return new


def mark(dev: dict[str, Any]) -> int:
    """Where the device's next batch's seq starts, by its counters."""
    return int(dev["samples"]) + int(dev["lost_samples"])


def loadavg() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--interval", type=float, default=10.0, help="status/RSS poll, seconds")
    ap.add_argument("--warmup", type=float, default=120.0, help="seconds before the second RSS")
    ap.add_argument("--out", type=Path, default=Path("/tmp/soak.md"), help="markdown report")
    ap.add_argument("--no-subscribe", action="store_true", help="no subscriber (finding leaks)")
    ap.add_argument(
        "--imud", help="command run instead of `imud` (e.g. a wrapper that profiles the daemon)"
    )
    args = ap.parse_args()

    work = Path(tempfile.mkdtemp(prefix="imud-soak-"))
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    cfg = work / "soak.toml"
    cfg.write_text(rewrite_listen(args.config.read_text(), endpoint))
    import tomllib

    names = [d["name"] for d in tomllib.loads(cfg.read_text())["device"]]
    log_path = work / "daemon.log"
    load_start = loadavg()
    print(f"soak: {args.minutes:g} min, config {args.config}, daemon log {log_path}, "
          f"load {load_start}", flush=True)  # fmt: skip
    t0 = time.monotonic()
    with open(log_path, "wb") as log_file:
        daemon = subprocess.Popen(
            [
                *(shlex.split(args.imud) if args.imud else [imud_executable()]),
                "run",
                "--config",
                str(cfg),
                "--log-level",
                "info",
            ],
            stdout=subprocess.DEVNULL,
            stderr=log_file,
        )
    streams = {n: Stream() for n in names}
    polls: list[Poll] = []
    try:
        session = None
        for _ in range(100):  # the daemon's listener comes up after its imports
            if daemon.poll() is not None:
                raise SystemExit(f"the daemon exited with {daemon.returncode}: see {log_path}")
            try:
                session = ic.open_session(endpoint)
                ic.get_status(session, PREFIX, timeout=1.0)
                break
            except ic.NoDaemon:
                time.sleep(0.3)
            except Exception:
                if session is not None:
                    session.close()  # type: ignore[no-untyped-call]
                    session = None
                time.sleep(0.3)
        if session is None:
            raise SystemExit(f"no daemon answered on {endpoint}: see {log_path}")
        subs = [
            session.declare_subscriber(ic.data_key(n, PREFIX), st.on_sample)
            for n, st in streams.items()
            if not args.no_subscribe
        ]
        end = t0 + args.minutes * 60.0
        next_poll = time.monotonic()
        while time.monotonic() < end:
            if daemon.poll() is not None:
                raise SystemExit(f"the daemon exited with {daemon.returncode}: see {log_path}")
            next_poll += args.interval
            try:
                st = ic.get_status(session, PREFIX, timeout=5.0)
            except ic.NoDaemon as e:
                print(f"{time.monotonic() - t0:7.1f} s  no status: {e}", flush=True)
            else:
                rss = {"daemon": (daemon.pid, rss_kb(daemon.pid) or 0)}
                for b in st["buses"]:
                    if b["pid"] is not None:
                        rss[b["bus"]] = (b["pid"], rss_kb(b["pid"]) or 0)
                anon = {k: anon_kb(pid) or 0 for k, (pid, _) in rss.items()}
                p = Poll(time.monotonic() - t0, st, rss, anon)
                polls.append(p)
                print(progress_line(p, streams), flush=True)
            time.sleep(max(0.0, min(next_poll, end) - time.monotonic()))
        time.sleep(2.0)  # batches in flight at the last poll
        for s in subs:
            s.undeclare()  # type: ignore[no-untyped-call]
        session.close()  # type: ignore[no-untyped-call]
    finally:
        load_end = loadavg()
        if daemon.poll() is None:
            daemon.send_signal(signal.SIGTERM)
            try:
                daemon.wait(15)
            except subprocess.TimeoutExpired:
                daemon.kill()
                daemon.wait()
    report = render(args, polls, streams, load_start, load_end, daemon.returncode, log_path)
    print(report)
    args.out.write_text(report)
    print(f"written to {args.out}; daemon log {log_path}")
    return 0


def progress_line(p: Poll, streams: dict[str, Stream]) -> str:
    devs = p.status["devices"]
    bad = [f"{d['name']}:{d['state']}" for d in devs if d["state"] != "running"]
    lost = sum(int(d["lost_samples"]) for d in devs)
    restarts = sum(int(b["restarts"]) for b in p.status["buses"])
    rss = " ".join(f"{k}={v[1] / 1024:.1f}" for k, v in p.rss_kb.items())
    return (f"{p.t:7.1f} s  recv {sum(s.samples() for s in streams.values())}  lost {lost}  "
            f"bus restarts {restarts}  {' '.join(bad) or 'all running'}  RSS MB {rss}")  # fmt: skip


def first_running(polls: list[Poll]) -> int:
    for i, p in enumerate(polls):
        if all(d["state"] == "running" for d in p.status["devices"]):
            return i
    return 0


def loss_check(
    polls: list[Poll], streams: dict[str, Stream], name: str
) -> tuple[int, int, int, int]:
    """(wire gaps, lost_samples growth, intervals that agree, intervals checked) from the first
    poll with every device running to the last poll the wire has passed."""
    idx = [i for i in range(first_running(polls), len(polls))]
    marks = [
        (mark(dev), dev) for i in idx for dev in polls[i].status["devices"] if dev["name"] == name
    ]
    st = streams[name]
    wire_end = st.end()
    marks = [(m, d) for m, d in marks if m <= wire_end]
    agree = checked = 0
    for (a, da), (b, db) in itertools.pairwise(marks):
        if b <= a:
            continue
        checked += 1
        gaps = (b - a) - st.received_between(a, b)
        agree += gaps == int(db["lost_samples"]) - int(da["lost_samples"])
    if len(marks) < 2:
        return 0, 0, agree, checked
    (a, da), (b, db) = marks[0], marks[-1]
    return (
        (b - a) - st.received_between(a, b),
        int(db["lost_samples"]) - int(da["lost_samples"]),
        agree,
        checked,
    )


def render(args: argparse.Namespace, polls: list[Poll], streams: dict[str, Stream], load_start: str,
           load_end: str, code: int | None, log_path: Path) -> str:  # fmt: skip
    if not polls:
        return f"no status was ever received; see {log_path}\n"
    last = polls[-1].status
    out = [
        f"Soak: {args.minutes:g} min of `imud run --config {args.config.name}` (one process per "
        f"bus), status and RSS every {args.interval:g} s; load average {load_start} at the start, "
        f"{load_end} at the end; daemon exit code {code}.",
        "",
        "| device | received | wire gaps | lost_samples (run) | agree | intervals agreeing | "
        "out of order | publish_dropped | restarts | resets | FIFO overflows | bus errors by kind "
        "| garbled |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for d in last["devices"]:
        n = d["name"]
        gaps, lost, agree, checked = loss_check(polls, streams, n)
        kinds = ", ".join(
            f"{k.removeprefix('bus_errors_')} {v}"
            for k, v in d.items()
            if k.startswith("bus_errors_") and v
        )
        st = streams[n]
        out.append(
            f"| {n} | {st.samples()} | {gaps} | {lost} (total {d['lost_samples']}) | "
            f"{'yes' if gaps == lost else 'NO'} | {agree}/{checked} | {st.out_of_order} | "
            f"{d['publish_dropped']} | {d['restarts']} | {d['resets']} | {d['fifo_overflows']} | "
            f"{kinds or '-'} | {d['garbled_transfers']} |"
        )
    out += ["", "| bus | process restarts | last error |", "|---|---|---|"]
    for b in last["buses"]:
        out.append(f"| {b['bus']} | {b['restarts']} | {b['last_error'] or '-'} |")
    out += [
        "",
        "| process | pid | RSS start (MB) | after warm-up (MB) | end (MB) "
        "| growth since warm-up (MB) | of which anonymous (MB) |",
        "|---|---|---|---|---|---|---|",
    ]
    i0 = first_running(polls)
    warm = next((p for p in polls if p.t >= polls[i0].t + args.warmup), polls[-1])
    for proc, (pid, end_kb) in polls[-1].rss_kb.items():
        same = [p for p in polls[i0:] if p.rss_kb.get(proc, (None, 0))[0] == pid]
        start_kb = same[0].rss_kb[proc][1]
        # a process started later (a restarted bus process) warms up from its own start
        warm_t = max(warm.t, same[0].t + args.warmup)
        wp = next((p for p in same if p.t >= warm_t), same[-1])
        w = wp.rss_kb[proc][1]
        anon = (polls[-1].anon_kb.get(proc, 0) - wp.anon_kb.get(proc, 0)) / 1024
        note = "" if same[0] is polls[i0] else f" (this process since {same[0].t:.0f} s)"
        out.append(
            f"| {proc}{note} | {pid} | {start_kb / 1024:.1f} | {w / 1024:.1f} | "
            f"{end_kb / 1024:.1f} | {(end_kb - w) / 1024:+.1f} | {anon:+.1f} |"
        )
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    os.chdir(ROOT)
    raise SystemExit(main())
