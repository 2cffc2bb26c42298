"""The I2C/SPI fault schedule of `[device.sim.faults]` through the real daemon (`imud run` in a
subprocess, one process per bus) to a real Zenoh subscriber over loopback (issue 10: every fault
"tested through the daemon"; tests/test_sim_faults.py and tests/test_sim_resets.py hold the same
faults at virtual time, through the device runner alone).

On one simulated I2C bus, `faulty`, an MPU6050 at 1 kHz, meets transfer errors (NAK, EIO,
timeout), few-ms stalls, an outage of 1.5 s and later a self-reset of the chip (a brown-out); its
bus-mate `clean` at 50 Hz has none (its 1024-byte FIFO holds 85 samples of 12 bytes, 1.7 s:
neither a few-ms stall of the shared bus nor an ordinary scheduler delay fills it). On a
simulated SPI bus, `spi`, an ICM-42688-P, has garbled answers, EIO and timeouts, and for its
first 3 s its WHO_AM_I register reads garbage.

What must hold, none of it a duration or a rate (the schedule's instants count from when each
bus process built its simulators, which the test does not know; it only waits, with a generous
bound, for things to happen, and checks what happened):
- for every device, the seq numbers the subscriber never received equal the growth of the
  daemon's `lost_samples` between any two status snapshots the wire has passed (a snapshot's
  `samples + lost_samples` is where the device's next batch starts: tests/streams.py), and each
  gap is announced in the batch right after it;
- `clean` never restarts and sees no bus error, and never has a gap nor loses a sample, unless
  the machine stopped every bus process for longer than its FIFO lasts (the SPI bus's worker was
  as late: seen on this 2-vCPU VM at a load of 7-11, 3 s at once): then that part is reported
  as an expected failure, after every other check has passed;
- `faulty` counts its errors by kind, is restarted after the outage and streams again before the
  reset (an outage is not a chip reset: `resets` stays 0 meanwhile), then counts the reset and
  streams again after it;
- `spi` fails to start with an error naming the register (WHO_AM_I, 0x75) and the byte it read,
  and starts once the window is over; it counts its errors by kind and its garbled answers (a
  garbled FIFO burst, or a status read all ones), and, since its chip never resets, never reports
  a reset nor restarts;
- the daemon keeps running, and `imud status --json` (the CLI, in a subprocess) answers and shows
  those counters.

Each device's fault draws are seeded per transfer (an outage's transfers draw nothing), so which
of its transfers fail is fixed by the config: `faulty` (seed 355) NAKs its 88th and 101st
transfers, fails its 168th with EIO and its 230th with a timeout, and stalls its 37th and 247th;
`spi` (seed 83) garbles its 85th, 177th, 254th and 371st transfers, fails its 92nd with EIO and
times out its 196th, and no two of its faults come within two transfers of each other in its
first 5500 (a register re-check reads twice before it calls a value changed). Both devices make
about a hundred transfers a second or more, so these come within a few seconds of their starts.

Found here: a garbled SPI write of the ICM-42688-P's REG_BANK_SEL (SPI has no acknowledge: the
write is simply lost) made the register re-check read another bank's register and report "the
chip was reset or glitched" (a re-initialisation, ~100 samples lost), and a lost return to bank 0
made the next poll read its FIFO from another bank. The driver now reads each bank select back;
the last test pins it at virtual time.
"""

from __future__ import annotations

import itertools
import re
import time
from pathlib import Path
from typing import Any

import pytest

import imud.client as ic
from imud.chips.icm42688p.registers import Bank0
from tests.daemon_fixture import DaemonProc
from tests.helpers import make_rig
from tests.streams import Stream, mark

pytestmark = pytest.mark.slow  # fault windows through the daemon, in real time

OUTAGE_AT_S, OUTAGE_S, RESET_AT_S, GARBAGE_ID_S = 3.0, 1.5, 10.0, 3.0
CLEAN_HZ = 50
CLEAN_FIFO_MS = 1024 // 12 / CLEAN_HZ * 1000  # how long `clean`'s FIFO holds its samples
CONFIG = f"""
[[device]]
name = "faulty"
chip = "mpu6050"
bus = {{ kind = "sim", bus = "i2c0", address = 0x68 }}
odr_hz = 1000
[device.sim]
seed = 355
nak_rate = 1e-3
[device.sim.faults]
eio_rate = 1e-3
timeout_rate = 1e-3
stall_rate = 2e-3
stall_ms = 3.0
outages = [{{ at_s = {OUTAGE_AT_S}, for_s = {OUTAGE_S} }}]
resets = [{{ at_s = {RESET_AT_S} }}]

[[device]]
name = "clean"
chip = "mpu6050"
bus = {{ kind = "sim", bus = "i2c0", address = 0x69 }}
odr_hz = {CLEAN_HZ}

[[device]]
name = "spi"
chip = "icm42688p"
bus = {{ kind = "sim", bus = "spi0", transport = "spi", cs = 0 }}
odr_hz = 1000
[device.sim]
seed = 83
[device.sim.faults]
eio_rate = 1e-3
timeout_rate = 1e-3
garble_rate = 5e-3
garbage_identity_s = {GARBAGE_ID_S}
"""
NAMES = ("faulty", "clean", "spi")
Devices = dict[str, dict[str, Any]]  # one status snapshot: device name -> its status


def _between_faults(snaps: list[Devices]) -> list[Devices]:
    """Snapshots of `faulty` running again after its outage's restart, before the reset."""
    return [
        m
        for m in snaps
        if m["faulty"]["state"] == "running"
        and m["faulty"]["restarts"] >= 1
        and m["faulty"]["resets"] == 0
    ]


def _after_reset(snaps: list[Devices]) -> list[Devices]:
    return [m for m in snaps if m["faulty"]["resets"] >= 1]


def _garbled(spi: dict[str, Any]) -> int:
    """Garbled SPI answers (all ones) the driver noticed: in a FIFO burst (its packets do not
    decode), or in the status and count read (a bus error of kind `other`)."""
    return int(spi["garbled_transfers"]) + int(spi["bus_errors_other"])


def _errors_seen(f: dict[str, Any], spi: dict[str, Any]) -> bool:
    return (
        min(f["bus_errors_nak"], f["bus_errors_eio"], f["bus_errors_timeout"]) >= 1
        and min(_garbled(spi), spi["bus_errors_eio"], spi["bus_errors_timeout"]) >= 1
    )


def _done(snaps: list[Devices], streams: dict[str, Stream]) -> bool:
    """Enough has happened to judge: `faulty` streamed between its two faults and after the
    reset, every error kind has been counted, and every device runs, in a snapshot the wire has
    passed."""
    between, after = _between_faults(snaps), _after_reset(snaps)
    passed = [m for m in snaps if all(streams[n].end() >= mark(m[n]) for n in NAMES)]
    if len(between) < 2 or not after or not passed:
        return False
    last = passed[-1]
    return (
        between[-1]["faulty"]["samples"] > between[0]["faulty"]["samples"]
        and last["faulty"]["samples"] > after[0]["faulty"]["samples"]
        and all(last[n]["state"] == "running" and last[n]["samples"] > 0 for n in NAMES)
        and _errors_seen(last["faulty"], last["spi"])
    )


def _check_accounting(name: str, stream: Stream, snaps: list[Devices]) -> int:
    """Every gap on the wire announced in the batch after it, and equal between any two
    snapshots to the growth of `lost_samples`. Returns how many intervals were compared."""
    assert stream.batches, f"{name}: nothing received"
    for (f0, n0, _), (f1, _, lost) in itertools.pairwise(stream.batches):
        assert f1 - (f0 + n0) == lost >= 0, (name, f0, n0, f1, lost)
    first, end = stream.batches[0][0], stream.end()
    # snapshots taken while subscribed (every batch from the first received on arrives) that
    # the wire has passed
    usable = [m[name] for m in snaps if first <= mark(m[name]) <= end]
    assert len(usable) >= 2, (name, first, end)
    compared = 0
    for a, b in itertools.pairwise(usable):
        assert mark(b) >= mark(a), (name, a, b)
        missing = stream.missing(mark(a), mark(b))
        grown = b["lost_samples"] - a["lost_samples"]
        assert missing == grown, (name, mark(a), mark(b), missing, grown, b["publish_dropped"])
        compared += 1
    a, b = usable[0], usable[-1]
    assert stream.missing(mark(a), mark(b)) == b["lost_samples"] - a["lost_samples"], name
    return compared


def test_bus_faults_through_the_daemon(tmp_path: Path) -> None:
    d = DaemonProc(tmp_path, CONFIG)
    snaps: list[Devices] = []
    try:
        with d.answering_session() as s:
            streams = {n: Stream(s, n) for n in NAMES}
            deadline = time.monotonic() + 90.0  # a bound for a broken daemon, not a measurement
            while time.monotonic() < deadline and not _done(snaps, streams):
                st = ic.get_status(s, timeout=5.0)
                for x in streams.values():
                    x.drain()
                snaps.append({x["name"]: x for x in st["devices"]})
                time.sleep(0.05)
            # the real CLI, in its own process: it answers, and its counters are a snapshot too
            assert d.proc.poll() is None, d.log.read_text()
            cli = {x["name"]: x for x in d.status()["devices"]}
            snaps.append(cli)
            end = time.monotonic() + 30.0
            while time.monotonic() < end and any(streams[n].end() < mark(cli[n]) for n in NAMES):
                time.sleep(0.05)  # the batches published before the CLI's snapshot
                for x in streams.values():
                    x.drain()
        assert d.proc.poll() is None, d.log.read_text()  # it kept running through it all
    finally:
        code, _ = d.stop()
    log = d.log.read_text()
    assert code == 0, log
    assert _done(snaps[:-1], streams), (snaps[-2] if len(snaps) > 1 else None, log)
    for n in NAMES:
        assert streams[n].end() >= mark(cli[n]), (n, streams[n].end(), cli[n])

    # every seq the subscriber never got is a sample the daemon counted as lost, exactly
    for n in NAMES:
        assert _check_accounting(n, streams[n], snaps) >= 10, n
        assert cli[n]["state"] == "running" and cli[n]["publish_dropped"] == 0, cli[n]

    # the faulty device: errors counted by kind (the outage's NAKs among them), restarted after
    # the outage and streaming again before the reset, which it then counted and got over
    f = cli["faulty"]
    assert f["bus_errors_nak"] >= 1 and f["bus_errors_eio"] >= 1, f
    assert f["bus_errors_timeout"] >= 1 and f["unexpected_errors"] == 0, f
    assert f["lost_samples"] > 0  # the outage and the reset cost samples
    assert f["restarts"] >= 2 and f["resets"] >= 1, f  # the outage's and the reset's
    between, after = _between_faults(snaps), _after_reset(snaps)
    # samples between the two faults reached the subscriber (a reset chip's FIFO is off and
    # empty until it is re-initialised, so none of them came after the reset)
    w0, w1 = between[0]["faulty"], between[-1]["faulty"]
    assert streams["faulty"].missing(mark(w0), mark(w1)) < mark(w1) - mark(w0), (w0, w1)
    # and samples published after the reset was counted reached it too
    r0 = after[0]["faulty"]
    assert f["samples"] > r0["samples"] and streams["faulty"].end() > mark(r0), (r0, f)

    # the SPI device: garbage in WHO_AM_I at start-up, named with the byte read; then it runs,
    # counting what went wrong by kind, and never takes a garbled answer for a chip reset
    s = cli["spi"]
    named = r"spi: start failed: WHO_AM_I \(0x75\) reads 0x[0-9a-f]{2}, expected 0x47"
    assert re.search(named, log), log
    assert s["samples"] > 0 and _garbled(s) >= 1, s
    assert s["bus_errors_eio"] >= 1 and s["bus_errors_timeout"] >= 1, s
    assert s["resets"] == 0 and s["restarts"] == 0 and s["unexpected_errors"] == 0, s

    # the bus-mate never noticed: no error, no restart, and no gap since its first sample
    c = cli["clean"]
    assert c["restarts"] == 0 and c["resets"] == 0 and c["bus_errors"] == 0, c
    gaps = [
        (f0 + n0, f1)
        for (f0, n0, _), (f1, _, _) in itertools.pairwise(streams["clean"].batches)
        if f1 != f0 + n0
    ]
    if c["lost_samples"] or gaps:
        # the machine stopped the other bus's process too, for longer than this FIFO lasts
        other_late_ms = max(m["spi"]["poll_late_max_ms"] for m in snaps)
        if other_late_ms > CLEAN_FIFO_MS:
            pytest.xfail(
                f"clean lost {c['lost_samples']} samples in {c['fifo_overflows']} FIFO "
                f"overflows while the machine stalled every bus process ({c['poll_late_max_ms']} "
                f"ms late here, {other_late_ms} ms on the SPI bus; its FIFO lasts "
                f"{CLEAN_FIFO_MS:.0f} ms): no verdict on its neighbour's faults"
            )
    assert c["lost_samples"] == 0 and c["fifo_overflows"] == 0 and not gaps, (c, gaps)
    assert all(lost == 0 for _, _, lost in streams["clean"].batches)


@pytest.mark.parametrize("to_bank0", [False, True], ids=["select", "return-to-bank0"])
def test_icm_a_lost_bank_select_is_not_a_chip_reset(to_bank0: bool) -> None:
    """At virtual time: writes of REG_BANK_SEL lost on the line (SPI has no acknowledge; the
    simulated bus drops a write it garbles), six, one at a time: each a select of bank 1 or 2,
    or each a return from there to bank 0, while an ICM-42688-P streams with room in its FIFO.
    The chip never resets and its FIFO never overflows, so nothing is lost and no reset is
    reported. Before the driver read its bank selects back: a
    lost select of bank 1 or 2 made the re-check read a bank-0 register and re-initialise the
    chip (here 4 times, 384 samples lost), and a lost return to bank 0 made a poll read its FIFO
    data, and the next polls their count, from bank 1 or 2 (249 lost)."""
    spi = {"kind": "sim", "transport": "spi", "cs": 0, "speed_hz": 10_000_000}
    rig = make_rig({"chip": "icm42688p", "bus": spi, "odr_hz": 1000},
                   {"seed": 1, "motion": {"kind": "still"}})  # fmt: skip
    rig.run(0.5)
    write, armed, lost = rig.sim.write, [False], []

    def lossy(register: int, data: bytes) -> None:
        held = rig.sim.bank  # a select of bank 0 while it is held would be lost harmlessly
        wanted = (data[0] == 0 and held != 0) if to_bank0 else (data[0] != 0 and held == 0)
        if register == int(Bank0.REG_BANK_SEL) and wanted and armed[0]:
            armed[0] = False
            lost.append(data)  # this one never reaches the chip
            return
        write(register, data)

    rig.sim.write = lossy
    for _ in range(6):
        armed[0] = True
        for _ in range(100):  # the next such write: within a round of the register re-check
            rig.run(0.05)
            if not armed[0]:
                break
        rig.run(0.2)  # the polls after it
    st = rig.runner.status().to_json()
    assert len(lost) == 6  # the test did what it says
    assert (st["resets"], st["restarts"], st["lost_samples"]) == (0, 0, 0), st
