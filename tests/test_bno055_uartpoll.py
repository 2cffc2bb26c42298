"""The BNO055 over a slow UART, at virtual time: a full read takes about as long as the chip's
100 Hz period, so the driver finds the sample grid's phase with short probes and places its
full reads between samples (imud/chips/bno055/uartpoll.py). Every sample the link had no time
for is counted exactly, and the stamps sit on the chip's true sample instants."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from imud.channels import Channel
from imud.chips.bno055.driver import Bno055Driver
from imud.chips.bno055.uart import UartStats
from imud.chips.bno055.uartpoll import PROBE_LEN
from imud.clock import VirtualClock
from imud.config import parse_config
from imud.pipeline import Pipeline
from imud.timestamps import SampleClock

CHAR_NS = 10e9 / 115200  # 8N1 at 115200 baud: 86.8 us a byte
CHUNK_GAP_NS = 2_000_000  # the driver sends a request two bytes at a time, 2 ms apart
LEAD_NS = round(4 * CHAR_NS + CHUNK_GAP_NS)  # read start -> the request's last byte is in
SNAP_NS = 1_000_000  # request in -> the chip's snapshot (its receive handling)
FRAME_NS = 1_000_000  # a USB serial adapter hands bytes over in 1 ms frames
PERIOD_NS = 10_030_000  # the chip 0.3 % slow
PHASE_NS = 3_333_000


class SlowLink:
    """What the driver sees of a BNO055 behind a USB serial adapter, at virtual time: a read's
    request is in LEAD_NS after it starts (two character times, if its first chunk went out
    ahead at least 2 ms before), the chip snapshots its registers SNAP_NS later, and
    the answer (2 + length bytes) arrives at the link's rate plus a frame. The snapshot's
    sample index k is written into the accelerometer's x word, so what a published sample says
    is which one it is."""

    address = 0

    def __init__(self, clock: VirtualClock, jitter: np.random.Generator) -> None:
        self.clock = clock
        self.jitter = jitter
        self.stats = UartStats()
        self.latch = (0, 0)
        self.ahead: int | None = None  # when a request's first chunk went out ahead

    def prepare_read(self) -> None:
        self.ahead = self.clock.now_ns()

    def index(self, t_ns: int) -> int:
        return (t_ns - PHASE_NS) // PERIOD_NS

    def read(self, register: int, length: int) -> bytes:
        assert register == 0x08 and length in (PROBE_LEN, 46)
        t0 = self.clock.now_ns()
        if self.ahead is not None and t0 - self.ahead <= 20_000_000:
            # the first chunk went out ahead: the rest after the 2 ms pause, or at once
            t_in = max(t0, self.ahead + CHUNK_GAP_NS) + round(2 * CHAR_NS)
        else:
            t_in = t0 + LEAD_NS
        self.ahead = None
        snap = t_in + SNAP_NS + int(self.jitter.integers(0, 300_000))
        head = snap + int(2 * CHAR_NS) + FRAME_NS
        done = snap + int((2 + length) * CHAR_NS) + FRAME_NS
        self.clock.advance(done - t0)
        self.latch = (t_in, head - int(2 * CHAR_NS))  # as Bno055Uart brackets it
        k = self.index(snap)
        words = [k % 30000, 7, 981, 16, -32, 800, 900 + k % 7, -450, 0] + [0] * 3
        words += [16384, 0, 0, 0, 0, 0, 0, 0, 0, 981]
        body = np.asarray(words, dtype="<i2").tobytes() + bytes([25, 0xFF])
        return body[:length]

    def read_u8(self, register: int) -> int:
        return 0x0C  # OPR_MODE: NDOF

    def write_u8(self, register: int, value: int) -> None:
        pass

    def flush(self) -> None:
        pass


def run(seconds: float, seed: int = 1) -> dict[str, Any]:
    clock = VirtualClock()
    rng = np.random.default_rng(seed)
    link = SlowLink(clock, rng)
    cfg = parse_config(
        {
            "device": [
                {
                    "name": "b",
                    "chip": "bno055",
                    "bus": {"kind": "sim", "bus": "u", "transport": "serial", "baud": 115200},
                    "save_offsets": False,
                }
            ]
        }
    ).device[0]
    drv = Bno055Driver(cfg, link, clock, uart=link)  # type: ignore[arg-type]
    pipe = Pipeline(SampleClock(drv.nominal_period_ns), None, 0)
    seq, t_ns, k_true, lost = [], [], [], 0
    end = seconds * 1e9
    while clock.now_ns() < end:
        raw = drv.read()
        b = pipe.process(raw)
        lost += b.lost_before
        if b.n:
            seq.append(b.first_seq)
            t_ns.append(int(b.t_ns[0]))
            k_true.append(round(float(b.channels[Channel.ACCEL][0, 0]) * 100))
        # the bus worker wakes for the next poll up to 200 us late
        wait = max(0, (drv.next_poll_ns or 0) - clock.now_ns())
        clock.advance(wait + int(rng.integers(0, 200_000)))
    return {
        "seq": np.array(seq),
        "t": np.array(t_ns),
        "k": np.array(k_true),
        "lost": lost,
        "status": drv.chip_status(),
        "now": clock.now_ns(),
    }


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_sample_is_counted_exactly_and_stamped_on_its_instant(seed: int) -> None:
    r = run(20.0, seed)
    seq, k, t = r["seq"], r["k"], r["t"]
    # the published sequence numbers are the chip's own sample indices, less a constant: every
    # sample between two published ones was counted
    offsets = set((seq - k).tolist())
    assert len(offsets) == 1, offsets
    # the stamps: the chip's true sample instants, once the period is learnt (the first 2 s)
    settled = t > 2e9
    err = t[settled] - (PHASE_NS + k[settled] * PERIOD_NS)
    assert np.abs(err).max() < 1_000_000, (err.mean(), err.std(), np.abs(err).max())
    # the link: a full read is in 2.35 ms (0.2 ms with its first chunk ahead), snapshots 1-1.3
    # ms later and is answered 4.2 ms and a frame after that: under the 10 ms period, so once
    # the phase is known every sample can be read; only the probes and aimed reads cost any
    late = k[t > 5e9]
    produced = late[-1] - late[0] + 1
    assert len(late) / produced > 0.9, (len(late), produced, r["status"])
    assert r["status"]["phase_losses"] == 0
