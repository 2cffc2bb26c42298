"""`imud plot` on recordings made here, one with gaps and one without: the picture of the one
with gaps has its red gap lines, the other none, and the summary counts what was lost (the
`plot` extra: matplotlib)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imud.channels import Channel
from imud.recording.mcapfile import McapOut
from imud.recording.recorder import native_topic
from imud.recording.schemas import BATCH, batch_cdr
from imud.wire import encode

pytestmark = pytest.mark.extra


def recording(path: Path, gaps: list[int]) -> int:
    """20 s of a 200 Hz device in 0.1 s batches; before each batch index in `gaps`, 7 samples
    lost (the seq jumps and the batch says so). Returns the samples lost."""
    out = McapOut(path)
    rng = np.random.default_rng(1)
    seq, lost = 0, 0
    for k in range(200):
        before = 7 if k in gaps else 0
        seq += before
        lost += before
        t = 1_700_000_000_000_000_000 + (seq + np.arange(20)) * 5_000_000
        chans = {
            Channel.ACCEL: np.r_[0.0, 0.0, 9.81] + rng.normal(0, 0.02, (20, 3)),
            Channel.GYRO: rng.normal(0, 0.001, (20, 3)),
        }
        wire = encode("dev0", seq, t, chans, lost_before=before)
        out.add(native_topic("imud", "dev0"), BATCH, int(t[-1]), batch_cdr(wire))
        seq += 20
    out.close()
    return lost


def red_pixels(png: Path) -> int:
    import matplotlib.image as mpimg

    img = mpimg.imread(png)[..., :3]
    # the gap lines: red at 0.6 alpha on white, (1, 0.4, 0.4); not the orange of a data line
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    reddish = (r > 0.9) & (g < 0.6) & (b > 0.25) & (np.abs(g - b) < 0.1)
    return int(np.count_nonzero(reddish))


def test_gaps_are_drawn_and_counted(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    pictures = {}
    for name, gaps in (("clean", []), ("gappy", [40, 90, 150])):
        rec = tmp_path / f"{name}.mcap"
        lost = recording(rec, gaps)
        png = tmp_path / f"{name}.png"
        r = subprocess.run([sys.executable, "-m", "imud", "plot", str(rec), "-o", str(png)],
                           capture_output=True, text=True, timeout=120)  # fmt: skip
        assert r.returncode == 0, r.stderr
        assert f"{lost:,} lost" in r.stdout, r.stdout
        pictures[name] = red_pixels(png)
    assert pictures["clean"] == 0
    assert pictures["gappy"] > 200  # three lines through every panel


def test_bad_input_is_said(tmp_path: Path) -> None:
    rec = tmp_path / "r.mcap"
    recording(rec, [])
    for args, says in (
        ((str(rec), "-o", str(tmp_path / "x.jpg")), "name a .png file"),
        ((str(rec), "--device", "nope"), "has no device 'nope'"),
    ):
        r = subprocess.run([sys.executable, "-m", "imud", "plot", *args],
                           capture_output=True, text=True, timeout=120)  # fmt: skip
        assert r.returncode == 2 and says in r.stderr and "Traceback" not in r.stderr, r.stderr
