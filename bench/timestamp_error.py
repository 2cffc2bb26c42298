"""Stamp error against the simulators' ground truth: imud's sample-clock fit beside the naive
method (read time minus n nominal periods), on the same reads.

Every simulated chip publishes its true sample instants on `<prefix>/<device>/sim/truth` when its
config says `truth = true`; a published stamp less the true instant of the sample its `seq`
names is the stamp's error. For each device, after a settle (5 s by default, counted from its
first published sample), it prints the mean, RMS and largest stamp error, the number of stamps
not after the one before (backwards steps), and the largest relative deviation of consecutive
stamp differences (successive seq) from the period: the fitted one (`chip_rate_hz` at the end)
for imud's, the nominal one for the naive stamps. `seq` is matched to the truth index by one
offset per device (the median over the settled samples of the nearest true instant's index less
seq), so a gap miscounted by a sample shows as a period of error.

The naive stamps are reconstructed from what the pipeline saw: a hook on
`imud.timestamps.SampleClock.update` records each read's n samples, end of the FIFO count read
(t_after) and first seq, so sample i of the read is stamped t_after - (n - 1 - i) nominal periods,
less the driver's declared filter group delay (the same convention as imud's stamps, so the two
differ only in how the sample clock is estimated). The daemon is `imud run` with its defaults (one
process per bus, no real-time priority); the hook reaches its bus processes through a
`sitecustomize` module on the PYTHONPATH the bench gives them (each process appends its reads to a
file), so both sets of stamps come from the same reads. This process subscribes over loopback
Zenoh. `--virtual` runs each I2C/SPI device alone at virtual time instead (no scheduler: the
estimator's own error) with a uniform poll jitter and a modelled SPI transfer time; the serial
chips are left out there (their links are real pseudo-terminals). The STIM300's "naive" read time
is its driver's bracket, already moved back by the datagram's latency field and wire time.

Run from the repository root:

    .venv/bin/python bench/timestamp_error.py                       # 45 s: 5 s settle + 40 s
    .venv/bin/python bench/timestamp_error.py --faults              # + bus faults and 3 ms stalls
    .venv/bin/python bench/timestamp_error.py --virtual --duration 20

A loaded machine makes the daemon figures pessimistic (a read that waited for a CPU brackets its
samples late, a FIFO that overflowed meanwhile resyncs): the bench prints the load average it ran
under and each device's losses. Everything listens on 127.0.0.1 only; multicast scouting is off.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from common import free_port

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from imud.chips.api import Stamped  # noqa: E402
from imud.timestamps import SampleClock  # noqa: E402
from imud.wire import decode  # noqa: E402

DEFAULT_CONFIG = Path(__file__).resolve().parent / "configs" / "timestamps.toml"
PREFIX = "imud"
# issue 10's "bus faults and scheduling stalls of a few ms", per transfer
FAULTS: dict[str, Any] = {"eio_rate": 1e-3, "timeout_rate": 1e-3, "stall_rate": 2e-3,
                          "stall_ms": 3.0}  # fmt: skip
SPI_FAULTS = {**FAULTS, "garble_rate": 1e-3}
NAK_RATE = 5e-4
I64 = npt.NDArray[np.int64]
Naive = dict[str, dict[str, Any]]


# --- the hook: what each read gave the sample clock ---------------------------------------------
_current = threading.local()


def install_hook(sink: Any) -> None:
    """Call `sink(runner, first_seq, n, t_after)` for every read a device's published-rate sample
    clock stamps (a BMI088's accel clock runs at another rate: left out)."""
    from imud.device import DeviceRunner

    update, step = SampleClock.update, DeviceRunner.step

    def hooked_update(self: SampleClock, n: int, t_before: int, t_after: int,
                      *args: Any, **kw: Any) -> Stamped:  # fmt: skip
        st = update(self, n, t_before, t_after, *args, **kw)
        r = getattr(_current, "runner", None)
        drv = None if r is None else r.driver
        if n and drv is not None and abs(self.nominal - drv.nominal_period_ns) < 1e-6:
            sink(r, st.first_seq, n, t_after)
        return st

    def hooked_step(self: DeviceRunner) -> None:
        _current.runner = self
        step(self)

    SampleClock.update = hooked_update  # type: ignore[method-assign]
    DeviceRunner.step = hooked_step  # type: ignore[method-assign]


def install_file_hook(folder: str) -> None:
    """The hook in a daemon process: one line per read in `folder/reads-<pid>.txt`."""
    out = open(Path(folder) / f"reads-{os.getpid()}.txt", "a", buffering=1)  # noqa: SIM115

    def sink(r: Any, first: int, n: int, t_after: int) -> None:
        d = r.driver
        out.write(f"{r.cfg.name} {first} {n} {t_after} {d.nominal_period_ns} "
                  f"{d.group_delay_ns} {r.epoch_offset_ns}\n")  # fmt: skip

    install_hook(sink)


SITECUSTOMIZE = """\
import os, sys
if os.environ.get("IMUD_TS_HOOK"):
    sys.path.insert(0, {bench!r})
    import timestamp_error
    timestamp_error.install_file_hook(os.environ["IMUD_TS_HOOK"])
"""


def naive(rows: list[list[float]]) -> dict[str, Any]:
    """seq and naive stamp of every sample, from reads (first_seq, n, t_after, nominal_ns,
    group_delay_ns, epoch offset_ns): t_after - (n - 1 - i) nominal periods - group delay."""
    a = np.array(rows, dtype=np.float64)
    first, n, ta = a[:, 0].astype(np.int64), a[:, 1].astype(np.int64), a[:, 2].astype(np.int64)
    nominal, gd, off = float(a[0, 3]), int(a[0, 4]), int(a[0, 5])
    idx = np.repeat(np.arange(len(n)), n)
    pos = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)  # i within its read
    back = np.rint((n[idx] - 1 - pos) * nominal).astype(np.int64)
    return {"seq": first[idx] + pos, "t_ns": ta[idx] - back - gd + off, "nominal_ns": nominal}


def read_file_hook(folder: Path) -> Naive:
    """Naive stamps per device from the reads the daemon's processes wrote."""
    rows: dict[str, list[list[float]]] = defaultdict(list)
    for f in folder.glob("reads-*.txt"):
        for line in f.read_text().splitlines():
            parts = line.split()
            if len(parts) == 7:
                rows[parts[0]].append([float(x) for x in parts[1:]])
    return {name: naive(r) for name, r in rows.items()}


# --- configs -------------------------------------------------------------------------------------
def bench_config(src: Path, port: int, faults: bool) -> str:
    """The config as TOML text: loopback port, defaults for [daemon] (no real-time priority),
    the fault schedule on every I2C/SPI device with `faults`."""
    raw = tomllib.loads(src.read_text())
    lines = [f'[zenoh]\nmode = "peer"\nlisten = ["tcp/127.0.0.1:{port}"]\nprefix = "{PREFIX}"\n']
    for d in raw["device"]:
        sim = dict(d.pop("sim", {}))
        transport = d["bus"].get("transport", "i2c")
        if faults and transport != "serial":
            sim["faults"] = SPI_FAULTS if transport == "spi" else FAULTS
            sim["nak_rate"] = NAK_RATE
        lines.append("[[device]]\n" + _toml_table(d))
        lines.append("[device.sim]\n" + _toml_table(sim))
    return "\n".join(lines)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v + '"'
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def _toml_table(d: dict[str, Any]) -> str:
    return "".join(f"{k} = {_toml_value(v)}\n" for k, v in d.items())


# --- the figures ---------------------------------------------------------------------------------
@dataclass
class Figures:
    n: int
    mean_us: float
    rms_us: float
    max_us: float
    backwards: int
    step_dev: float  # largest |dt - period| / period over successive seq


def figures(seq: I64, t: I64, truth_index: I64, truth_t: I64, offset: int, settle_ns: float,
            period_ns: float) -> Figures | None:  # fmt: skip
    """Stamp errors after the settle against the truth at seq + offset."""
    order = np.argsort(seq, kind="stable")
    seq, t = seq[order], t[order]
    keep = t >= t[0] + settle_ns
    seq, t = seq[keep], t[keep]
    j = seq + offset - truth_index[0]
    ok = (j >= 0) & (j < len(truth_t))
    ok &= truth_index[np.clip(j, 0, len(truth_t) - 1)] == seq + offset  # the truth is contiguous
    if not ok.any():
        return None
    e = (t[ok] - truth_t[j[ok]]).astype(np.float64) / 1e3
    dt = np.diff(t)
    succ = np.diff(seq) == 1
    dev = np.abs(dt[succ] - period_ns) / period_ns if succ.any() else np.zeros(1)
    return Figures(int(e.size), float(e.mean()), float(np.sqrt((e**2).mean())),
                   float(np.abs(e).max()), int((dt <= 0).sum()), float(dev.max()))  # fmt: skip


def seq_offset(seq: I64, t: I64, truth_index: I64, truth_t: I64, settle_ns: float) -> int:
    """Truth index minus seq: the median over the settled samples of the nearest true instant's."""
    keep = t >= t.min() + settle_ns
    s, tt = seq[keep], t[keep]
    i = np.clip(np.searchsorted(truth_t, tt), 1, len(truth_t) - 1)
    near = np.where(np.abs(truth_t[i] - tt) < np.abs(truth_t[i - 1] - tt), i, i - 1)
    return int(np.median(truth_index[near] - s))


def seq_slips(seq: I64, t: I64, truth_index: I64, truth_t: I64, offset: int, settle_ns: float,
              period_ns: float) -> float:  # fmt: skip
    """The share of settled samples whose nearest true instant (within a quarter period) is not
    the one their seq names: samples after a gap miscounted, not stamps off."""
    keep = t >= t.min() + settle_ns
    s, tt = seq[keep], t[keep]
    i = np.clip(np.searchsorted(truth_t, tt), 1, len(truth_t) - 1)
    near = np.where(np.abs(truth_t[i] - tt) < np.abs(truth_t[i - 1] - tt), i, i - 1)
    close = np.abs(truth_t[near] - tt) < period_ns / 4
    if not close.any():
        return 0.0
    return float(np.mean(truth_index[near][close] - s[close] != offset))


def joined(batches: list[bytes]) -> tuple[I64, I64]:
    bs = [b for b in (decode(x) for x in batches) if b.count]
    if not bs:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate([b.seq for b in bs]), np.concatenate([b.t_ns for b in bs])


def _cols(f: Figures | None) -> str:
    if f is None:
        return f"{'n/a':>11}"
    return (f"{f.mean_us:+11.1f} {f.rms_us:7.1f} {f.max_us:8.1f} {f.backwards:4d} "
            f"{100 * f.step_dev:7.2f}%")  # fmt: skip


def report(data: dict[str, list[bytes]], truth: dict[str, list[bytes]], nv: Naive,
           settle_s: float) -> None:  # fmt: skip
    settle = settle_s * 1e9
    head = (
        f"{'device':8} {'samples':>8} | {'imud: mean':>11} {'RMS':>7} {'max':>8} {'back':>4} "
        f"{'step':>8} | {'naive: mean':>11} {'RMS':>7} {'max':>8} {'back':>4} {'step':>8}"
    )
    print(head)
    print("-" * len(head))
    for name in sorted(data):
        seq, t = joined(data[name])
        ti, tt = joined(truth.get(name, []))
        if not seq.size or not ti.size:
            print(f"{name:8} no {'samples' if not seq.size else 'truth'}")
            continue
        info = nv.get(name, {})
        off = seq_offset(seq, t, ti, tt, settle)
        ours = figures(seq, t, ti, tt, off, settle, info.get("period_ns") or float(np.median(
            np.diff(t))))  # fmt: skip
        theirs = None
        if "seq" in info:
            theirs = figures(info["seq"], info["t_ns"], ti, tt, off, settle, info["nominal_ns"])
        slips = seq_slips(seq, t, ti, tt, off, settle, info.get("nominal_ns") or float(
            np.median(np.diff(t))))  # fmt: skip
        print(f"{name:8} {ours.n if ours else 0:8d} | {_cols(ours)} | {_cols(theirs)} | "
              f"{100 * slips:5.1f}%")  # fmt: skip
    print(
        "errors in us (stamp - true instant); step: largest |dt - period|/period between "
        "successive samples"
    )


# --- the daemon ---------------------------------------------------------------------------------
def subscribe(endpoint: str, names: list[str]) -> tuple[Any, list[Any], dict[str, list[bytes]],
                                                         dict[str, list[bytes]]]:  # fmt: skip
    import imud.client as ic

    data: dict[str, list[bytes]] = defaultdict(list)
    truth: dict[str, list[bytes]] = defaultdict(list)
    session = ic.open_session(endpoint)
    subs = []
    for name in names:
        for store, key in ((data, ic.data_key(name, PREFIX)),
                           (truth, ic.data_key(name, PREFIX, truth=True))):  # fmt: skip

            def put(sample: Any, store: dict[str, list[bytes]] = store, name: str = name) -> None:
                store[name].append(sample.payload.to_bytes())

            subs.append(session.declare_subscriber(key, put))
    return session, subs, data, truth


def daemon_status(endpoint: str) -> dict[str, Any]:
    import imud.client as ic

    with ic.open_session(endpoint) as s:
        return ic.get_status(s, PREFIX)


def wait_running(endpoint: str, names: list[str], timeout: float = 30.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            states = {d["name"]: d["state"] for d in daemon_status(endpoint).get("devices", [])}
            if all(states.get(n) == "running" for n in names):
                return
        except Exception:
            pass
        time.sleep(0.5)
    raise SystemExit(f"the daemon did not run every device within {timeout:g} s")


def run_daemon(args: argparse.Namespace) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    tmp = Path(tempfile.mkdtemp(prefix="imud-ts-"))
    cfg = tmp / "imud.toml"
    cfg.write_text(bench_config(args.config, port, args.faults))
    names = [d["name"] for d in tomllib.loads(cfg.read_text())["device"]]
    hook, reads = tmp / "hook", tmp / "reads"
    hook.mkdir()
    reads.mkdir()
    (hook / "sitecustomize.py").write_text(SITECUSTOMIZE.format(bench=str(Path(__file__).parent)))
    path = os.pathsep.join(p for p in (str(hook), os.environ.get("PYTHONPATH")) if p)
    env = {**os.environ, "IMUD_TS_HOOK": str(reads), "PYTHONPATH": path}
    cmd = [str(Path(sys.executable).with_name("imud")), "run", "--config", str(cfg)]
    with open(tmp / "daemon.log", "wb") as log:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log, env=env)
    status: dict[str, Any] = {}
    try:
        time.sleep(1.0)
        session, subs, data, truth = subscribe(endpoint, names)
        wait_running(endpoint, names)
        time.sleep(args.settle + args.duration)
        load = os.getloadavg()
        status = daemon_status(endpoint)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
    for s in subs:
        s.undeclare()
    session.close()
    nv = read_file_hook(reads)
    for d in status.get("devices", []):
        if d.get("chip_rate_hz"):
            nv.setdefault(d["name"], {})["period_ns"] = 1e9 / d["chip_rate_hz"]
    print(
        f"imud run (bus processes, no real-time priority); {args.settle:g} s settle + "
        f"{args.duration:g} s; faults {'on' if args.faults else 'off'}; load average "
        f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} CPUs; log "
        f"{tmp / 'daemon.log'}"
    )
    report(data, truth, nv, args.settle)
    for d in status.get("devices", []):
        print(
            f"  {d['name']}: lost {d.get('lost_samples')}, FIFO overflows "
            f"{d.get('fifo_overflows')}, bus errors {d.get('bus_errors')}, poll late max "
            f"{d.get('poll_late_max_ms')} ms"
        )


# --- virtual time --------------------------------------------------------------------------------
def run_virtual(args: argparse.Namespace) -> None:
    """Each I2C/SPI device alone at virtual time, driven by its DeviceRunner as a bus worker
    drives it, with a uniform poll jitter and SPI transfers that take bus time (the chip answers
    in the middle of the transfer)."""
    from imud.clock import VirtualClock
    from imud.config import parse_config
    from imud.device import DeviceRunner
    from imud.sim.i2c import SimI2CBus
    from imud.sim.spi import SimSpiDev
    from imud.wiring import connect

    reads: dict[str, list[list[float]]] = defaultdict(list)

    def sink(r: Any, first: int, n: int, t_after: int) -> None:
        d = r.driver
        reads[r.cfg.name].append([first, n, t_after, d.nominal_period_ns, d.group_delay_ns, 0])

    install_hook(sink)
    all_data: dict[str, list[bytes]] = {}
    all_truth: dict[str, list[bytes]] = {}
    all_nv: Naive = {}
    raw = tomllib.loads(bench_config(args.config, 7450, args.faults))
    print(
        f"virtual time, {args.settle:g} s settle + {args.duration:g} s, poll jitter "
        f"{args.jitter_us:g} us, faults {'on' if args.faults else 'off'}"
    )
    for d in raw["device"]:
        if d["bus"].get("transport") == "serial":
            continue
        cfg = parse_config({"device": [d]}).device[0]
        clock = VirtualClock()
        driver, sim = connect(cfg, SimI2CBus(), clock)
        speed = int(d["bus"].get("speed_hz", 10_000_000))
        for link in vars(driver).values():  # 1 us a transfer plus its bytes on the wire
            spi = getattr(link, "spi", None)
            if isinstance(spi, SimSpiDev):
                spi.transfer_time = (clock, 1_000, 8 * 10**9 // speed)
        data: list[bytes] = []
        truth: list[bytes] = []
        runner = DeviceRunner(cfg, driver, None, data.append, 0, sim=sim,
                              publish_truth=truth.append, now_ns=clock.now_ns)  # fmt: skip
        rng = np.random.default_rng(1)
        end = clock.now_ns() + int((args.settle + args.duration + 1) * 1e9)
        jitter = int(args.jitter_us * 1e3)
        while clock.now_ns() < end:
            runner.step()
            wait = max(0, runner.next_due_ns - clock.now_ns())
            clock.advance(wait + (int(rng.integers(0, jitter)) if jitter else 0))
        if reads[cfg.name]:
            all_nv[cfg.name] = naive(reads[cfg.name])
        if runner.pipeline is not None:
            all_nv.setdefault(cfg.name, {})["period_ns"] = runner.pipeline.period_ns
        all_data[cfg.name], all_truth[cfg.name] = data, truth
    report(all_data, all_truth, all_nv, args.settle)


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    ap.add_argument("--duration", type=float, default=40.0, help="seconds measured")
    ap.add_argument("--settle", type=float, default=5.0, help="seconds left out first")
    ap.add_argument("--faults", action="store_true", help="EIO, timeouts, NAKs, 3 ms stalls")
    ap.add_argument("--virtual", action="store_true", help="at virtual time, no scheduler")
    ap.add_argument("--jitter-us", type=float, default=50.0, help="virtual poll jitter")
    args = ap.parse_args()
    if args.virtual:
        run_virtual(args)
    else:
        run_daemon(args)


if __name__ == "__main__":
    main()
