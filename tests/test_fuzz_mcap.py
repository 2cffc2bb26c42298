"""Recordings cut short or damaged anywhere: reading (open_recording, its batches) and
`--recover` either work or say what is wrong (McapInputError, RecoverError), never another
exception, which the CLI would show as a traceback."""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from imud.channels import Channel
from imud.recording.mcapfile import McapOut
from imud.recording.reader import McapInputError, open_recording
from imud.recording.recorder import native_topic
from imud.recording.recover import RecoverError, recover
from imud.recording.schemas import BATCH, batch_cdr
from imud.wire import encode

_DIR = Path(tempfile.mkdtemp(prefix="imud-fuzz-mcap-"))
atexit.register(shutil.rmtree, _DIR, ignore_errors=True)  # hypothesis's examples share it


def _valid() -> bytes:
    path = _DIR / "valid.mcap"
    if not path.exists():
        out = McapOut(path, flush_s=0.0)  # a chunk a message: many places to cut
        for k in range(30):
            t = 10**18 + (k * 10 + np.arange(10)) * 1_000_000
            chans = {Channel.ACCEL: np.zeros((10, 3)), Channel.GYRO: np.ones((10, 3))}
            wire = encode("dev0", k * 10, t, chans)
            out.add(native_topic("imud", "dev0"), BATCH, int(t[-1]), batch_cdr(wire))
        out.close()
    return path.read_bytes()


@settings(max_examples=150, deadline=None)
@given(st.data())
def test_cut_or_damaged_anywhere(data: st.DataObject) -> None:
    raw = bytearray(_valid())
    cut = data.draw(st.integers(0, len(raw)))
    raw = raw[:cut]
    for _ in range(data.draw(st.integers(0, 3))):
        if raw:
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    path = _DIR / f"case-{cut}.mcap"
    path.write_bytes(bytes(raw))
    try:
        rec = open_recording(path)
        for _ in rec.batches():
            pass
    except McapInputError as e:
        assert str(path) in str(e)
    out = _DIR / f"case-{cut}-recovered.mcap"
    out.unlink(missing_ok=True)
    try:
        recover(path, out)
    except RecoverError as e:
        assert str(path) in str(e)
