"""The compiled kernels (imud/_kernels.c, imud/chips/*/_*.c) against their NumPy twins.

The twins are the reference: each is checked against datasheet byte vectors and physics in its
own tests (tests/test_icm42688p_decode.py, tests/test_timestamps.py, tests/test_pipeline_flags.py).
Here every kernel must give the same results to the bit on the same inputs: hand-written edge
cases, random inputs, and a whole simulated chip run both ways through the daemon's runner.
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from imud import align, compiled, pipeline, timestamps, wire
from imud.calib import track
from imud.channels import Channel
from imud.chips.api import RawChannel
from imud.chips.bmi088 import decode as bmi
from imud.chips.bmi088 import registers as bmi_r
from imud.chips.icm42688p import driver as icm
from imud.chips.icm42688p import registers as icm_r
from imud.orient import ekf, kalman
from imud.settings import GyroBiasTracking
from imud.sim import scenarios as sc
from tests.helpers import make_rig

KERNELS = ["imud._kernels", "imud.chips.icm42688p._fifo", "imud.chips.bmi088._fifo"]
FUZZ = settings(max_examples=300, deadline=None)


def _kernel(name: str) -> Any:
    if compiled.pure():
        pytest.skip("IMUD_PURE_PYTHON is set: the NumPy twins run")
    try:
        return importlib.import_module(name)
    except ImportError:  # test_every_kernel_is_built fails for it, saying why
        pytest.skip(f"{name} was not built")


@pytest.mark.parametrize("name", KERNELS)
def test_every_kernel_is_built(name: str) -> None:
    if compiled.pure():
        pytest.skip("IMUD_PURE_PYTHON is set: the NumPy twins run")
    try:
        importlib.import_module(name)
    except ImportError as e:
        pytest.fail(
            f"{name} was not built ({e}): install a C compiler and Python's headers "
            "(Debian: build-essential python3-dev), then `pip install -e .` again"
        )


def test_a_missing_kernel_falls_back_and_is_reported() -> None:
    """A kernel that is not there: load gives None (the caller runs the twin), and missing()
    names it; IMUD_PURE_PYTHON=1 asks for the twins everywhere, and nothing is then missing."""
    code = (
        "from imud import compiled\n"
        "assert compiled.load('imud._no_such_kernel') is None\n"
        "assert compiled.load('imud._no_such_kernel') is None\n"
        "compiled.warn_missing()\n"
        "compiled.warn_missing()\n"
        "print(compiled.missing())\n"
    )
    env = {k: v for k, v in os.environ.items() if k != compiled.PURE_ENV}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    assert out.stdout.strip() == "['imud._no_such_kernel']"
    # the process says so when asked (a device about to stream asks), once, and the fix
    assert out.stderr.count("compiled kernels not built: imud._no_such_kernel.") == 1
    assert "build-essential" in out.stderr
    code = (
        "from imud import compiled, timestamps\n"
        "assert compiled.load('imud._kernels') is None and timestamps._kernels is None\n"
        "print(compiled.missing())\n"
    )
    env = {**env, compiled.PURE_ENV: "1"}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    assert out.stdout.strip() == "[]"


# --- ICM-42688-P FIFO decode ---------------------------------------------------------------------


def test_icm_kernel_constants_are_the_register_maps() -> None:
    k = _kernel("imud.chips.icm42688p._fifo")
    assert k.HDR_EMPTY == icm_r.Header.MSG
    assert k.HDR_ACCEL == icm_r.Header.ACCEL
    assert k.HDR_GYRO == icm_r.Header.GYRO
    assert k.HDR_20 == icm_r.Header.HIRES_20
    assert k.INVALID_16 == icm_r.INVALID_16
    assert k.INVALID_20 == icm_r.INVALID_20
    assert k.INVALID_TEMP_8 == icm_r.INVALID_TEMP_8
    assert k.TIMESTAMP_MODULO == icm_r.TIMESTAMP_MODULO


def _same_packets(data: bytes, hires: bool, per_sample: float) -> None:
    _kernel("imud.chips.icm42688p._fifo")
    p, breaks = icm.decode_fifo(data, hires, per_sample)
    q = icm.decode_packets(data, hires)
    assert breaks == icm.timestamp_breaks(q.timestamp, per_sample)
    assert p.n == q.n and bool(p.clean) == bool(q.clean)
    for name in ("accel", "gyro", "temperature_c", "timestamp"):
        a, b = getattr(p, name), getattr(q, name)
        assert a.dtype == b.dtype and a.shape == b.shape, name
        assert a.tobytes() == b.tobytes(), name  # to the bit (NaN-free: temperatures are finite)
    for name in ("accel_invalid", "gyro_invalid", "temperature_invalid"):
        assert getattr(p, name).tolist() == getattr(q, name).tolist(), name


# headers a FIFO can send, and some it should not: valid packets, a sensor missing, no 20-bit
# data, 'FIFO empty' alone and with other bits
HEADERS = [0x68, 0x78, 0x60, 0x70, 0x48, 0x28, 0x08, 0x00, 0x80, 0xE8, 0xFF, 0x10]
# values near the invalid markers and the ends of the range, and anything
VALUES = st.one_of(st.sampled_from([-32768, -32767, -1, 0, 1, 32767]), st.integers(-32768, 32767))


@st.composite
def fifo_bytes(draw: st.DrawFn, hires: bool) -> bytes:
    n = draw(st.integers(0, 40))
    rec = np.zeros(n, dtype=icm.PACKET4 if hires else icm.PACKET3)
    rec["hdr"] = draw(st.lists(st.sampled_from(HEADERS), min_size=n, max_size=n))
    for field in ("accel", "gyro"):
        if draw(st.booleans()):  # whole sensors at the marker, often
            rec[field] = draw(st.sampled_from([-32768, 0, 5]))
        else:
            rec[field] = np.array(
                draw(st.lists(VALUES, min_size=3 * n, max_size=3 * n)), dtype=np.int64
            ).reshape(n, 3)
    lo, hi = (-32768, 32767) if hires else (-128, 127)
    rec["temp"] = draw(st.lists(st.sampled_from([lo, lo + 1, 0, hi]), min_size=n, max_size=n))
    # timestamps a sample apart (ticks_per_sample below), sometimes jumping or wrapping
    start = draw(st.integers(0, 0xFFFF))
    steps = draw(st.lists(st.sampled_from([1, 1, 1, 2, 7, 40_000]), min_size=n, max_size=n))
    rec["ts"] = (start + np.cumsum(steps)) % 0x10000
    if hires:
        rec["ext"] = np.array(
            draw(st.lists(st.integers(0, 255), min_size=3 * n, max_size=3 * n)), dtype=np.uint8
        ).reshape(n, 3)
    tail = draw(st.binary(max_size=(20 if hires else 16) - 1))
    return rec.tobytes() + tail


@FUZZ
@given(st.booleans(), st.data(), st.sampled_from([1.0, 1.3, 8.0, 30_000.0]))
def test_icm_decode_matches_numpy_on_packets(hires: bool, data: Any, per_sample: float) -> None:
    _same_packets(data.draw(fifo_bytes(hires)), hires, per_sample)


@FUZZ
@given(st.binary(max_size=2100), st.booleans(), st.floats(0.01, 1e5))
def test_icm_decode_matches_numpy_on_any_bytes(data: bytes, hires: bool, per_sample: float) -> None:
    _same_packets(data, hires, per_sample)


def test_icm_decode_hand_vectors() -> None:
    from tests import test_icm42688p_decode as v

    for data, hires in [
        (v.P3_A, False),
        (v.P3_B, False),
        (v.P3_A + v.P3_B + v.FIFO_EMPTY + v.P3_A, False),
        (v.P3_A + v.ACCEL_INVALID + v.GYRO_INVALID, False),
        (v.P4_A + v.P4_B, True),
        (v.P4_A + v.P4_B + v.P4_A[:19], True),
        (b"", False),
        (b"", True),
    ]:
        _same_packets(data, hires, 8.0)


def test_icm_decode_refuses_outputs_too_small() -> None:
    k = _kernel("imud.chips.icm42688p._fifo")
    data = bytes(16 * 4)
    small = np.empty((3, 3), np.int32)
    ok = np.empty((4, 3), np.int32)
    with pytest.raises(ValueError, match="accel"):
        k.decode(data, False, 0.0, small, ok, np.empty(4), np.empty(4, np.int64),
                 np.empty((3, 4), bool))  # fmt: skip
    ro = np.zeros((3, 4), bool)
    ro.setflags(write=False)
    with pytest.raises((BufferError, ValueError)):  # a read-only output
        k.decode(data, False, 0.0, ok, ok.copy(), np.empty(4), np.empty(4, np.int64), ro)


# --- the sample clock's stamps and ticks ---------------------------------------------------------


@FUZZ
@given(
    st.integers(1, 300),
    st.floats(0, 2e15),
    st.floats(-1e6, 1e6),
    st.integers(-(10**6), 10**9),
    st.floats(1e3, 1e8),
    st.floats(-1e7, 1e7),
    st.one_of(st.none(), st.integers(0, 2 * 10**15)),
    st.booleans(),
    st.floats(0, 1e6),
)
def test_line_stamps_match_numpy(
    n: int,
    s: float,
    b: float,
    k0: int,
    period: float,
    corr: float,
    last: int | None,
    follow: bool,
    room: float,
) -> None:
    k = _kernel("imud._kernels")
    want = timestamps.line_stamps_numpy(n, s, b, k0, period, corr, last, follow, room)
    got = np.empty(n, dtype=np.int64)
    k.stamps(got, s, b, k0, period, corr, last, follow and last is not None, room)
    assert got.tolist() == want.tolist()


def test_line_stamps_near_the_last_stamp() -> None:
    """Where the rounding, the slew and the strictly-after rule all bite: a line a fraction of a
    nanosecond off .5, steered from a last stamp ahead of it."""
    k = _kernel("imud._kernels")
    for last in (None, 1_000_000_000_000, 1_000_000_000_500, 1_000_000_010_000):
        for s in (1_000_000_000_000.5, 1_000_000_000_001.5, 999_999_999_999.4999):
            args = (64, s, 0.0, 1, 125_000.0, -0.5, last, last is not None, 625.0)
            want = timestamps.line_stamps_numpy(*args)
            got = np.empty(64, dtype=np.int64)
            k.stamps(got, *args[1:])
            assert got.tolist() == want.tolist(), (last, s)


@FUZZ
@given(st.lists(st.integers(-(2**40), 2**40), max_size=80), st.sampled_from([7, 1 << 16, 1 << 32]))
def test_tick_steps_match_numpy(ticks: list[int], mod: int) -> None:
    k = _kernel("imud._kernels")
    a = np.asarray(ticks, dtype=np.int64)
    steps = np.diff(a) % mod
    want = (int(steps.max()), int(steps.sum())) if steps.size else (0, 0)
    assert k.tick_steps(a, mod) == want


def test_tick_steps_wrap_as_numpy_does() -> None:
    """Differences beyond int64 wrap in NumPy; the kernel wraps them the same way."""
    k = _kernel("imud._kernels")
    a = np.array([3 * 2**61, -3 * 2**61, 5, 2**63 - 1, -(2**63)], dtype=np.int64)
    with np.errstate(over="ignore"):
        steps = np.diff(a) % (1 << 16)
    assert k.tick_steps(a, 1 << 16) == (int(steps.max()), int(steps.sum()))


def test_tick_steps_refuse_other_integers() -> None:
    k = _kernel("imud._kernels")
    with pytest.raises(TypeError, match="int64"):
        k.tick_steps(np.arange(4, dtype=np.int32), 16)
    with pytest.raises(ValueError, match="positive"):
        k.tick_steps(np.arange(4, dtype=np.int64), 0)


@FUZZ
@given(
    st.lists(st.integers(-(2**31), 2**31 - 1), min_size=1, max_size=60),
    st.sampled_from([1.0, 32767.0, 32768.0, 524288.0, 2.0**31, 5e9]),
)
def test_reaches_matches_numpy(values: list[int], fs: float) -> None:
    k = _kernel("imud._kernels")
    a = np.asarray(values, dtype=np.int32)
    want = bool(a.max() >= fs or a.min() <= -fs)
    assert k.reaches(a, fs) is want
    assert k.reaches(a[::2], fs) is bool(a[::2].max() >= fs or a[::2].min() <= -fs)
    # a driver's columns of a wider record: two dimensions, strided
    m = np.resize(a, (len(values), 6))[:, 1:4]
    assert k.reaches(m, fs) is bool(m.max() >= fs or m.min() <= -fs)
    assert k.reaches(m.T, fs) is bool(m.max() >= fs or m.min() <= -fs)


def test_reaches_refuses_other_dtypes() -> None:
    k = _kernel("imud._kernels")
    with pytest.raises(TypeError, match="int32"):
        k.reaches(np.zeros(3, np.int64), 1.0)
    with pytest.raises(TypeError, match="two dimensions"):
        k.reaches(np.zeros((2, 2, 2), np.int32), 1.0)
    # the pipeline hands those to NumPy instead
    assert pipeline.reaches(np.array([0.0, 2.5]), 2.5) is True


# --- BMI088 accel FIFO walk ----------------------------------------------------------------------


def test_bmi_kernel_constants_are_the_register_maps() -> None:
    k = _kernel("imud.chips.bmi088._fifo")
    h = bmi_r.AccFifoHeader
    assert k.HEADER_MASK == bmi_r.ACC_FIFO_HEADER_MASK
    assert (k.HDR_ACCEL, k.HDR_SKIP, k.HDR_SENSORTIME) == (h.ACCEL, h.SKIP, h.SENSORTIME)
    assert (k.HDR_INPUT_CONFIG, k.HDR_SAMPLE_DROP) == (h.INPUT_CONFIG, h.SAMPLE_DROP)
    assert k.HDR_OVER_READ == h.OVER_READ
    assert k.ACCEL_FRAME == bmi_r.ACC_FRAME_BYTES == bmi_r.ACC_FIFO_FRAME_BYTES[h.ACCEL]
    sizes = {h.SKIP: 2, h.SENSORTIME: 4, h.INPUT_CONFIG: 2, h.SAMPLE_DROP: 2}
    assert {k: v for k, v in bmi_r.ACC_FIFO_FRAME_BYTES.items() if k != h.ACCEL} == sizes


@st.composite
def accel_fifo(draw: st.DrawFn) -> bytes:
    """Frames as the die writes them (any tag bits), control frames between, and sometimes a
    stray byte, an over-read marker or a frame cut off at the end."""
    out = b""
    for _ in range(draw(st.integers(0, 30))):
        kind = draw(st.sampled_from(["accel"] * 6 + ["skip", "time", "config", "drop", "junk"]))
        tag = draw(st.integers(0, 3))
        if kind == "accel":
            out += bytes([0x84 | tag]) + draw(st.binary(min_size=6, max_size=6))
        elif kind == "skip":
            out += bytes([0x40 | tag, draw(st.integers(0, 255))])
        elif kind == "time":
            out += bytes([0x44 | tag]) + draw(st.binary(min_size=3, max_size=3))
        elif kind in ("config", "drop"):
            out += bytes([(0x48 if kind == "config" else 0x50) | tag, 0])
        else:
            out += bytes([draw(st.integers(0, 255))])
    return out + draw(st.sampled_from([b"", b"\x80", b"\x80\x00\x00", b"\x84\x01\x02", b"\x44"]))


def _same_accel_fifo(data: bytes) -> None:
    _kernel("imud.chips.bmi088._fifo")
    got, want = bmi.decode_accel_fifo(data), bmi.decode_accel_fifo_numpy(data)
    assert got.accel.dtype == want.accel.dtype and got.accel.shape == want.accel.shape
    assert got.accel.tolist() == want.accel.tolist()
    assert got.skipped_before == want.skipped_before
    assert got.sensortime == want.sensortime
    assert got.over_read == want.over_read and got.corrupt_at == want.corrupt_at


@FUZZ
@given(accel_fifo())
def test_bmi_accel_walk_matches_numpy_on_frames(data: bytes) -> None:
    _same_accel_fifo(data)


@FUZZ
@given(st.binary(max_size=1100))
def test_bmi_accel_walk_matches_numpy_on_any_bytes(data: bytes) -> None:
    _same_accel_fifo(data)


# --- the align stage's interpolation -------------------------------------------------------------


@st.composite
def follower(draw: st.DrawFn) -> tuple[list[Any], Any]:
    """Reads of another die (times rising, seqs with gaps, some values invalid, a 3-axis and a
    1-value channel), then the primary's times to place among them."""
    reads = []
    t, seq = draw(st.integers(0, 10**6)), 0
    for _ in range(draw(st.integers(1, 4))):
        n = draw(st.integers(1, 12))
        steps = draw(st.lists(st.integers(1, 900_000), min_size=n, max_size=n))
        ts = t + np.cumsum(steps)
        gaps = draw(st.lists(st.sampled_from([1, 1, 1, 2, 5]), min_size=n, max_size=n))
        seqs = seq + np.cumsum(gaps)
        t, seq = int(ts[-1]), int(seqs[-1])
        acc = np.array(draw(st.lists(st.integers(-32768, 32767), min_size=3 * n, max_size=3 * n)))
        inv = np.array(
            draw(st.lists(st.sampled_from([False] * 5 + [True]), min_size=n, max_size=n))
        )
        channels = {
            Channel.ACCEL: RawChannel(acc.reshape(n, 3).astype(np.int32), 0.01, 32768.0,
                                      inv if inv.any() else None),
            Channel.TEMPERATURE: RawChannel(np.linspace(20, 21, n)),
        }  # fmt: skip
        reads.append((seqs.astype(np.int64), ts.astype(np.int64), channels))
    lo, hi = int(reads[0][1][0]) - 2_000_000, t + 2_000_000
    times = sorted(set(draw(st.lists(st.integers(lo, hi), min_size=1, max_size=40))))
    return reads, np.array(times, dtype=np.int64)


@FUZZ
@given(follower())
def test_interpolation_matches_numpy(case: tuple[list[Any], Any]) -> None:
    _kernel("imud._kernels")
    reads, t = case
    results = []
    for kernels in (align._kernels, None):
        f = align._Follower()
        for seq, ts, channels in reads:
            f.add(seq, ts, channels)
        saved, align._kernels = align._kernels, kernels
        try:
            results.append((f.at(t), f.t.tolist(), f.seq.tolist()))
        finally:
            align._kernels = saved
    (fast, ft, fs), (slow, st_, ss) = results
    assert (ft, fs) == (st_, ss)  # the same history let go
    assert fast.keys() == slow.keys()
    for ch in fast:
        a, b = fast[ch], slow[ch]
        assert a.data.dtype == b.data.dtype and a.data.shape == b.data.shape
        assert a.data.tobytes() == b.data.tobytes(), ch
        assert (a.invalid is None) == (b.invalid is None)
        if a.invalid is not None and b.invalid is not None:
            assert a.invalid.tolist() == b.invalid.tolist()


def test_interpolation_refuses_mismatched_buffers() -> None:
    k = _kernel("imud._kernels")
    n = 3
    jj, w, base = np.zeros(n, np.int64), np.zeros(n), np.ones(n, bool)
    v, inv = np.zeros((4, 3)), np.zeros(4, bool)
    with pytest.raises(ValueError, match="outputs"):
        k.lerp(v, inv, jj, w, base, np.empty((n, 2)), np.empty(n, bool))
    with pytest.raises(ValueError, match="outside"):
        k.lerp(v, inv, np.full(n, 3, np.int64), w, base, np.empty((n, 3)), np.empty(n, bool))
    with pytest.raises(ValueError, match="seq"):
        k.bracket(np.zeros(4, np.int64), np.zeros(2, np.int64), np.zeros(n, np.int64), jj, w,
                  base)  # fmt: skip


# --- the wire batch's bytes ----------------------------------------------------------------------


@FUZZ
@given(
    st.integers(0, 50),
    st.sampled_from([np.float64, np.float32]),
    st.booleans(),
    st.booleans(),
    st.text(max_size=9),
    st.integers(0, 3),
)
def test_pack_matches_numpy(
    n: int, dtype: Any, flagged: bool, strided: bool, name: str, seed: int
) -> None:
    """Stamps, flags and channels (float64 or float32, values float32 cannot hold among them:
    huge, tiny, NaN) packed by the kernel and by NumPy: the same bytes."""
    _kernel("imud._kernels")
    rng = np.random.default_rng(seed)
    special = np.array([0.0, -0.0, 1e39, -1e39, 1e-46, np.nan, np.inf, 1 / 3])
    values = rng.normal(size=(n, 8)) * 10.0 ** rng.integers(-8, 8, size=(n, 8))
    if n:
        values.flat[: min(values.size, special.size)] = special[: min(values.size, 8)]
    with np.errstate(over="ignore"):  # (1e39 is float32's infinity: on purpose)
        wide = values.astype(dtype)
    channels = {
        Channel.ACCEL: wide[:, 0:6:2] if strided else np.ascontiguousarray(wide[:, 0:3]),
        Channel.GYRO: np.ascontiguousarray(wide[:, 3:6]),
        Channel.TEMPERATURE: np.ascontiguousarray(wide[:, 6]),
    }
    t = np.cumsum(rng.integers(1, 10**6, size=n)).astype(np.int64)
    sf = rng.integers(0, 2**32, size=n, dtype=np.uint32) if flagged else None
    args = (name, 17, t, channels, sf)
    saved = wire._pack
    with np.errstate(over="ignore"):
        fast = wire.encode(*args, flags=3, lost_before=2)
        wire._pack = None
        try:
            slow = wire.encode(*args, flags=3, lost_before=2)
        finally:
            wire._pack = saved
    assert fast == slow
    b = wire.decode(fast)  # and it is a batch
    assert b.count == n and b.t_ns.tolist() == t.tolist()


def test_pack_refuses_what_it_cannot_pack() -> None:
    k = _kernel("imud._kernels")
    t = np.arange(3, dtype=np.int64)
    with pytest.raises(TypeError, match="float64 or float32"):
        k.pack(b"", t, None, (np.zeros(3, np.int32),))
    with pytest.raises(TypeError, match="int64"):
        k.pack(b"", t.astype(np.int32), None, ())
    with pytest.raises(TypeError, match="sample flags"):
        k.pack(b"", t, np.zeros(2, np.uint32), ())
    with pytest.raises((BufferError, ValueError)):
        k.pack(b"", t, None, (np.zeros((3, 6))[:, ::2],))
    # and encode then packs such channels with NumPy
    raw = wire.encode("d", 0, t, {Channel.ACCEL: np.zeros((3, 3), np.int32)})
    assert wire.decode(raw).channels[Channel.ACCEL].tolist() == [[0.0] * 3] * 3


# --- the orientation filter's integration --------------------------------------------------------


@FUZZ
@given(
    st.integers(1, 70),
    st.integers(0, 2**32 - 1),
    st.booleans(),
    st.booleans(),
    st.integers(0, 500),
)
def test_orient_chunk_matches_numpy(
    m: int, seed: int, with_accel: bool, holes: bool, steps: int
) -> None:
    """A chunk of gyro (fast turns among them) and accelerometer samples, some invalid (NaN),
    integrated by the kernel and by NumPy from the same state: the same orientations, sums and
    end, to rounding (the twin's matrix products add in another order)."""
    _kernel("imud._kernels")
    rng = np.random.default_rng(seed)
    gyro = rng.normal(0.0, 3.0, size=(m, 3)) * rng.choice([0.01, 1.0, 30.0])
    accel = rng.normal(0.0, 2.0, size=(m, 3)) + np.array([0.0, 0.0, 9.81])
    if holes:
        gyro[rng.random(m) < 0.1] = np.nan
        accel[rng.random(m) < 0.2] = np.nan
    q0 = rng.normal(size=4)
    q0 /= np.linalg.norm(q0)
    runs = []
    for use_kernel in (True, False):
        f = ekf.OrientationFilter(ekf.NoiseModel(1e-4, 1e-3))
        f.q, f.b = q0.copy(), rng.normal(0, 0.01, 3) if use_kernel else runs[0][6]
        f._iv.steps = steps
        f._iv.qq[:] = 1.0
        f.P = np.arange(64.0).reshape(8, 8)
        q_out, c_out = np.empty((m, 4)), np.empty((m, 6))
        saved, ekf._kernels = ekf._kernels, ekf._kernels if use_kernel else None
        try:
            f._chunk(gyro, accel if with_accel else None, 0.001, q_out, c_out)
        finally:
            ekf._kernels = saved
        iv = f._iv
        runs.append((q_out, f.q, iv.qq, iv.qqa, iv.kqqa, (iv.n, iv.kn, iv.steps, iv.t), f.b, c_out))
    fast, slow = runs
    for a, b in zip(fast[:5], slow[:5], strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(b).max()))
    assert fast[5] == slow[5]
    # every row: the rotation error's covariance (xx, xy, xz, yy, yz, zz) of the 8 x 8
    assert fast[7].tolist() == slow[7].tolist() == [[0.0, 1.0, 2.0, 9.0, 10.0, 18.0]] * m


@pytest.mark.parametrize(
    "form",
    [
        lambda x: x.astype(np.float32),
        np.asfortranarray,
        lambda x: np.repeat(x, 2, axis=0)[::2],  # a strided view
    ],
    ids=["float32", "fortran", "strided"],
)
def test_orient_and_track_kernels_take_any_float_rows(form: Any) -> None:
    """Rows the kernels cannot read in place (another dtype, another layout) go through a
    float64 copy: the same results as the float64 rows of the same values."""
    _kernel("imud._kernels")
    rng = np.random.default_rng(4)
    gyro = rng.normal(0.0, 0.5, size=(40, 3))
    accel = rng.normal(0.0, 0.3, size=(40, 3)) + np.array([0.0, 0.0, 9.81])
    runs = []
    for g, a in ((form(gyro), form(accel)), (form(gyro).astype(float), form(accel).astype(float))):
        f = ekf.OrientationFilter(ekf.NoiseModel(1e-4, 1e-3))
        q_out, c_out = np.empty((40, 4)), np.empty((40, 6))
        f._chunk(g, a, 0.001, q_out, c_out)
        t = track.GyroBiasTracker(GyroBiasTracking())
        rows = t._windows(g, a, 8)
        runs.append((q_out, f.q, f._iv.qqa, np.array(rows)))
    for x, y in zip(*runs, strict=True):
        assert x.tolist() == y.tolist()
    assert len(runs[0][3]) == 5


# --- the orientation filter's correction ---------------------------------------------------------


def _both(fn: Any, *args: Any) -> tuple[Any, Any, list[np.ndarray], list[np.ndarray]]:
    """`fn(*args)` with the kernels and with the NumPy twins, each on its own copies of the
    arrays: (kernel result, twin result, kernel's arrays after, twin's arrays after)."""
    runs = []
    saved = kalman._kernels
    for k in (saved, None):
        copies = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
        kalman._kernels = k
        try:
            out = fn(*copies)
        finally:
            kalman._kernels = saved
        runs.append((out, [a for a in copies if isinstance(a, np.ndarray)]))
    return runs[0][0], runs[1][0], runs[0][1], runs[1][1]


def _close(a: np.ndarray, b: np.ndarray) -> None:
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-13 * max(1.0, float(np.abs(b).max())))


def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    """A covariance-like matrix: positive definite, entries spread over decades."""
    a = rng.normal(size=(n, n)) * np.exp(rng.uniform(-8.0, 0.0, size=n))[:, None]
    out: np.ndarray = a @ a.T + np.diag(np.exp(rng.uniform(-14.0, -4.0, size=n)))
    return out


@FUZZ
@given(st.integers(0, 2**32 - 1))
def test_orient_sums_and_propagation_match_numpy(seed: int) -> None:
    """An interval's specific-force sums and the covariance's propagation over it (the linear
    acceleration decaying with it): the kernel and NumPy agree to rounding."""
    _kernel("imud._kernels")
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    q2 = (q[:, :, None] * q[:, None, :]).reshape(50, 16)
    a = rng.normal(0.0, 3.0, size=(50, 3))
    qq, qqa, kqqa = q2.sum(axis=0), q2.T @ a, q2.T @ (a * np.arange(50)[:, None])
    fast, slow, _, _ = _both(kalman.force_sums, qqa, kqqa)
    _close(np.array(fast), np.array(slow))
    # the plain sum is the quaternions' rotations applied to the samples (an independent check)
    w, x, y, z = q.T
    rotated_x = (
        (w * w + x * x - y * y - z * z) * a[:, 0]
        + 2 * (x * y - w * z) * a[:, 1]
        + 2 * (x * z + w * y) * a[:, 2]
    ).sum()
    assert fast[0] == pytest.approx(rotated_x, rel=1e-12, abs=1e-11)

    p = _spd(rng, 8)
    density = np.exp(rng.uniform(-20.0, -8.0, size=8))
    rho, t, lvar = float(rng.uniform(0.5, 1.0)), float(rng.uniform(0.01, 0.5)), 0.01
    lin = rng.normal(size=2)
    args = (p, qq, t / 50, rho, density, t, lvar, lin)
    _, _, (pf, *_, af), (ps, *_, as_) = _both(kalman.propagate, *args)
    _close(pf, ps)
    _close(af, as_)
    assert af.tolist() == pytest.approx((lin * rho).tolist(), rel=1e-15)


@FUZZ
@given(
    st.integers(0, 2**32 - 1),
    st.sampled_from(list(kalman.Learn)),
    st.integers(1, 3),
    st.booleans(),
    st.floats(0.01, 30.0),
)
def test_orient_update_matches_numpy(
    seed: int, learn: kalman.Learn, d: int, keep_heading: bool, gate: float
) -> None:
    """Gravity's measurement matrix and a gated update, accepted or rejected, with every way of
    learning less than all: the kernel and NumPy agree to rounding, and a rejected update
    changes nothing."""
    _kernel("imud._kernels")
    rng = np.random.default_rng(seed)
    p = _spd(rng, 8)
    qq = rng.normal(size=16)
    h2 = np.empty((2, 8))
    fast, slow, (_, _, hf), (_, _, hs) = _both(kalman.gravity_h, p, qq, 0.01, 9.81, h2)
    _close(hf, hs)
    assert fast == pytest.approx(slow, rel=1e-12)
    h = hs if d == 2 else rng.normal(size=(d, 8))
    s = h @ p @ h.T
    r = tuple((np.exp(rng.uniform(-3.0, 1.0, size=d)) * float(np.trace(s)) / d).tolist())
    y = tuple((rng.normal(size=d) * np.sqrt(np.diag(s) + r) * rng.uniform(0.5, 3.0)).tolist())
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    b, lin = rng.normal(size=3), rng.normal(size=2)
    args = (p, h, y, r, gate, learn, 5.991, q, keep_heading, b, lin)
    fast, slow, (pf, _, qf, bf, af), (ps, _, qs, bs, as_) = _both(kalman.update, *args)
    assert (fast is None) == (slow is None)
    for x, y_ in ((pf, ps), (qf, qs), (bf, bs), (af, as_)):
        _close(x, y_)
    if fast is None:
        assert (pf == p).all() and (qf == q).all() and (bf == b).all() and (af == lin).all()
    else:
        _close(np.array(fast), np.array(slow))
        assert (pf == pf.T).all()
        assert float(qf @ qf) == pytest.approx(1.0, abs=1e-15)


def _filter_run(kernels: bool, scenario: str) -> tuple[np.ndarray, np.ndarray, Any]:
    """A filter over one of three streams, with the kernels or with the NumPy twins: a car with
    a magnetometer (rejections by the hundred), a start under acceleration (re-seeded) and a
    chip at rest whose still windows teach the bias (the corrections that also take them)."""
    rng = np.random.default_rng(8)
    if scenario == "car":
        s = sc.car(seed=1, mag=True, seconds=30.0)
        gyro, accel, mag, dt = s.gyro, s.accel, s.mag, s.dt
        f = ekf.OrientationFilter(ekf.NoiseModel(s.gyro_density, s.accel_density, mag=s.mag_sigma))
    else:
        n = 12000
        gyro = np.radians([0.2, -0.1, 0.3]) + rng.normal(0.0, 0.003, (n, 3))
        accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.13, (n, 3))
        if scenario == "reseed":
            accel[:1500, 0] += 5.0
        gyro, accel, mag, dt = gyro, accel, None, 0.001
        f = ekf.OrientationFilter(ekf.NoiseModel(1e-4, 0.004), recovery_s=5.0)
    saved = (ekf._kernels, kalman._kernels)
    if not kernels:
        ekf._kernels = kalman._kernels = None
    try:
        qs, cs = [], []
        for i in range(0, len(gyro), 25):
            if scenario == "still" and i % 1000 == 0 and i:  # a still window's mean, each second
                f.zero_rate(gyro[i - 1000 : i].mean(axis=0), np.full(3, 1e-8))
            m = None if mag is None else mag[i : i + 25]
            q, c = f.step(gyro[i : i + 25], accel[i : i + 25], dt, m)
            qs.append(q)
            cs.append(c)
    finally:
        ekf._kernels, kalman._kernels = saved
    return np.vstack(qs), np.vstack(cs), f


@pytest.mark.parametrize("scenario", ["car", "reseed", "still"])
def test_the_filter_runs_alike_on_its_kernels_and_on_numpy(scenario: str) -> None:
    """The whole filter (the chunk's kernel, the correction's in one call, the still windows'
    and the magnetometer's updates through the smaller kernels) against its NumPy twins: the
    same decisions (every count alike), the same orientations and covariances to rounding."""
    _kernel("imud._kernels")
    qf, cf, ff = _filter_run(True, scenario)
    qs, cs, fs = _filter_run(False, scenario)
    assert ff.counters == fs.counters
    if scenario == "reseed":
        assert ff.counters.recoveries >= 1
    if scenario == "still":
        assert ff.counters.zero_rate_updates >= 10
    if scenario == "car":
        assert ff.counters.accel_rejected > 50 and ff.counters.mag_updates > 100
    ok = np.isfinite(qs[:, 0])
    assert (np.isfinite(qf[:, 0]) == ok).all() and ok.sum() > len(qs) // 2
    np.testing.assert_allclose(qf[ok], qs[ok], rtol=0, atol=1e-9)
    np.testing.assert_allclose(cf[ok], cs[ok], rtol=1e-7, atol=1e-18)
    for name in ("linear_var", "_g0", "_white_var", "_g_var", "_rejected_s", "_drifted_s"):
        assert getattr(ff, name) == pytest.approx(getattr(fs, name), rel=1e-7, abs=1e-15)


def test_orient_kernels_name_a_wrong_size() -> None:
    """A covariance of the wrong size, or an innovation and noise that do not match, is a
    ValueError naming the kernel, not a crash."""
    k = _kernel("imud._kernels")
    with pytest.raises(ValueError, match="orient_propagate"):
        k.orient_propagate(np.eye(7), np.zeros(16), 1.0, 1.0, np.zeros(8), 0.1, 0.0, np.zeros(2))
    with pytest.raises(ValueError, match="orient_update"):
        k.orient_update(np.eye(8), np.zeros((4, 8)), (0.0,) * 4, (1.0,) * 4, 1.0, 0, 1.0,
                        np.ones(4), False, np.zeros(3), np.zeros(2))  # fmt: skip
    with pytest.raises(ValueError, match="one length"):
        k.orient_update(np.eye(8), np.zeros((2, 8)), (0.0, 0.0), (1.0,), 1.0, 0, 1.0,
                        np.ones(4), False, np.zeros(3), np.zeros(2))  # fmt: skip


# --- the gyro-bias tracker's windows -------------------------------------------------------------


@FUZZ
@given(
    st.integers(0, 2**32 - 1),
    st.sampled_from([8, 31, 32, 100, 1000]),
    st.booleans(),
    st.booleans(),
)
def test_track_windows_match_numpy(seed: int, m: int, with_accel: bool, holes: bool) -> None:
    """A stream cut into random batches, its windows' statistics from the kernel's running sums
    and from NumPy on the samples: the same windows, flagged alike, equal to rounding (a still
    accelerometer's variance too, sitting at 9.8 m/s^2 where its noise is 1e-4 of that)."""
    _kernel("imud._kernels")
    rng = np.random.default_rng(seed)
    n = int(rng.integers(m, 4 * m + 50))
    gyro = rng.normal(0.01, 1e-3, size=(n, 3)) * rng.choice([1.0, 100.0])
    accel = rng.normal(0.0, 1e-3, size=(n, 3)) + np.array([0.1, -0.2, 9.81])
    if holes:
        gyro[rng.random(n) < 2.0 / n] = np.nan
        accel[rng.random(n) < 2.0 / n, 1] = np.nan
    cuts = np.sort(
        rng.choice(np.arange(1, n), size=min(n - 1, int(rng.integers(0, 40))), replace=False)
    )
    fast, slow = (
        track.GyroBiasTracker(GyroBiasTracking()),
        track.GyroBiasTracker(GyroBiasTracking()),
    )
    rows_fast: list[list[float]] = []
    rows_slow: list[list[float]] = []
    for g, a in zip(np.split(gyro, cuts), np.split(accel, cuts), strict=True):
        a_in = a if with_accel else None
        rows_fast += fast._windows(g, a_in, m)
        rows_slow += slow._windows_numpy(g, a_in, m)
    assert len(rows_fast) == len(rows_slow) == n // m
    for rf, rs in zip(rows_fast, rows_slow, strict=True):
        assert rf[:2] == rs[:2]
        if rs[0]:
            np.testing.assert_allclose(rf, rs, rtol=1e-9, atol=0)


def _mpu_run() -> list[bytes]:
    device = {"chip": "mpu6050", "odr_hz": 1000, "dlpf_hz": 188, "orientation": {"enabled": True}}
    sim = {"seed": 9, "motion": {"kind": "tumble", "rate_dps": [10.0, 20.0, 60.0]}}
    rig = make_rig(device, sim)
    rig.run(6.0, jitter_ns=200_000, seed=5)
    return rig.out


def test_a_simulated_mpu6050_orients_the_same_both_ways(monkeypatch: pytest.MonkeyPatch) -> None:
    """The daemon's orientation stage with the kernels, then with their NumPy twins, over 6 s of a
    turning chip (the filter starts, corrects and learns its bias in that time): the same
    published orientations, to float32's rounding."""
    _kernel("imud._kernels")
    fast = [wire.decode(b) for b in _mpu_run()]
    monkeypatch.setattr(ekf, "_kernels", None)
    monkeypatch.setattr(kalman, "_kernels", None)
    slow = [wire.decode(b) for b in _mpu_run()]
    assert len(fast) == len(slow) > 100
    for a, b in zip(fast, slow, strict=True):
        assert a.t_ns.tolist() == b.t_ns.tolist()
        qa, qb = a.channels[Channel.ORIENTATION], b.channels[Channel.ORIENTATION]
        np.testing.assert_allclose(qa, qb, rtol=0, atol=2e-6, equal_nan=True)
    assert np.isfinite(fast[-1].channels[Channel.ORIENTATION]).all()  # it did start


# --- a whole chip both ways ----------------------------------------------------------------------

FAULTS = {"garble_rate": 2e-3, "stall_rate": 2e-3, "stall_ms": 20.0}


def _icm_run(hires: bool) -> list[bytes]:
    device = {
        "chip": "icm42688p",
        "bus": {"kind": "sim", "transport": "spi"},
        "odr_hz": 8000,
        "hires": hires,
    }
    sim = {"seed": 5, "clock_error": 0.004, "faults": FAULTS,
           "motion": {"kind": "tumble", "rate_dps": [10.0, 20.0, 100.0]}}  # fmt: skip
    rig = make_rig(device, sim)
    rig.run(3.0, jitter_ns=400_000, seed=3)
    return rig.out


def _bmi_run() -> list[bytes]:
    device = {
        "chip": "bmi088",
        "bus": {"kind": "sim", "transport": "spi", "cs": 0},
        "gyro_bus": {"kind": "sim", "transport": "spi", "cs": 1},
        "odr_hz": 2000,
        "accel_odr_hz": 1600,
        "gyro_filter_hz": 532,
    }
    sim = {"seed": 7, "clock_error": 0.003, "faults": FAULTS,
           "motion": {"kind": "tumble", "rate_dps": [10.0, 20.0, 100.0]}}  # fmt: skip
    rig = make_rig(device, sim)
    rig.run(4.0, jitter_ns=400_000, seed=4)
    return rig.out


def test_a_simulated_bmi088_publishes_the_same_bytes_both_ways(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Both dies' FIFOs, their clocks and the align stage with every kernel, then with the NumPy
    twins: the same published batches, byte for byte."""
    _kernel("imud._kernels")
    fast = _bmi_run()
    monkeypatch.setattr(bmi, "_fifo", None)
    monkeypatch.setattr(align, "_kernels", None)
    monkeypatch.setattr(timestamps, "_kernels", None)
    monkeypatch.setattr(pipeline, "_kernels", None)
    monkeypatch.setattr(wire, "_pack", None)
    slow = _bmi_run()
    assert len(fast) > 100
    assert fast == slow


@pytest.mark.parametrize("hires", [False, True])
def test_a_simulated_icm_publishes_the_same_bytes_both_ways(
    hires: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The driver, the clock and the pipeline with every kernel, then with the NumPy twins: the
    same published batches, byte for byte, through FIFO overflows and garbled bursts."""
    _kernel("imud._kernels")
    fast = _icm_run(hires)
    monkeypatch.setattr(icm, "_fifo", None)
    monkeypatch.setattr(timestamps, "_kernels", None)
    monkeypatch.setattr(pipeline, "_kernels", None)
    monkeypatch.setattr(wire, "_pack", None)
    slow = _icm_run(hires)
    assert len(fast) > 100
    assert fast == slow
