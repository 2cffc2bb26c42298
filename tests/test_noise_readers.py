"""The fast readers of `imud noise` give what the whole-file readers give: a CSV read a block at a
time (pyarrow, or NumPy without it) against read_csv, an MCAP file's chunks scanned against the
recording reader's batches one at a time; and what they do not take as it is (a bad value, a
comment among the rows, a damaged chunk) ends in the whole-file reader's answer or refusal."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

import imud.cli.noise as cli_noise
from imud.calib.csvio import CsvWriter
from imud.channels import Channel
from imud.recording.mcapfile import McapOut
from imud.recording.recorder import native_topic
from imud.recording.schemas import BATCH, batch_cdr
from imud.wire import encode

RATE = 500.0


def _samples(n: int, seed: int = 3) -> tuple[Any, Any, Any, Any]:
    rng = np.random.default_rng(seed)
    t = 10**18 + np.arange(n, dtype=np.int64) * 2_000_000
    gyro = rng.normal(0.0, 0.003, (n, 3)) + np.array([0.01, 0.0, -0.02])
    accel = rng.normal(0.0, 0.03, (n, 3)) + np.array([0.1, -0.2, 9.81])
    temp = np.linspace(20.0, 30.0, n)
    return t, accel, gyro, temp


def _csv(path: Path, n: int = 40_000) -> Path:
    t, accel, gyro, temp = _samples(n)
    keep = np.ones(n, dtype=bool)
    keep[15_000:15_030] = False  # a stamp gap: two stretches
    with CsvWriter(path, has_temp=True, comments={"device": "imu3", "chip": "mpu6050"}) as w:
        w.write(t[keep], accel[keep], gyro[keep], temp[keep])
    return path


def _run(monkeypatch: pytest.MonkeyPatch, path: Path, stream: bool, **env: str) -> Any:
    monkeypatch.setattr(cli_noise, "STREAM_BYTES", 0 if stream else 1 << 40)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    r = CliRunner().invoke(cli_noise.noise, [str(path), "--json"], catch_exceptions=False)
    for k in env:
        monkeypatch.delenv(k)
    return r


def _same(a: dict[str, Any], b: dict[str, Any]) -> None:
    assert a["samples"] == b["samples"] and a["stretches"] == b["stretches"]
    assert a["rate_hz"] == pytest.approx(b["rate_hz"], rel=1e-12)
    assert a["tau_s"] == pytest.approx(b["tau_s"], rel=1e-12)
    for k in ("gyro_adev_rad_s", "accel_adev_m_s2"):
        np.testing.assert_allclose(a[k], b[k], rtol=1e-9)


@pytest.mark.parametrize("parser", ["numpy", pytest.param("pyarrow", marks=pytest.mark.extra)])
def test_a_csv_read_a_block_at_a_time_equals_the_whole_read(
    parser: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    if parser == "pyarrow":
        pytest.importorskip("pyarrow")
    path = _csv(tmp_path / "still.csv")
    whole = _run(monkeypatch, path, stream=False)
    streamed = _run(monkeypatch, path, stream=True, IMUD_NOISE_CSV=parser)
    assert whole.exit_code == 0 and streamed.exit_code == 0, whole.output + streamed.output
    a, b = json.loads(streamed.output), json.loads(whole.output)
    assert a["reader"]["parser"].startswith(parser) and b["reader"]["parser"].startswith("read_csv")
    assert a["stretches"] == 2 and a["samples"] == 40_000 - 30
    assert a["device"] == "imu3" and a["chip"] == "mpu6050"
    _same(a, b)


@pytest.mark.parametrize("parser", ["numpy", pytest.param("pyarrow", marks=pytest.mark.extra)])
@pytest.mark.parametrize(
    ("bad", "says"),
    [
        ("abc", "'abc' is not a number"),
        ("nan", "nan is not a finite number"),
        ("", "empty value"),
    ],
)
def test_a_bad_value_deep_in_a_streamed_csv_is_named_by_its_line(
    parser: str, bad: str, says: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    if parser == "pyarrow":
        pytest.importorskip("pyarrow")
    path = _csv(tmp_path / "bad.csv")
    lines = path.read_text().splitlines(keepends=True)
    k = 30_001  # a line far past the first block's rows
    fields = lines[k - 1].split(",")
    fields[2] = bad
    lines[k - 1] = ",".join(fields)
    path.write_text("".join(lines))
    r = _run(monkeypatch, path, stream=True, IMUD_NOISE_CSV=parser)
    assert r.exit_code == 2, r.output
    assert f"bad.csv:{k}: column ay" in r.output and says in r.output, r.output


def test_a_comment_among_the_rows_is_read_by_read_csv(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The documented format allows comments anywhere: the block reader hands over, and the
    answer is the whole read's."""
    path = _csv(tmp_path / "c.csv")
    lines = path.read_text().splitlines(keepends=True)
    lines.insert(25_000, "# the chamber door was opened here\n")
    path.write_text("".join(lines))
    whole = json.loads(_run(monkeypatch, path, stream=False).output)
    r = _run(monkeypatch, path, stream=True, IMUD_NOISE_CSV="numpy")
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert out["reader"]["parser"].startswith("read_csv")
    _same(out, whole)


def test_wrong_units_in_a_streamed_csv_are_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    t, accel, gyro, _ = _samples(20_000)
    path = tmp_path / "g.csv"
    with CsvWriter(path) as w:
        w.write(t, accel / 9.80665, gyro)  # in g, not m/s^2
    r = _run(monkeypatch, path, stream=True, IMUD_NOISE_CSV="numpy")
    assert r.exit_code == 2 and "looks like g" in r.output, r.output


def _mcap(path: Path, damaged: bool = False) -> tuple[int, int]:
    """Two devices' batches interleaved, a chunk a second: imu0 loses 7 samples once (a seq
    gap with lost_before) and marks one sample invalid (NaN), so three stretches."""
    t, accel, gyro, temp = _samples(30_000)
    accel[9_001] = np.nan
    now = [0.0]
    out = McapOut(path, metadata={"imud.devices": {
        "imu0": json.dumps({"name": "imu0", "chip": "mpu6050", "odr_hz": RATE}),
        "imu1": json.dumps({"name": "imu1", "chip": "mpu6050", "odr_hz": RATE}),
    }}, clock=lambda: now[0])  # fmt: skip
    seq = 0
    kept = 0
    for i in range(0, 30_000, 25):
        s = slice(i, i + 25)
        lost = 7 if i == 20_000 else 0
        seq += lost
        chans = {Channel.ACCEL: accel[s], Channel.GYRO: gyro[s], Channel.TEMPERATURE: temp[s]}
        late = 7 * 2_000_000 if i >= 20_000 else 0  # the lost samples' time
        wire = encode("imu0", seq, t[s] + late, chans, lost_before=lost)
        seq += 25
        kept += 25
        log = int(t[s][-1])
        now[0] = (log - 10**18) / 1e9
        out.add(native_topic("imud", "imu0"), BATCH, log, batch_cdr(wire))
        other = encode("imu1", i, t[s], {Channel.ACCEL: accel[s] * 0, Channel.GYRO: gyro[s]})
        out.add(native_topic("imud", "imu1"), BATCH, log, batch_cdr(other))
    out.close()
    if damaged:  # the middle chunk's zstd frame header overwritten
        raw = bytearray(path.read_bytes())
        magic = b"\x28\xb5\x2f\xfd"
        at = raw.find(magic, len(raw) // 2)
        assert at > 0
        raw[at : at + 4] = b"\0\0\0\0"
        path.write_bytes(bytes(raw))
    return kept, 3


def _noise(monkeypatch: pytest.MonkeyPatch, path: Path, library: bool) -> Any:
    if library:
        monkeypatch.setenv("IMUD_NOISE_MCAP", "library")
    r = CliRunner().invoke(cli_noise.noise, [str(path), "--device", "imu0", "--json"])
    monkeypatch.delenv("IMUD_NOISE_MCAP", raising=False)
    return r


def test_an_mcap_scanned_by_chunks_equals_the_batches_one_by_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "r.mcap"
    kept, stretches = _mcap(path)
    scanned, library = _noise(monkeypatch, path, False), _noise(monkeypatch, path, True)
    assert scanned.exit_code == 0 and library.exit_code == 0, scanned.output + library.output
    a, b = json.loads(scanned.output), json.loads(library.output)
    assert a["reader"]["parser"].startswith("MCAP chunk scan")
    assert b["reader"]["parser"].startswith("the mcap library")
    assert a["samples"] == kept - 1 and a["stretches"] == stretches
    assert a["rate_hz"] == pytest.approx(RATE, rel=1e-9)
    _same(a, b)


def test_a_damaged_chunk_is_said_by_the_recording_reader(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "d.mcap"
    _mcap(path, damaged=True)
    r = _noise(monkeypatch, path, False)
    assert r.exit_code == 2, r.output
    assert "d.mcap" in r.output and "damaged" in r.output, r.output
