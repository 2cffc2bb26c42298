"""Reading what `imud record` wrote: the devices a file holds, how the daemon described them, and
their native batches in time order, for replay, export and the offline commands.

A file without its summary (a recorder that died) is read as a stream, with a warning that
names `imud record --recover`; a file that is not MCAP, is empty, or holds no imud batches is an
`McapInputError` naming the file and what it holds instead.
"""

from __future__ import annotations

import glob
import itertools
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.reader import NonSeekingReader, make_reader

from imud.recording.recover import has_footer
from imud.recording.schemas import BATCH, batch_wire

MAGIC = b"\x89MCAP0\r\n"
OVERLAP_NS = 250_000_000  # how far split parts' log times may overlap (open_recordings)


class McapInputError(ValueError):
    """A file imud cannot read as a recording: the message names it and says why."""


def is_mcap(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(8) == MAGIC
    except OSError:
        return False


@dataclass
class Recording:
    """What a file holds: per device its native topic and the daemon's description of it."""

    path: Path
    indexed: bool  # has its summary: seekable, counted
    devices: dict[str, str] = field(default_factory=dict)  # name -> native topic
    raw: dict[str, str] = field(default_factory=dict)  # name -> its uncorrected stream's topic
    info: dict[str, dict[str, Any]] = field(default_factory=dict)  # name -> status JSON
    attachments: dict[str, bytes] = field(default_factory=dict)
    warning: str | None = None
    parts: list[tuple[Path, bool]] = field(default_factory=list)  # a split recording's files,
    # in order, each with whether it is indexed (empty: `path` alone)

    def daemon_config(self) -> tuple[dict[str, Any], dict[str, str]] | None:
        """The daemon's config file, as recorded (a table), and each device's calibration
        file's text; None when the recording kept no config."""
        import tomllib

        configs = [n for n in self.attachments if ": " not in n and n.endswith(".toml")]
        if not configs:
            return None
        try:
            raw = tomllib.loads(self.attachments[configs[0]].decode("utf-8", "replace"))
        except tomllib.TOMLDecodeError:
            return None
        cal = {
            n.split(": ", 1)[0]: data.decode("utf-8", "replace")
            for n, data in self.attachments.items()
            if ": " in n
        }
        return raw, cal

    def batches(
        self, devices: list[str] | None = None, raw: bool = False
    ) -> Iterator[tuple[str, int, bytes]]:
        """(device, log time ns, wire bytes) of the named devices (all by default), in log
        time order (a stream's own order for a file without its summary); `raw`: their
        uncorrected streams (recorded with --raw)."""
        which = self.raw if raw else self.devices
        topics = {which[d]: (d, raw) for d in (devices or list(self.devices)) if d in which}
        for device, _, log_ns, wire in self._read(topics):
            yield device, log_ns, wire

    def streams(self, devices: list[str] | None = None) -> Iterator[tuple[str, bool, int, bytes]]:
        """(device, raw, log time ns, wire bytes): the named devices' native batches and their
        uncorrected streams (where recorded) together, in log time order."""
        names = devices or list(self.devices)
        topics = {self.devices[d]: (d, False) for d in names if d in self.devices}
        topics.update({self.raw[d]: (d, True) for d in names if d in self.raw})
        yield from self._read(topics)

    def _read(self, topics: dict[str, tuple[str, bool]]) -> Iterator[tuple[str, bool, int, bytes]]:
        """The messages of `topics` file by file (a split recording's parts in order)."""
        for path, indexed in self.parts or [(self.path, self.indexed)]:
            with open(path, "rb") as f:
                if indexed:
                    it = make_reader(f).iter_messages(topics=list(topics), log_time_order=True)
                else:
                    it = NonSeekingReader(f).iter_messages(
                        topics=list(topics), log_time_order=False
                    )
                try:
                    for _, channel, message in it:
                        if channel is None or channel.topic not in topics:
                            continue
                        device, raw = topics[channel.topic]
                        yield device, raw, message.log_time, batch_wire(message.data)
                except Exception as e:
                    # own errors, struct's, zstd's; a file without a summary ends in one
                    if indexed:
                        raise McapInputError(f"{path}: damaged: {e}") from None


def split_parts(path: Path) -> list[Path]:
    """The files `imud record -o PATH --split-...` wrote (PATH_000.mcap, PATH_001.mcap, ...),
    in order, each replaced by its `-recovered` copy where `imud record --recover` made one of
    a broken part; empty when there are none. McapInputError for a series with a part missing
    (naming it)."""
    suffix = path.suffix or ".mcap"
    pattern = f"{glob.escape(path.stem)}_[0-9][0-9][0-9]{suffix}"
    found = sorted(path.parent.glob(pattern))
    if not found:
        return []
    names = {p.name for p in found}
    last = max(int(p.stem[-3:]) for p in found)
    missing = [
        f"{path.stem}_{k:03d}{suffix}"
        for k in range(last + 1)
        if f"{path.stem}_{k:03d}{suffix}" not in names
    ]
    if missing:
        have = ", ".join(p.name for p in found)
        raise McapInputError(
            f"{path}: split part {', '.join(missing)} is missing (found {have}); name the "
            "parts to read one by one to go on without it"
        )
    out = []
    for p in found:
        fixed = p.with_name(f"{p.stem}-recovered{p.suffix}")
        out.append(fixed if not has_footer(p) and fixed.exists() else p)
    return out


def _span(rec: Recording) -> tuple[int, int]:
    """(first, last) log time of a file's native batches (only theirs: a recording of a replay
    logs its /diagnostics at the wall clock's time)."""
    if rec.indexed:
        topics = list(rec.devices.values())
        with open(rec.path, "rb") as f:
            r = make_reader(f)
            first = next(r.iter_messages(topics=topics), None)
            last = next(r.iter_messages(topics=topics, reverse=True), None)
        return (first[2].log_time if first else 0), (last[2].log_time if last else 0)
    times = [log_ns for _, log_ns, _ in rec.batches()]
    return (times[0], times[-1]) if times else (0, 0)


def open_recordings(paths: list[Path], prefix: str | None = None) -> Recording:
    """One recording from one file, or from the parts of a split one: the files given, put in
    time order, or for one name that does not exist (`-o NAME.mcap` with --split-...), its
    parts NAME_000.mcap, NAME_001.mcap, ... Raises McapInputError naming what is wrong (parts
    that overlap in time are not one recording)."""
    if len(paths) == 1 and not paths[0].exists():
        parts = split_parts(paths[0])
        if not parts:
            first = f"{paths[0].stem}_000{paths[0].suffix or '.mcap'}"
            raise McapInputError(f"{paths[0]} does not exist (nor split parts of it, {first}, ...)")
        paths = parts
    seen = set()
    for p in paths:
        key = p.resolve()
        if key in seen:
            raise McapInputError(f"{p} is named twice: give each part of a recording once")
        seen.add(key)
    recs = [open_recording(p, prefix) for p in paths]
    if len(recs) == 1:
        return recs[0]
    spans = {id(r): _span(r) for r in recs}
    recs.sort(key=lambda r: spans[id(r)][0])
    for a, b in itertools.pairwise(recs):
        # a split part's last batches may be logged a little after the next part's first (a
        # batch is logged at its last sample, the split made as batches arrive: one slow
        # device's batch, tens of ms): a quarter of a second, and never the same start
        sa, sb = spans[id(a)], spans[id(b)]
        if sb[0] < sa[1] - OVERLAP_NS or sb[0] == sa[0]:
            raise McapInputError(
                f"{a.path} and {b.path} overlap in time: not parts of one recording (a part "
                "and its -recovered copy? give one of them)"
            )
    out = Recording(recs[0].path, recs[0].indexed, attachments=recs[0].attachments)
    out.parts = [(r.path, r.indexed) for r in recs]
    for r in recs:
        for name, topic in r.devices.items():
            out.devices.setdefault(name, topic)
        for name, topic in r.raw.items():
            out.raw.setdefault(name, topic)
        for name, info in r.info.items():
            out.info.setdefault(name, info)
    warnings = [r.warning for r in recs if r.warning]
    out.warning = "; ".join(warnings) if warnings else None
    return out


def open_recording(path: Path, prefix: str | None = None) -> Recording:
    """The devices and descriptions in `path`. Raises McapInputError for what is not a
    recording of imud's."""
    try:
        size = path.stat().st_size
    except OSError as e:
        raise McapInputError(f"{path}: cannot read: {e.strerror}") from None
    if size == 0:
        raise McapInputError(f"{path} is empty (a recorder that died at once?)")
    if not is_mcap(path):
        raise McapInputError(f"{path} is not an MCAP file (imud record -o FILE.mcap writes one)")
    rec = Recording(path, indexed=has_footer(path))
    channels: list[tuple[str, str]] = []  # (topic, schema name)
    with open(path, "rb") as f:
        try:
            if rec.indexed:
                reader = make_reader(f)
                summary = reader.get_summary()
                if summary is not None:
                    channels = [
                        (c.topic, summary.schemas[c.schema_id].name if c.schema_id else "")
                        for c in summary.channels.values()
                    ]
                for m in reader.iter_metadata():
                    _take_metadata(rec, m.name, m.metadata)
                for a in reader.iter_attachments():
                    rec.attachments[a.name] = a.data
            else:
                rec.warning = (
                    f"{path} has no summary (its recorder stopped before closing it): read as a "
                    f"stream to its last whole message; `imud record --recover {path}` makes an "
                    "indexed copy"
                )
                channels = _stream_channels(rec, f)
        except Exception as e:
            raise McapInputError(f"{path}: not a readable MCAP file ({e})") from None
    for topic, schema in channels:
        parts = topic.strip("/").split("/")
        ours = schema == BATCH and len(parts) == 3 and parts[2] in ("batch", "raw")
        if ours and (prefix is None or parts[0] == prefix):
            (rec.devices if parts[2] == "batch" else rec.raw)[parts[1]] = topic
    if not rec.devices:
        listed = ", ".join(sorted(t for t, _ in channels)) or "none"
        raise McapInputError(
            f"{path} holds no imud batches (its topics: {listed}): `imud record -o FILE.mcap` "
            "writes them"
        )
    return rec


def _take_metadata(rec: Recording, name: str, data: dict[str, str]) -> None:
    if name == "imud.devices":
        for device, text in data.items():
            try:
                rec.info[device] = json.loads(text)
            except ValueError:
                continue


def _stream_channels(rec: Recording, f: Any) -> list[tuple[str, str]]:
    from mcap.records import Attachment, Channel, Metadata, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, str] = {}
    out: list[tuple[str, str]] = []
    try:
        for r in StreamReader(f).records:
            if isinstance(r, Schema):
                schemas[r.id] = r.name
            elif isinstance(r, Channel):
                out.append((r.topic, schemas.get(r.schema_id, "")))
            elif isinstance(r, Metadata):
                _take_metadata(rec, r.name, r.metadata)
            elif isinstance(r, Attachment):
                rec.attachments[r.name] = r.data
    except Exception:
        pass
    return out
