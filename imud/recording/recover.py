"""`imud record --recover BROKEN.mcap`: every complete message of an MCAP file whose writer died
(SIGKILL, a power cut, a full disk), into a new, indexed file.

A killed writer leaves no summary and no footer, so indexed readers (Foxglove, rosbags, the
`mcap` library's seeking reader) refuse the file, and its last chunk may be cut short. The
records are read in order with a stream reader until the first one that is not whole; the
schemas, channels, messages, attachments and metadata read so far are written again, chunked
and indexed, in the order they came. Nothing of the broken file is changed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.records import (
    Attachment,
    Channel,
    DataEnd,
    Footer,
    Header,
    Message,
    Metadata,
    Schema,
)
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from imud.recording.mcapfile import LIBRARY


class RecoverError(ValueError):
    """A file that holds no MCAP to recover (not MCAP at all, or empty): names the file."""


@dataclass
class Recovered:
    path: Path
    messages: int = 0
    attachments: int = 0
    complete: bool = False  # the input had its footer: nothing needed recovering
    stopped_at: str = ""  # why the read ended before a footer
    per_topic: dict[str, int] = field(default_factory=dict)


def has_footer(path: Path) -> bool:
    """Whether an MCAP file ends in its footer and closing magic (written to the end)."""
    try:
        with open(path, "rb") as f:
            f.seek(0, 2)
            if f.tell() < 8 + 8:
                return False
            f.seek(-8, 2)
            return f.read(8) == b"\x89MCAP0\r\n"
    except OSError:
        return False


def recover(src: Path, dst: Path) -> Recovered:
    """Write every complete record of `src` into `dst` (which must not exist). Raises
    RecoverError for a file that is not MCAP."""
    out = Recovered(dst)
    with open(src, "rb") as f:
        head = f.read(8)
        if head != b"\x89MCAP0\r\n":
            what = "empty" if not head else f"starts with {head[:8]!r}"
            raise RecoverError(f"{src} is not an MCAP file ({what}): nothing to recover")
        f.seek(0)
        records: list[Any] = []
        try:
            for r in StreamReader(f, record_size_limit=1 << 31).records:
                if isinstance(r, DataEnd | Footer):  # the summary after it repeats the data's
                    out.complete = True
                    break
                records.append(r)
        except Exception as e:
            # own errors, struct's, zstd's
            out.stopped_at = f"{type(e).__name__}: {e}"
    profile, library = "ros2", LIBRARY
    for r in records:
        if isinstance(r, Header):
            profile, library = r.profile, f"{r.library} (recovered by {LIBRARY})"
    with open(dst, "xb") as g:
        w = Writer(g, compression=CompressionType.ZSTD)
        w.start(profile=profile, library=library)
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        topics: dict[int, str] = {}
        for r in records:
            if isinstance(r, Schema) and r.id not in schema_ids:
                schema_ids[r.id] = w.register_schema(r.name, r.encoding, r.data)
            elif isinstance(r, Channel) and r.id not in channel_ids:
                if r.schema_id and r.schema_id not in schema_ids:
                    continue  # its schema was in the lost part
                channel_ids[r.id] = w.register_channel(
                    r.topic, r.message_encoding, schema_ids.get(r.schema_id, 0), r.metadata
                )
                topics[r.id] = r.topic
            elif isinstance(r, Message) and r.channel_id in channel_ids:
                w.add_message(
                    channel_ids[r.channel_id], r.log_time, r.data, r.publish_time, r.sequence
                )
                out.messages += 1
                topic = topics[r.channel_id]
                out.per_topic[topic] = out.per_topic.get(topic, 0) + 1
            elif isinstance(r, Attachment):
                w.add_attachment(r.create_time, r.log_time, r.name, r.media_type, r.data)
                out.attachments += 1
            elif isinstance(r, Metadata):
                w.add_metadata(r.name, r.metadata)
        w.finish()  # type: ignore[no-untyped-call]
    return out
