"""`imud noise` on any CSV the documented format allows, and some it does not: any length (0, 1,
2, ... rows), stamp gaps, NaN or empty fields. Always an answer (exit 0) or a clear message
(exit 2, naming the file), never a traceback."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from imud.cli.noise import noise

HEADER = "timestamp_ns,ax,ay,az,gx,gy,gz\n"


@st.composite
def recordings(draw: st.DrawFn) -> str:
    n = draw(st.integers(0, 60))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    steps = np.full(n, 10_000_000, dtype=np.int64)
    for i in draw(st.lists(st.integers(0, max(n - 1, 0)), max_size=4)):
        if n:
            steps[i] *= draw(st.integers(2, 50))  # a stamp gap
    t = 10**18 + np.cumsum(steps)
    rows = []
    bad = set(draw(st.lists(st.integers(0, max(n - 1, 0)), max_size=5))) if n else set()
    for i in range(n):
        v = [f"{x:.6g}" for x in rng.normal(0.0, 0.01, 6) + np.array([0, 0, 9.81, 0, 0, 0])]
        if i in bad:
            v[draw(st.integers(0, 5))] = draw(st.sampled_from(["nan", "", "NaN", "inf"]))
        rows.append(f"{t[i]}," + ",".join(v))
    return HEADER + "".join(r + "\n" for r in rows)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(text=recordings())
def test_any_csv_gives_an_answer_or_a_message(tmp_path: Path, text: str) -> None:
    path = tmp_path / "r.csv"
    path.write_text(text)
    r = CliRunner().invoke(noise, [str(path), "--json"])
    assert r.exit_code in (0, 2), (r.exit_code, r.output, r.exception)
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    assert "Traceback" not in r.output
    if r.exit_code == 2:
        assert str(path) in r.output or "r.csv" in r.output, r.output


def test_short_clean_recordings_answer_or_say_why(tmp_path: Path) -> None:
    """3 .. 12 clean rows: the fit has one or two taus; it answers (N from them)."""
    rng = np.random.default_rng(0)
    for n in range(3, 13):
        path = tmp_path / f"s{n}.csv"
        rows = [f"{10**18 + i * 10**7}," + ",".join(f"{x:.6g}" for x in rng.normal(0.0, 0.01, 6)
                + np.array([0, 0, 9.81, 0, 0, 0])) for i in range(n)]  # fmt: skip
        path.write_text(HEADER + "\n".join(rows) + "\n")
        r = CliRunner().invoke(noise, [str(path), "--json"])
        assert r.exit_code in (0, 2), (n, r.output)
        assert r.exception is None or isinstance(r.exception, SystemExit), (n, r.exception)


@pytest.mark.parametrize("parser", ["numpy", pytest.param("pyarrow", marks=pytest.mark.extra)])
def test_any_csv_read_a_block_at_a_time_gives_an_answer_or_a_message(
    parser: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The same files through the block reader (every file counts as big): what it does not
    take goes to read_csv, so the outcome is the whole read's, never a traceback."""
    if parser == "pyarrow":
        pytest.importorskip("pyarrow")
    import imud.cli.noise as cli_noise

    monkeypatch.setenv("IMUD_NOISE_CSV", parser)

    @settings(max_examples=40, deadline=None)
    @given(text=recordings())
    def check(text: str) -> None:
        path = tmp_path / "r.csv"
        path.write_text(text)
        outcome = []
        for stream_bytes in (1 << 40, 0):
            monkeypatch.setattr(cli_noise, "STREAM_BYTES", stream_bytes)
            r = CliRunner().invoke(noise, [str(path), "--json"])
            assert r.exit_code in (0, 2), (r.exit_code, r.output, r.exception)
            assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
            outcome.append(r.exit_code)
            if r.exit_code == 0:
                out = json.loads(r.output)
                outcome.append((out["samples"], out["stretches"], len(out["tau_s"])))
        assert outcome[: len(outcome) // 2] == outcome[len(outcome) // 2 :], outcome

    check()


def _recording(path: Path) -> bytes:
    from imud.channels import Channel
    from imud.recording.mcapfile import McapOut
    from imud.recording.recorder import native_topic
    from imud.recording.schemas import BATCH, batch_cdr
    from imud.wire import encode

    if not path.exists():
        rng = np.random.default_rng(5)
        now = [0.0]
        meta = {"imud.devices": {"d0": json.dumps({"name": "d0", "odr_hz": 100.0})}}
        with McapOut(path, metadata=meta, clock=lambda: now[0]) as out:
            for k in range(120):
                t = 10**18 + (k * 10 + np.arange(10)) * 10_000_000
                now[0] = k / 10
                chans = {Channel.ACCEL: rng.normal(0, 0.01, (10, 3)) + np.array([0, 0, 9.8]),
                         Channel.GYRO: rng.normal(0, 0.01, (10, 3))}  # fmt: skip
                wire = encode("d0", k * 10, t, chans)
                out.add(native_topic("imud", "d0"), BATCH, int(t[-1]), batch_cdr(wire))
    return path.read_bytes()


def test_a_damaged_mcap_gives_an_answer_or_a_message(tmp_path: Path) -> None:
    """Bytes changed anywhere in a recording: the chunk scan reads it, hands it to the
    recording reader, or says what is wrong; never a traceback."""
    good = _recording(tmp_path / "good.mcap")

    @settings(max_examples=60, deadline=None)
    @given(st.data())
    def check(data: st.DataObject) -> None:
        raw = bytearray(good)
        for _ in range(data.draw(st.integers(1, 4))):
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
        path = tmp_path / "bad.mcap"
        path.write_bytes(bytes(raw))
        r = CliRunner().invoke(noise, [str(path), "--json"])
        assert r.exit_code in (0, 2), (r.exit_code, r.output, r.exception)
        assert r.exception is None or isinstance(r.exception, SystemExit), r.exception

    check()
