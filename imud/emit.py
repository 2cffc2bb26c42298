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

    def lost(self, n: int, now: int) -> None:
        self.unpublished_lost += n
        self.on_loss(n, now)

    def emit(self, batch: SampleBatch, now: int) -> None:
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
