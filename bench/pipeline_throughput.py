"""Pipeline throughput on one core: simulated bus bytes to a published Zenoh batch.

One simulated MPU6050 on a simulated I2C bus is driven by the daemon's own `DeviceRunner` at
virtual time (`VirtualClock`): each step advances the clock by the poll interval, lets the simulator
generate the samples due, then runs `DeviceRunner.step()` exactly as a bus worker does: FIFO burst
read over the simulated bus -> MPU6050 decode -> SI scaling -> timestamping -> calibration (a
bias/scale file written to a temp dir) -> wire encode -> `put` on a real Zenoh publisher (the
daemon's publisher settings, on a session opened with `imud.zsession.daemon_config`, listening on
127.0.0.1 only, multicast scouting off).

The simulator's sample generation is timed separately by calling `sim.advance()` explicitly before
each step (the chip's own lazy `advance()` inside the register reads then has nothing left to do),
so the report separates:

  (a) everything, simulator included;
  (b) the simulator's sample generation, and its share;
  (c) driver + pipeline + publish, simulator generation excluded.

plus a per-stage breakdown per batch. Samples/s are given per wall second of the (single-threaded)
loop and per CPU second of the whole process (`time.process_time()`, which also counts Zenoh's
own runtime threads: the conservative "everything on one core" figure).

Run from the repository root:

    .venv/bin/python bench/pipeline_throughput.py                   # 60 virtual s, 1 kHz, Zenoh
    .venv/bin/python bench/pipeline_throughput.py --subscriber      # + a subscriber process
    .venv/bin/python bench/pipeline_throughput.py --publisher null  # no Zenoh at all
    .venv/bin/python bench/pipeline_throughput.py --batch-ms 5 --profile

Without `--subscriber` nobody matches the publisher's key, so Zenoh's `put` does no network I/O;
with it, a second process (client session connected to the bench's endpoint) counts the bytes,
samples and sequence gaps it receives, and the bench waits until it matches before timing.
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import json
import os
import pstats
import shlex
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from common import CALIBRATION_TOML, free_port

PREFIX = "imud"
DONE_KEY = f"{PREFIX}/bench/done"


# --- helpers --------------------------------------------------------------------------------------


@dataclass
class Acc:
    """Accumulated wall time of one stage."""

    seconds: float = 0.0
    calls: int = 0


def timed(fn: Callable[..., Any], acc: Acc) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            acc.seconds += time.perf_counter() - t
            acc.calls += 1

    return wrapper


# --- one timed run --------------------------------------------------------------------------------
@dataclass
class RunResult:
    samples: int = 0
    batches: int = 0
    steps: int = 0
    bytes_published: int = 0
    lost: int = 0
    overflows: int = 0
    bus_errors: int = 0
    poll_ns: int = 0  # mean virtual time between polls
    unaccounted: int = 0  # samples the chip produced that were neither delivered nor counted lost
    wall: float = 0.0  # the timed loop's busy wall time
    cpu: float = 0.0  # process CPU (all threads) over the loop
    thread_cpu: float = 0.0  # main-thread CPU over the loop
    sim_gen_wall: float = 0.0
    sim_gen_cpu: float = 0.0
    stages: dict[str, Acc] = field(default_factory=dict)


class Bench:
    def __init__(
        self,
        odr: float,
        batch_ms: float | None,
        cal_path: Path,
        publish: Callable[[bytes], None],
        seed: int = 1,
    ) -> None:
        from imud.config import parse_config

        self.odr = odr
        self.batch_ms = batch_ms
        self.cal_path = cal_path
        self.publish = publish
        self.seed = seed
        self.sent_samples = 0  # every batch published by every run (start-up, warm-up, timed)
        self.sent_bytes = 0
        # validate a device table the way the daemon does (reachable ODR, calibration file)
        raw = {
            "device": [
                {
                    "name": "bench0",
                    "chip": "mpu6050",
                    "bus": {"kind": "sim", "bus": "sim0", "address": 0x68},
                    "gyro_range_dps": 500,
                    "accel_range_g": 4,
                    "dlpf_hz": 188,
                    "odr_hz": odr,
                    "calibration": str(cal_path),
                    "sim": {"seed": seed, "motion": {"kind": "tumble"}, "truth": False},
                }
            ]
        }
        self.cfg = parse_config(raw, cal_path.parent)

    def run(
        self, name: str, virtual_s: float, warmup_s: float = 1.0, paced: bool = False
    ) -> RunResult:
        from imud.buses.i2c import I2CDevice
        from imud.calib.file import load_calibration
        from imud.chips.mpu6050.config import Mpu6050Config
        from imud.chips.mpu6050.driver import Mpu6050Driver
        from imud.chips.mpu6050.sim import Mpu6050Sim
        from imud.clock import VirtualClock, epoch_offset_ns
        from imud.device import DeviceRunner
        from imud.sim.i2c import SimI2CBus

        d = self.cfg.device[0].model_copy(update={"name": name})
        assert isinstance(d, Mpu6050Config) and d.sim is not None and d.calibration is not None
        clock = VirtualClock()
        bus = SimI2CBus(seed=self.seed)
        sim = Mpu6050Sim(d.sim, clock)
        bus.attach(d.bus.address, sim, 0.0)  # type: ignore[union-attr]
        driver = Mpu6050Driver(d, I2CDevice(bus, d.bus.address), clock)  # type: ignore[union-attr]
        if self.batch_ms is not None:
            driver.poll_interval_ns = int(self.batch_ms * 1e6)
        res = RunResult()

        def publish(payload: bytes) -> None:
            res.bytes_published += len(payload)
            self.sent_bytes += len(payload)
            self.publish(payload)

        runner = DeviceRunner(
            d,
            driver,
            load_calibration(d.calibration),
            publish,
            epoch_offset_ns(),
            sim=sim,
            now_ns=clock.now_ns,
        )
        # start-up (reset waits included) at virtual time
        for _ in range(100):
            if runner.state == "running":
                break
            clock.advance(max(0, runner.next_due_ns - clock.now_ns()))
            runner.step()
        if runner.state != "running":
            raise RuntimeError(f"device did not start: {runner.state}: {runner.last_error}")

        def step_once() -> None:
            clock.advance(max(0, runner.next_due_ns - clock.now_ns()))
            runner.step()

        for _ in range(max(1, round(warmup_s * 1e9 / driver.poll_interval_ns))):
            step_once()

        # Per-stage timers: instance attributes shadow the methods, imud itself is untouched.
        assert runner.pipeline is not None
        st = {
            k: Acc()
            for k in ("step", "driver.read", "sim registers", "pipeline", "publish", "sim gen")
        }
        driver.read = timed(driver.read, st["driver.read"])  # type: ignore[method-assign]
        sim.read = timed(sim.read, st["sim registers"])  # type: ignore[method-assign]
        sim.write = timed(sim.write, st["sim registers"])  # type: ignore[method-assign]
        runner.pipeline.process = timed(  # type: ignore[method-assign]
            runner.pipeline.process, st["pipeline"]
        )
        runner.publish = timed(runner.publish, st["publish"])
        s0, b0, l0, by0 = runner.samples, runner.batches, runner.lost_samples, res.bytes_published
        o0, e0 = driver.counters.fifo_overflows, runner.bus_errors
        p0, f0 = sim.samples_produced, len(sim.fifo) // 12
        gen, step = st["sim gen"], st["step"]
        advance, perf, tcpu = sim.advance, time.perf_counter, time.thread_time
        gen_cpu = 0.0
        steps = 0
        v0 = clock.now_ns()
        end_ns = v0 + int(virtual_s * 1e9)

        w0, c0, t0 = perf(), time.process_time(), tcpu()
        wake = w0
        while runner.next_due_ns <= end_ns:  # the runner dithers its poll instants a little
            dt = max(0, runner.next_due_ns - clock.now_ns())
            clock.advance(dt)
            if paced:  # polls at the real poll rate, as in the daemon
                wake += dt / 1e9
                time.sleep(max(0.0, wake - perf()))
            steps += 1
            a, ac = perf(), tcpu()
            advance()
            b, bc = perf(), tcpu()
            runner.step()
            c = perf()
            gen.seconds += b - a
            gen_cpu += bc - ac
            step.seconds += c - b
        w1, c1, t1 = perf(), time.process_time(), tcpu()

        gen.calls = step.calls = steps
        res.steps = steps
        res.poll_ns = (clock.now_ns() - v0) // max(1, steps)
        res.samples = runner.samples - s0
        res.batches = runner.batches - b0
        res.lost = runner.lost_samples - l0
        res.overflows = driver.counters.fifo_overflows - o0
        res.bus_errors = runner.bus_errors - e0
        produced = sim.samples_produced - p0
        res.unaccounted = produced - res.samples - res.lost - (len(sim.fifo) // 12 - f0)
        res.bytes_published -= by0
        # busy wall time: the loop minus any pacing sleeps (= the loop's wall time unpaced)
        res.wall = gen.seconds + step.seconds if paced else w1 - w0
        res.cpu, res.thread_cpu = c1 - c0, t1 - t0
        res.sim_gen_wall, res.sim_gen_cpu = gen.seconds, gen_cpu
        res.stages = st
        self.sent_samples += runner.samples
        runner.stop()
        return res


# --- Zenoh ----------------------------------------------------------------------------------------
@contextlib.contextmanager
def zenoh_publisher(port: int, key: str) -> Iterator[tuple[Callable[[bytes], None], Any, Any]]:
    import zenoh

    from imud.config import ZenohSettings
    from imud.daemon import _make_publisher  # the daemon's own publisher settings (DROP, DATA_HIGH)
    from imud.zsession import daemon_config

    session = zenoh.open(daemon_config(ZenohSettings(listen=[f"tcp/127.0.0.1:{port}"])))
    try:
        put, pub = _make_publisher(session, key)
        yield put, pub, session
        pub.undeclare()  # type: ignore[no-untyped-call]
    finally:
        session.close()  # type: ignore[no-untyped-call]


def start_subscriber(endpoint: str) -> subprocess.Popen[str]:
    cmd = [sys.executable, os.path.abspath(__file__), "--subscriber-child", endpoint]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if line.strip() != "ready":
        proc.kill()
        raise RuntimeError(f"subscriber did not start: {line!r}")
    return proc


def subscriber_child(endpoint: str) -> int:
    """Second process: count bytes, samples and sequence gaps on `imud/*/imu` until told to stop."""
    import zenoh

    from imud.wire import HEADER
    from imud.zsession import client_config

    lock = threading.Lock()
    c: dict[str, int] = {"bytes": 0, "batches": 0, "samples": 0, "gaps": 0, "gap_samples": 0}
    next_seq: dict[str, int] = {}

    def on_sample(s: Any) -> None:
        buf = s.payload.to_bytes()
        _, _, _, name_len, first_seq, n, _, _, _ = HEADER.unpack_from(buf)
        dev = bytes(buf[HEADER.size : HEADER.size + name_len]).decode()
        with lock:
            c["bytes"] += len(buf)
            c["batches"] += 1
            c["samples"] += n
            want = next_seq.get(dev)
            if want is not None and first_seq != want:
                c["gaps"] += 1
                c["gap_samples"] += first_seq - want
            next_seq[dev] = first_seq + n

    done = threading.Event()
    session = zenoh.open(client_config(endpoint))
    try:
        sub = session.declare_subscriber(f"{PREFIX}/*/imu", on_sample)
        dsub = session.declare_subscriber(DONE_KEY, lambda s: done.set())
        print("ready", flush=True)
        done.wait(600)
        last = -1
        while True:  # the done message may overtake the last (higher-priority) batches
            with lock:
                now = c["bytes"]
            if now == last:
                break
            last = now
            time.sleep(0.3)
        sub.undeclare()  # type: ignore[no-untyped-call]
        dsub.undeclare()  # type: ignore[no-untyped-call]
    finally:
        session.close()  # type: ignore[no-untyped-call]
    print(json.dumps({**c, "cpu_s": time.process_time()}), flush=True)
    return 0


# --- report ---------------------------------------------------------------------------------------
def med(xs: list[float]) -> float:
    return statistics.median(xs)


def spread(xs: list[float]) -> str:
    return f"{min(xs):,.0f}-{max(xs):,.0f}" if len(xs) > 1 else ""


def report(results: list[RunResult], args: argparse.Namespace, poll_ns: int) -> None:
    n = results[0].samples
    rows: list[tuple[str, list[float], list[float]]] = []
    a_w = [r.samples / r.wall for r in results]
    a_c = [r.samples / r.cpu for r in results]
    rows.append(("(a) total, simulator included", a_w, a_c))
    b_w = [r.samples / r.sim_gen_wall for r in results]
    b_c = [r.samples / r.sim_gen_cpu for r in results]
    rows.append(("(b) simulator sample generation alone", b_w, b_c))
    c_w = [r.samples / (r.wall - r.sim_gen_wall) for r in results]
    c_c = [r.samples / (r.cpu - r.sim_gen_cpu) for r in results]
    rows.append(("(c) driver+pipeline+publish, excl. (b)", c_w, c_c))
    d_w = [
        r.samples / (r.wall - r.sim_gen_wall - r.stages["sim registers"].seconds) for r in results
    ]
    d_c = [r.samples / (r.cpu - r.sim_gen_cpu - r.stages["sim registers"].seconds) for r in results]
    rows.append(("(d) as (c), also excl. sim register side", d_w, d_c))

    r0 = results[0]
    print()
    print(
        f"pipeline throughput: 1 x MPU6050 sim @ {args.odr:g} Hz, "
        f"polls every {poll_ns / 1e6:.2f} ms (mean)"
        f" (~{n / max(1, r0.batches):.1f} samples/batch), {args.seconds:g} virtual s "
        f"= {n:,} samples/run, publisher: {args.publisher}"
        f"{' + subscriber process' if args.subscriber else ''}, {len(results)} run(s)"
        f"{', paced at real time' if args.paced else ''}"
    )
    print()
    w = 42
    print(f"{'':{w}} {'samples/s (wall)':>17} {'range':>17} {'samples/s (CPU)':>16} {'range':>17}")
    for label, ws, cs in rows:
        print(f"{label:{w}} {med(ws):>17,.0f} {spread(ws):>17} {med(cs):>16,.0f} {spread(cs):>17}")
    share_w = [r.sim_gen_wall / r.wall * 100 for r in results]
    share_c = [r.sim_gen_cpu / r.cpu * 100 for r in results]
    print(
        f"{'simulator generation share of (a)':{w}} {med(share_w):>16.1f}% {'':>17} "
        f"{med(share_c):>15.1f}%"
    )
    print()
    print("per batch, median run (wall µs; stages nest: step = driver.read + pipeline + ...):")
    mid = sorted(results, key=lambda r: r.wall)[len(results) // 2]
    nb = max(1, mid.batches)
    s = mid.stages
    encode_etc = (
        s["step"].seconds - s["driver.read"].seconds - s["pipeline"].seconds - s["publish"].seconds
    )
    parts = [
        ("sim sample generation (sim.advance)", s["sim gen"].seconds),
        ("DeviceRunner.step, of which:", s["step"].seconds),
        ("  driver.read (I2C transfers + decode)", s["driver.read"].seconds),
        ("    of which sim register side", s["sim registers"].seconds),
        ("  pipeline (SI, timestamps, calibration)", s["pipeline"].seconds),
        ("  wire encode + runner bookkeeping", encode_etc),
        (
            "  publish (Zenoh put)" if args.publisher == "zenoh" else "  publish (null)",
            s["publish"].seconds,
        ),
        ("loop total", mid.wall),
    ]
    for label, sec in parts:
        print(f"  {label:{w}} {sec / nb * 1e6:>9.1f} µs  {sec / mid.wall * 100:5.1f} %")
    print(
        f"  process CPU / busy wall time of the loop: {mid.cpu / mid.wall:.2f} "
        f"(main thread {mid.thread_cpu / mid.wall:.2f}; the rest is Zenoh's runtime threads)"
    )
    lost = sum(r.lost for r in results)
    ovf = sum(r.overflows for r in results)
    errs = sum(r.bus_errors for r in results)
    unacc = sum(r.unaccounted for r in results)
    print(
        f"  all runs: lost samples {lost}, FIFO overflows {ovf}, bus errors {errs}, samples "
        f"produced by the chip but neither delivered nor counted lost {unacc}; "
        f"{mid.bytes_published / nb:.0f} B/batch"
    )
    if n == 0:
        print("  WARNING: nothing was delivered (is the poll interval longer than the FIFO holds?)")


def _null_publish(payload: bytes) -> None:
    pass


# --- main -----------------------------------------------------------------------------------------
def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    p.add_argument("--seconds", type=float, default=60.0, help="virtual seconds per run")
    p.add_argument("--odr", type=float, default=1000.0, help="MPU6050 output data rate, Hz")
    p.add_argument("--batch-ms", type=float, default=None, help="poll interval override, ms")
    p.add_argument("--repeat", type=int, default=5, help="timed runs (median and range reported)")
    p.add_argument(
        "--paced",
        action="store_true",
        help="sleep between polls so that they come at the real poll rate, as in the daemon "
        "(runs take --seconds of real time; figures are per busy second)",
    )
    p.add_argument("--publisher", choices=("zenoh", "null"), default="zenoh")
    p.add_argument("--subscriber", action="store_true", help="count bytes in a second process")
    p.add_argument("--port", type=int, default=None, help="Zenoh listen port (default: free)")
    p.add_argument("--profile", action="store_true", help="cProfile one extra run, print top 25")
    p.add_argument("--subscriber-child", metavar="ENDPOINT", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.subscriber and args.publisher != "zenoh":
        p.error("--subscriber needs --publisher zenoh")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.subscriber_child:
        return subscriber_child(args.subscriber_child)
    from imud.errors import ConfigError

    print("command:", shlex.join([sys.executable, *sys.argv]))
    port = args.port or free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    with tempfile.TemporaryDirectory(prefix="imud-bench-") as tmp:
        cal = Path(tmp) / "cal.toml"
        cal.write_text(CALIBRATION_TOML)
        with contextlib.ExitStack() as stack:
            sub_proc: subprocess.Popen[str] | None = None
            pub: Any = None
            session: Any = None
            publish: Callable[[bytes], None] = _null_publish
            if args.publisher == "zenoh":
                # one publisher for every run, as in the daemon
                publish, pub, session = stack.enter_context(
                    zenoh_publisher(port, f"{PREFIX}/bench/imu")
                )
            if args.subscriber:
                sub_proc = start_subscriber(endpoint)
                deadline = time.monotonic() + 10
                while not pub.matching_status.matching:
                    if time.monotonic() > deadline:
                        raise RuntimeError("the subscriber never matched the publisher")
                    time.sleep(0.02)
            try:
                bench = Bench(args.odr, args.batch_ms, cal, publish)
            except ConfigError as e:
                print("invalid device settings:", *e.messages, sep="\n  ", file=sys.stderr)
                return 2
            bench.run("warmup", min(args.seconds, 5.0))  # imports, caches, Zenoh routes
            results = [
                bench.run(f"run{i}", args.seconds, paced=args.paced) for i in range(args.repeat)
            ]
            report(results, args, results[0].poll_ns)
            if args.profile:
                prof = cProfile.Profile()
                prof.enable()
                bench.run("profile", args.seconds, paced=args.paced)
                prof.disable()
                out = io.StringIO()
                pstats.Stats(prof, stream=out).sort_stats("tottime").print_stats(25)
                print("\ncProfile of one more run, by own time:")
                print(out.getvalue())
            if sub_proc is not None:
                session.put(DONE_KEY, b"")
                out_s, _ = sub_proc.communicate(timeout=30)
                got = json.loads(out_s.strip().splitlines()[-1])
                print(
                    f"\nsubscriber process: received {got['samples']:,} of {bench.sent_samples:,}"
                    f" published samples ({got['bytes']:,} of {bench.sent_bytes:,} B, "
                    f"{got['batches']:,} batches, warm-up included); sequence gaps "
                    f"{got['gaps']} ({got['gap_samples']} samples); subscriber CPU "
                    f"{got['cpu_s']:.2f} s"
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
