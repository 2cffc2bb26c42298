"""A device's published stream: the pipeline's batches in, encoded wire batches out.

A batch is published as one or more runs of samples: samples with no valid measurement at all
(holes) are left out and count as lost, like the samples lost before the batch. Losses are
carried into the next published batch's `lost_before` (flagged as a resync), so a subscriber
finds every gap counted exactly.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from imud.channels import INVALID_MASK, Channel
from imud.pipeline import SampleBatch
from imud.wire import FLAG_CALIBRATED, FLAG_GAP_UNCERTAIN, FLAG_RESYNC, encode

Publish = Callable[[bytes], None]
# a stream of small batches (a chip read once a sample) is published in batches of up to this
# much of its time: per published batch, the encode, the send and the daemon's relay cost as
# much as for one sample, and the wait it adds is a few of the chip's periods
MERGE_NS = 5_000_000


def runs(hole: npt.NDArray[np.bool_] | None, n: int) -> list[tuple[int, int]]:
    """[start, end) of each run of publishable samples; the whole batch when there are no
    holes."""
    if hole is None:
        return [(0, n)] if n else []
    edges = np.flatnonzero(np.diff(np.concatenate(([True], hole, [True])).astype(np.int8)))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


class Emitter:
    """Encodes and publishes one device's batches and counts what it published."""

    def __init__(
        self,
        name: str,
        epoch_offset_ns: int,
        publish: Publish,
        on_loss: Callable[[int, int], None],
    ) -> None:
        self.name = name
        self.epoch_offset_ns = epoch_offset_ns
        self.publish = publish
        self.publish_raw: Publish | None = None  # the uncorrected stream, while subscribed
        self.on_loss = on_loss  # (samples lost, now): counted and logged by the runner
        self.samples = 0
        self.batches = 0
        self.invalid_samples = 0
        self.calibration_outside_span = 0
        self.temperature_c: float | None = None
        self.unpublished_lost = 0  # carried into the next published batch's lost_before
        self.unpublished_uncertain = False  # ... and whether that count is an estimate
        self.uncertain_gaps = 0  # gaps published as estimates (FLAG_GAP_UNCERTAIN)
        # (next seq, last stamp less the epoch offset) of what was published: where a
        # successor (the device restarted with new settings by a reload) continues
        self.stream_end: tuple[int, int] | None = None
        self._held: list[SampleBatch] = []  # small batches waiting to go out as one
        self._held_since = 0  # host time the first of them came
        self._last_t: int | None = None  # the newest stamp seen

    def emit(self, batch: SampleBatch, now: int) -> None:
        """Publish `batch`, or hold it to go out with the next ones (MERGE_NS)."""
        if not batch.n and not batch.lost_before and not batch.flags & FLAG_GAP_UNCERTAIN:
            return  # a poll that found nothing: nothing to publish, nothing held to end
        if self._held and not self._joins(batch):
            self.flush()
        fast = self._last_t is not None and batch.n and batch.t_ns[0] - self._last_t < MERGE_NS // 2
        if batch.n:
            self._last_t = int(batch.t_ns[-1])
        if self._held:
            self._held.append(batch)
            if batch.t_ns[-1] - self._held[0].t_ns[0] >= MERGE_NS // 2:
                self.flush()
            return
        if fast and batch.hole is None and batch.t_ns[-1] - batch.t_ns[0] < MERGE_NS // 2:
            self._held, self._held_since = [batch], now
            return
        self._emit(batch, now)

    def flush_due(self, now: int) -> None:
        """Publish what is held once it has waited MERGE_NS."""
        if self._held and now - self._held_since >= MERGE_NS:
            self.flush()

    def flush(self) -> None:
        """Publish what is held, as one batch."""
        held, self._held = self._held, []
        if held:
            self._emit(merged(held) if len(held) > 1 else held[0], self._held_since)

    def _joins(self, batch: SampleBatch) -> bool:
        """`batch` goes on from the held ones with nothing between and nothing different."""
        first, last = self._held[0], self._held[-1]
        return (
            batch.n > 0
            and batch.lost_before == 0
            and batch.hole is None
            and batch.flags == first.flags
            and batch.first_seq == last.first_seq + last.n
            and (batch.raw is None) == (first.raw is None)
            and batch.channels.keys() == first.channels.keys()
            and batch.t_ns[-1] - first.t_ns[0] < MERGE_NS
        )

    def lost(self, n: int, now: int) -> None:
        self.unpublished_lost += n
        self.on_loss(n, now)

    def _emit(self, batch: SampleBatch, now: int) -> None:
        if batch.lost_before:
            self.lost(batch.lost_before, now)
        if batch.flags & FLAG_GAP_UNCERTAIN:
            self.unpublished_uncertain = True
        self.calibration_outside_span += batch.outside_span
        run_end = 0
        whole = batch.hole is None
        spans = ((0, batch.n),) if whole and batch.n else runs(batch.hole, batch.n)
        for start, end in spans:
            if start > run_end:  # samples with no valid data at all are holes: lost
                self.lost(start - run_end, now)
            self._run(batch, start, end, whole)
            run_end = end
        if batch.n and run_end < batch.n:
            self.lost(batch.n - run_end, now)

    def _run(self, batch: SampleBatch, start: int, end: int, whole: bool) -> None:
        sf = batch.sample_flags
        if sf is not None and not whole:
            sf = sf[start:end]
        chans = batch.channels if whole else {c: a[start:end] for c, a in batch.channels.items()}
        t_ns = batch.t_ns if whole else batch.t_ns[start:end]
        flags = batch.flags & ~FLAG_GAP_UNCERTAIN | (FLAG_RESYNC if self.unpublished_lost else 0)
        if self.unpublished_uncertain:  # on the run that carries the gap, not the ones after
            flags |= FLAG_GAP_UNCERTAIN
            self.uncertain_gaps += 1
        lost, seq = self.unpublished_lost, batch.first_seq + start
        self.publish(encode(self.name, seq, t_ns, chans, sf, flags=flags, lost_before=lost))
        if batch.raw is not None and self.publish_raw is not None:
            raw = batch.raw if whole else {c: a[start:end] for c, a in batch.raw.items()}
            uncorrected = flags & ~FLAG_CALIBRATED
            self.publish_raw(
                encode(self.name, seq, t_ns, raw, sf, flags=uncorrected, lost_before=lost)
            )
        self.unpublished_lost = 0
        self.unpublished_uncertain = False
        self.stream_end = (seq + end - start, int(t_ns[-1]) - self.epoch_offset_ns)
        self.samples += end - start
        self.batches += 1
        if sf is not None:
            self.invalid_samples += int(np.count_nonzero(sf & INVALID_MASK))
        temp = chans.get(Channel.TEMPERATURE)
        if temp is not None:
            t = float(temp[-1])
            if t == t:  # not NaN
                self.temperature_c = t


def merged(held: list[SampleBatch]) -> SampleBatch:
    """Consecutive batches (no gap between, the same flags and channels) as one."""
    first = held[0]
    flags = [b.sample_flags for b in held]
    sample_flags = None
    if any(f is not None for f in flags):
        sample_flags = np.concatenate(
            [
                np.zeros(b.n, dtype=np.uint32) if f is None else f
                for b, f in zip(held, flags, strict=True)
            ]
        )
    raw = None
    if first.raw is not None:
        raw = {c: np.concatenate([b.raw[c] for b in held if b.raw is not None]) for c in first.raw}
    return SampleBatch(
        first.first_seq,
        first.lost_before,
        first.flags,
        np.concatenate([b.t_ns for b in held]),
        {c: np.concatenate([b.channels[c] for b in held]) for c in first.channels},
        sample_flags,
        None,
        raw,
        sum(b.outside_span for b in held),
    )
