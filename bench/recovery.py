"""Recovery after a fault, in the real daemon: how long a device that vanished from its bus, or
whose chip reset itself, takes to stream again, and whether its neighbours noticed.

issue 10: "recovery within 1 s after a fault ends; a chip that reset itself is detected within
100 ms by the register re-check and reconfigured; the other devices keep streaming with no gap".
The virtual-time tests assert those (tests/test_sim_faults.py, tests/test_sim_resets.py); this
measures them with a scheduler, which a test must not.

`imud run` (bus processes, no real-time priority) on five simulated devices, each fault repeated
`--events` times, `--every` seconds apart (instants count from when each device's simulator was
made, so the first comes a few seconds after start):

- `mpu_out`: an MPU6050 at 1 kHz that vanishes from its I2C bus for `--outage` seconds;
- `mpu_nbr`: a clean MPU6050 on the same bus (it must see no gap);
- `mpu_rst`: an MPU6050 at 1 kHz on another bus whose chip resets itself (registers to defaults);
- `icm_out`: an ICM-42688-P at 8 kHz on SPI that vanishes for `--outage` seconds;
- `bmi_rst`: a BMI088 (both dies on SPI) whose accel die resets itself.

A subscriber on loopback Zenoh keeps every batch's first seq, count, `lost_before` and first and
last stamps. Each gap on the wire (a batch whose first seq is not the previous batch's end) is a
fault's cost: its duration is the first stamp after it less the last stamp before it. For an
outage, the recovery is that duration less the outage's (an upper bound: the last sample before
it was latched up to one poll before the device vanished); for a self-reset, the duration is all
of it (the register check finding the reset, the reconfiguration, the sensors starting again).
Also printed: lost samples on the wire against `lost_samples` in status, restarts and resets.

Run from the repository root:

    .venv/bin/python bench/recovery.py                     # 3 events each, ~30 s
    .venv/bin/python bench/recovery.py --events 5 --outage 2.0

Everything listens on 127.0.0.1 only; multicast scouting is off.
"""

from __future__ import annotations

import argparse
import itertools
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from common import free_port, imud_executable

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

PREFIX = "imud"
OUTAGE_DEVICES = ("mpu_out", "icm_out")
RESET_DEVICES = ("mpu_rst", "bmi_rst")
CLEAN_DEVICES = ("mpu_nbr",)


def config(port: int, events: int, every: float, first: float, outage: float) -> str:
    at = [first + i * every for i in range(events)]
    outages = ", ".join(f"{{ at_s = {a:g}, for_s = {outage:g} }}" for a in at)
    resets = ", ".join(f"{{ at_s = {a:g} }}" for a in at)
    spi = 'kind = "sim", transport = "spi", speed_hz = 10_000_000'
    return f"""\
[zenoh]
mode = "peer"
listen = ["tcp/127.0.0.1:{port}"]
prefix = "{PREFIX}"

[[device]]
name = "mpu_out"
chip = "mpu6050"
bus = {{ kind = "sim", bus = "i2c0", address = 0x68 }}
odr_hz = 1000
[device.sim]
seed = 1
faults = {{ outages = [{outages}] }}

[[device]]
name = "mpu_nbr"
chip = "mpu6050"
bus = {{ kind = "sim", bus = "i2c0", address = 0x69 }}
odr_hz = 200
[device.sim]
seed = 2

[[device]]
name = "mpu_rst"
chip = "mpu6050"
bus = {{ kind = "sim", bus = "i2c1", address = 0x68 }}
odr_hz = 1000
[device.sim]
seed = 3
faults = {{ resets = [{resets}] }}

[[device]]
name = "icm_out"
chip = "icm42688p"
bus = {{ {spi}, bus = "spi0", cs = 0 }}
odr_hz = 8000
[device.sim]
seed = 4
faults = {{ outages = [{outages}] }}

[[device]]
name = "bmi_rst"
chip = "bmi088"
bus = {{ {spi}, bus = "spi1", cs = 0 }}
gyro_bus = {{ {spi}, bus = "spi1", cs = 1 }}
[device.sim]
seed = 5
faults = {{ resets = [{resets}] }}
"""


@dataclass
class Stream:
    """What a device's batches said: (first seq, count, lost_before, first stamp, last stamp)."""

    rows: list[tuple[int, int, int, int, int]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def gaps(self, mark: int) -> list[tuple[int, float]]:
        """(samples missing, ns between the stamps either side) for each gap on the wire before
        `mark` (where a status snapshot's count had got to: `samples + lost_samples`)."""
        with self.lock:
            rows = sorted(self.rows)
        out = []
        for (f0, n0, _, _, t0), (f1, _, _, t1, _) in itertools.pairwise(rows):
            if f1 != f0 + n0 and f1 <= mark:
                out.append((f1 - (f0 + n0), float(t1 - t0)))
        return out


def status(endpoint: str) -> dict[str, Any]:
    import imud.client as ic

    with ic.open_session(endpoint) as s:
        return ic.get_status(s, PREFIX, timeout=5.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--events", type=int, default=3, help="faults of each kind per device")
    ap.add_argument("--every", type=float, default=6.0, help="seconds between them")
    ap.add_argument("--first", type=float, default=6.0, help="first one, after the simulator")
    ap.add_argument("--outage", type=float, default=1.5, help="seconds a device is gone")
    args = ap.parse_args()

    import imud.client as ic
    from imud.wire import decode

    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    tmp = Path(tempfile.mkdtemp(prefix="imud-recovery-"))
    cfg = tmp / "imud.toml"
    cfg.write_text(config(port, args.events, args.every, args.first, args.outage))
    names = (*OUTAGE_DEVICES, *RESET_DEVICES, *CLEAN_DEVICES)
    streams = {n: Stream() for n in names}
    log = open(tmp / "daemon.log", "wb")  # noqa: SIM115 (the daemon's, for its whole life)
    proc = subprocess.Popen([imud_executable(), "run", "--config", str(cfg)],
                            stdout=subprocess.DEVNULL, stderr=log)  # fmt: skip
    session = None
    st: dict[str, Any] = {}
    try:
        end = time.monotonic() + 60.0
        while session is None:
            try:
                session = ic.open_session(endpoint)
            except ic.NoDaemon:
                if time.monotonic() > end or proc.poll() is not None:
                    raise
                time.sleep(0.5)
        subs = []
        for n in names:

            def put(sample: Any, s: Stream = streams[n]) -> None:
                b = decode(sample.payload.to_bytes())
                if b.t_ns.size:
                    with s.lock:
                        s.rows.append((b.first_seq, int(b.t_ns.size), b.lost_before,
                                       int(b.t_ns[0]), int(b.t_ns[-1])))  # fmt: skip

            subs.append(session.declare_subscriber(ic.data_key(n, PREFIX), put))
        ready = time.monotonic()
        while True:
            try:
                if all(d["state"] == "running" for d in status(endpoint)["devices"]):
                    break
            except ic.NoDaemon:  # slow to answer: ask again
                pass
            time.sleep(0.5)
        if time.monotonic() - ready > args.first - 1.0:
            print(
                f"warning: the devices took {time.monotonic() - ready:.1f} s to run: faults "
                "scheduled before that are not measured (a loaded machine? raise --first)"
            )
        last = args.first + (args.events - 1) * args.every + args.outage
        time.sleep(last + 4.0)  # the last fault over, and time to come back
        st = {d["name"]: d for d in status(endpoint)["devices"]}
        load = os.getloadavg()
        for sub in subs:
            sub.undeclare()  # type: ignore[no-untyped-call]
    finally:
        if session is not None:
            session.close()  # type: ignore[no-untyped-call]
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
        log.close()

    print(f"imud run, {args.events} events each, {args.every:g} s apart, outages {args.outage:g} s;"
          f" load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} CPUs;"
          f" log {tmp / 'daemon.log'}")  # fmt: skip
    print(f"{'device':8} {'fault':7} {'gaps':>4} {'lost (wire/status)':>19} {'restarts':>8} "
          f"{'resets':>6}  time to stream again, ms (each event); other gaps")  # fmt: skip
    for n in names:
        d = st.get(n, {})
        gaps = streams[n].gaps(int(d.get("samples", 0)) + int(d.get("lost_samples", 0)))
        fault = "outage" if n in OUTAGE_DEVICES else "reset" if n in RESET_DEVICES else "none"
        less = args.outage * 1e9 if n in OUTAGE_DEVICES else 0.0
        # a fault's gap is at least 50 ms (a reset's reconfiguration; an outage's length); the
        # rest are FIFO overflows of a late read
        events = [dt for _, dt in gaps if dt > max(less / 2, 50e6)]
        times = " ".join(f"{(dt - less) / 1e6:.0f}" for dt in events) or "-"
        others = len(gaps) - len(events)
        wire = sum(k for k, _ in gaps)
        print(f"{n:8} {fault:7} {len(gaps):>4} {wire:>9}/{d.get('lost_samples', '?'):<9} "
              f"{d.get('restarts', '?'):>8} {d.get('resets', '?'):>6}  {times}"
              f"{f'; {others} overflow gaps' if others else ''}")  # fmt: skip
    print("outage: gap less the outage (an upper bound on the recovery); reset: the whole gap")


if __name__ == "__main__":
    main()
