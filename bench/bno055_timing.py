"""How well the BNO055 driver counts and stamps samples, against the simulator's own sample
instants: a simulated BNO055 on I2C or behind a real pty at 115200 baud, driven by the real
driver and device runner at real time in this process, with each sample's index written into
its accelerometer's x register (the first word of a full read and of a probe) so every
published sample says which one it is.

    .venv/bin/python bench/bno055_timing.py --transport uart --seconds 20

Prints: samples delivered and lost (the device's own counts), how many distinct offsets
between the published sequence number and the chip's sample index there were (1: every gap
counted exactly), and the stamps' error against the chip's true sample instants after the
first fifth of the run (the clock fit settling). Scheduler-dependent: this is a measurement,
not a test (docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from typing import Any

import numpy as np

import imud.client as ic
from imud.busworker import _ChipSelects
from imud.clock import MonotonicClock
from imud.config import parse_config
from imud.device import DeviceRunner
from imud.sim.i2c import SimI2CBus
from imud.wiring import connect

# where each sample's index is written: ACC_DATA_X in the register page, the first word of the
# 0x08 burst and of a probe (which delivers the motion sensors alone), so every delivered sample
# says which one it is
TAG = slice(0x08, 0x0A)


def run(transport: str, seconds: float, seed: int) -> dict[str, Any]:
    bus: dict[str, Any] = (
        {"kind": "sim", "bus": "u", "transport": "serial", "baud": 115200}
        if transport == "uart"
        else {"kind": "sim", "bus": "i2c0", "transport": "i2c", "address": 0x28}
    )
    d = {"name": "b", "chip": "bno055", "bus": bus, "save_offsets": False,
         "sim": {"seed": seed, "clock_error": -0.003}}  # fmt: skip
    cfg = parse_config({"device": [d]}).device[0]
    clock = MonotonicClock()
    shared = _ChipSelects() if transport == "uart" else SimI2CBus(seed=seed)
    driver, sim = connect(cfg, shared, clock)
    assert sim is not None
    out: list[bytes] = []
    runner = DeviceRunner(cfg, driver, None, out.append, 0, sim=sim, now_ns=clock.now_ns)
    produced = [0]
    instants: dict[int, tuple[int, int]] = {}  # heading word -> (sample index, instant)
    produce = sim._produce  # the simulator's sample step: tag each newest sample

    def tagged(t_ns: np.ndarray) -> None:
        produce(t_ns)
        produced[0] += len(t_ns)
        tag = (produced[0] - 1) % 30000
        instants[tag] = (produced[0] - 1, int(t_ns[-1]))
        sim.p0[TAG] = tag.to_bytes(2, "little")  # type: ignore[attr-defined]

    sim._produce = tagged  # type: ignore[method-assign]
    tags: list[int] = []
    decode = driver._decode  # type: ignore[attr-defined]

    def record(body: bytes, timing: Any) -> Any:
        tags.append(int.from_bytes(body[0:2], "little"))
        return decode(body, timing)

    driver._decode = record  # type: ignore[attr-defined]
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        runner.step()
        wait = runner.next_due_ns - clock.now_ns()
        if wait > 0:
            time.sleep(wait / 1e9)
    st = runner.status().to_json()
    batches = [ic.decode(x) for x in out]
    seq = np.concatenate([b.seq for b in batches])
    t = np.concatenate([b.t_ns for b in batches])
    n = min(len(seq), len(tags))
    k = np.array([instants[c][0] for c in tags[:n]])
    true_t = np.array([instants[c][1] for c in tags[:n]])
    err = (t[:n] - true_t)[n // 5 :] / 1e6
    chip = st["chip_status"]
    return {
        "transport": transport,
        "seconds": seconds,
        "samples": st["samples"],
        "lost": st["lost_samples"],
        "count_offsets": len(set((seq[:n] - k).tolist())),
        "stamp_error_ms": {
            "mean": round(float(err.mean()), 3),
            "sd": round(float(err.std()), 3),
            "max_abs": round(float(np.abs(err).max()), 3),
        },
        "suspected_missed": chip["suspected_missed"],
        "phase_losses": chip.get("phase_losses"),
        "probes": chip.get("uart", {}).get("probes"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--transport", choices=("i2c", "uart"), default="uart")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=22)
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    print(json.dumps(run(args.transport, args.seconds, args.seed)))


if __name__ == "__main__":
    main()
