"""imud's batch MCAP writer against the format: the `mcap` library's reader (CRCs validated)
gets back every message as written, and the CRCs, chunk and message indexes are checked here
byte by byte from the specification (https://mcap.dev/spec), not through imud's code."""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import zstandard
from mcap.reader import make_reader

from imud.recording.mcapwrite import McapWriter

MAGIC = b"\x89MCAP0\r\n"


def _write(path: Path, chunk_bytes: int) -> list[tuple[int, int, int, bytes]]:
    """A file of two fixed-size channels written in batches and one variable-size channel
    written a message at a time, interleaved, with flushes between; returns what went in as
    (channel, sequence, log time, data)."""
    rng = np.random.default_rng(7)
    sent: list[tuple[int, int, int, bytes]] = []
    with open(path, "wb") as f:
        w = McapWriter(f, profile="ros2", library="test", chunk_bytes=chunk_bytes)
        w.metadata("imud", {"devices": "a,b"})
        w.attachment(5, 6, "imud.toml", "application/toml", b"[zenoh]\n")
        s1 = w.schema("sensor_msgs/msg/Imu", "ros2msg", b"float64 x\n")
        s2 = w.schema("imud_msgs/msg/Batch", "ros2msg", b"uint8[] data\n")
        a = w.channel("/a/imu", "cdr", s1, {"offered_qos_profiles": ""})
        b = w.channel("/b/imu", "cdr", s1, {})
        c = w.channel("/a/batch", "cdr", s2, {})
        seq = {a: 1, b: 1, c: 1}
        t = 1_700_000_000_000_000_000
        for step in range(40):
            for ch, size in ((a, 48), (b, 340)):
                n = int(rng.integers(0, 30))
                stamps = t + np.sort(rng.integers(0, 200_000_000, n)).astype(np.int64)
                data = rng.bytes(n * size)
                w.messages(ch, stamps, seq[ch], data, size)
                for i in range(n):
                    sent.append((ch, seq[ch] + i, int(stamps[i]), data[i * size : (i + 1) * size]))
                seq[ch] += n
            one = rng.bytes(int(rng.integers(1, 900)))
            w.message(c, t + 199_000_000, seq[c], one)
            sent.append((c, seq[c], t + 199_000_000, one))
            seq[c] += 1
            if step % 7 == 3:
                w.flush()
            t += 200_000_000
        w.finish()
    return sent


@pytest.mark.parametrize("chunk_bytes", [1 << 30, 20_000, 1])
def test_every_message_reads_back_with_crcs_validated(tmp_path: Path, chunk_bytes: int) -> None:
    path = tmp_path / "w.mcap"
    sent = _write(path, chunk_bytes)
    with open(path, "rb") as f:
        r = make_reader(f, validate_crcs=True)
        got = [(m.channel_id, m.sequence, m.log_time, m.data) for _, _, m in r.iter_messages()]
        s = r.get_summary()
        assert s is not None
        assert [a.name for a in r.iter_attachments()] == ["imud.toml"]
        assert [(m.name, m.metadata) for m in r.iter_metadata()] == [("imud", {"devices": "a,b"})]
    # in log-time order, as an indexed reader gives them
    assert sorted(got, key=lambda x: x[2]) == got
    assert sorted(got) == sorted(sent)
    st = s.statistics
    assert st is not None
    assert st.message_count == len(sent)
    assert st.message_start_time == min(x[2] for x in sent)
    assert st.message_end_time == max(x[2] for x in sent)
    for ch in (1, 2, 3):
        assert st.channel_message_counts[ch] == sum(1 for x in sent if x[0] == ch)
    assert st.chunk_count == len(s.chunk_indexes) >= 6  # a chunk at least every flush
    assert {c.topic for c in s.channels.values()} == {"/a/imu", "/b/imu", "/a/batch"}


def _records(buf: bytes, at: int, end: int) -> list[tuple[int, int, bytes]]:
    """(offset, opcode, body) of each record in buf[at:end] (spec: opcode u8, length u64)."""
    out = []
    while at < end:
        op, n = struct.unpack_from("<BQ", buf, at)
        out.append((at, op, buf[at + 9 : at + 9 + n]))
        at += 9 + n
    return out


def test_crcs_and_indexes_are_the_specifications(tmp_path: Path) -> None:
    path = tmp_path / "w.mcap"
    sent = _write(path, 30_000)
    buf = path.read_bytes()
    assert buf[:8] == MAGIC and buf[-8:] == MAGIC
    footer_at = len(buf) - 8 - (9 + 20)
    op, n, summary_start, offsets_start, summary_crc = struct.unpack_from("<BQQQI", buf, footer_at)
    assert (op, n) == (0x02, 20)
    # the summary's CRC covers it and the footer up to the CRC field
    assert zlib.crc32(buf[summary_start : footer_at + 9 + 16]) == summary_crc
    # the data end record just before the summary: the CRC of everything before it
    data_end_at = summary_start - 13
    op, n, data_crc = struct.unpack_from("<BQI", buf, data_end_at)
    assert (op, n) == (0x0F, 4)
    assert zlib.crc32(buf[:data_end_at]) == data_crc
    # every chunk index points at a chunk whose messages its message indexes locate
    summary = _records(buf, summary_start, offsets_start)
    chunk_indexes = [body for _, op, body in summary if op == 0x08]
    assert chunk_indexes
    located = []
    for body in chunk_indexes:
        start, end, chunk_at, chunk_len, map_len = struct.unpack_from("<QQQQI", body)
        index_at = dict(struct.unpack_from("<HQ", body, 36 + 10 * i) for i in range(map_len // 10))
        [(_, op, chunk)] = _records(buf, chunk_at, chunk_at + chunk_len)
        assert op == 0x06
        c_start, c_end, usize, ucrc, clen = struct.unpack_from("<QQQII", chunk)
        assert (c_start, c_end) == (start, end)
        assert chunk[32 : 32 + clen] == b"zstd"
        (dlen,) = struct.unpack_from("<Q", chunk, 32 + clen)
        data = zstandard.ZstdDecompressor().decompress(
            chunk[40 + clen : 40 + clen + dlen], max_output_size=usize
        )
        assert len(data) == usize and zlib.crc32(data) == ucrc
        for ch, mi_at in index_at.items():
            [(_, op, mi)] = _records(
                buf, mi_at, mi_at + 9 + struct.unpack_from("<Q", buf, mi_at + 1)[0]
            )
            assert op == 0x07
            mch, k = struct.unpack_from("<HI", mi)
            assert mch == ch
            pairs = np.frombuffer(mi, "<u8", k // 8, 6).reshape(-1, 2)
            for log_time, off in pairs.tolist():
                op, n, cid, seq, log, pub = struct.unpack_from("<BQHIQQ", data, off)
                assert (op, cid, log, pub) == (0x05, ch, log_time, log_time)
                assert start <= log <= end
                located.append((cid, seq, log, data[off + 31 : off + 9 + n]))
    assert sorted(located) == sorted(sent)


def test_a_file_without_messages_is_whole(tmp_path: Path) -> None:
    buf = io.BytesIO()
    w = McapWriter(buf, profile="ros2", library="test")
    w.channel("/x", "cdr", w.schema("s", "ros2msg", b""), {})
    w.finish()
    r = make_reader(io.BytesIO(buf.getvalue()), validate_crcs=True)
    assert list(r.iter_messages()) == []
    s = r.get_summary()
    assert s is not None and s.statistics is not None and s.statistics.message_count == 0


def test_a_batch_whose_bytes_are_not_its_messages_is_refused() -> None:
    w = McapWriter(io.BytesIO(), profile="ros2", library="test")
    with pytest.raises(ValueError, match="not 3 messages of 10"):
        w.messages(1, np.arange(3, dtype=np.int64), 1, b"\0" * 29, 10)
