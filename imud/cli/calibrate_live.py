"""Live captures for `imud calibrate --device`: the daemon's uncorrected stream
(`<prefix>/<device>/raw`, computed only while this subscribes) into a `Recording`, with progress
on stderr: which still poses are held, which are missing, and when motion spoiled a capture.

The still-pose detection is the offline one (imud.calib.still) run on what has arrived so far,
once a second, so live and offline agree on what counts as a pose.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from imud.calib.recording import Recording
from imud.calib.still import StillInterval
from imud.calib.temp import SPAN_PER_ORDER_C
from imud.channels import INVALID_MASK, SATURATED, Channel
from imud.status import DeviceState

F64 = npt.NDArray[np.float64]
_SAT_MASK = sum(int(f) for f in SATURATED.values())
UPDATE_S = 1.0
MORE_EVERY_S = 3.0  # how often an extended capture asks its fit what more it needs
MAX_EXTEND_S = 600.0  # the longest an extended capture goes on


class Buffer:
    """Decoded raw batches accumulated as arrays; samples a chip marked invalid are left out
    (a recording holds measurements only) and counted."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.parts: list[dict[str, Any]] = []
        self.dropped_invalid = 0
        self.lost = 0

    def add(self, b: Any) -> None:
        if b.accel is None or b.gyro is None:
            return
        if self.parts:  # a first batch's count is from before this capture subscribed
            self.lost += int(b.lost_before)
        ok = (b.sample_flags & np.uint32(INVALID_MASK)) == 0
        self.dropped_invalid += int(np.count_nonzero(~ok))
        if not ok.any():
            return
        part: dict[str, Any] = {
            "t": b.t_ns[ok],
            "a": b.accel[ok].astype(np.float64),
            "g": b.gyro[ok].astype(np.float64),
            "sat": (b.sample_flags[ok] & np.uint32(_SAT_MASK)) != 0,
        }
        if b.temperature_c is not None:
            part["T"] = b.temperature_c[ok].astype(np.float64)
        mag = b.get(Channel.MAG)
        if mag is not None:
            part["m"] = mag[ok].astype(np.float64)
        self.parts.append(part)

    @property
    def n(self) -> int:
        return sum(len(p["t"]) for p in self.parts)

    def summary(self) -> str:
        """What the capture could not use, for the person running it ('' when nothing)."""
        parts = [
            f"{n} {what}"
            for n, what in (
                (self.lost, "samples lost on the way"),
                (self.dropped_invalid, "samples the chip marked invalid, left out"),
            )
            if n
        ]
        return "; ".join(parts)

    def recording(self) -> Recording:
        ps = self.parts

        def cat(key: str) -> Any:
            if not ps or any(key not in p for p in ps):
                return None
            return np.concatenate([p[key] for p in ps])

        return Recording(
            cat("t").astype(np.int64),
            cat("a"),
            cat("g"),
            cat("T"),
            cat("m"),
            cat("sat"),
            self.source,
        )


def _stream(job: Any) -> tuple[Any, Any]:
    """(session, batch iterator) on the device's raw stream."""
    import imud.client as ic
    from imud.cli.common import _session

    dev = _status_device(job)
    if dev.get("state") != DeviceState.RUNNING:
        from imud.cli.common import EXIT_NO_DAEMON, _fail

        _fail(
            f"{job.device_name} is {dev.get('state')}: {dev.get('last_error') or '-'}",
            EXIT_NO_DAEMON,
            job.as_json,
        )
    s = _session(job.o["endpoint"], job.as_json)
    it = ic.batches(s, job.device_name, job.o["prefix"], raw=True, timeout=5.0)
    return s, it


def _status_device(job: Any) -> dict[str, Any]:
    """The live device's status entry (checks the name, fills in the chip)."""
    from imud.cli.common import _ask_status, _device, _session

    o = job.o
    with _session(o["endpoint"], job.as_json) as s:
        st = _ask_status(s, o["endpoint"], o["prefix"], 2.0, job.as_json)
    dev = _device(st, job.device_name, o["endpoint"], False, job.as_json)
    job.chip = job.chip or dev["chip"]
    return dev


def _console(job: Any) -> Any:
    from rich.console import Console

    return Console(stderr=True, highlight=False, quiet=job.as_json)


def capture_poses(
    job: Any, target: int, min_s: float, missing: Callable[[list[StillInterval]], str | None]
) -> Recording:
    """Capture until `target` distinct still orientations are held and `missing(poses)` has
    nothing more to ask for (the fit can be formed from them), or --duration passes."""
    from rich.live import Live
    from rich.text import Text

    from imud.calib.accel import orientation_labels, suggest_poses
    from imud.calib.still import CalibrationRefused, find_still

    limit = job.o["duration"] or 600.0
    buf = Buffer(f"live {job.device_name}")
    s, it = _stream(job)
    con = _console(job)
    start = time.monotonic()
    distinct, last = 0, 0.0
    with s, Live(Text("waiting for samples..."), console=con, transient=False) as live:
        for b in it:
            buf.add(b)
            now = time.monotonic()
            if now - last < UPDATE_S or now - start < 3 * UPDATE_S:
                continue
            last = now
            rec = buf.recording()
            try:
                ivs = find_still(rec, min_s=min_s)
            except CalibrationRefused:  # too little yet to tell still from moving
                continue
            dirs = np.zeros((0, 3))
            if ivs:
                _, dirs = orientation_labels(np.array([iv.accel for iv in ivs]))
            distinct = len(dirs)
            bar = "#" * min(distinct, target) + "." * max(0, target - distinct)
            moving = not ivs or ivs[-1].end < rec.n - int(rec.rate_hz)  # last second not still
            text = Text(
                f"[{bar}] {distinct}/{target} orientations held still >= {min_s:g} s, "
                f"{now - start:.0f} s; now: {'moving' if moving else 'still'}"
            )
            why = None
            if distinct < target:
                text.append("\n  next: " + "; ".join(suggest_poses(dirs, 3)))
            else:  # enough orientations; enough for the fit?
                why = missing(ivs)
                if why:
                    text.append(f"\n  still needed: {why}")
            live.update(text)
            if (distinct >= target and why is None) or now - start > limit:
                break
        it.close()
    if buf.n < 2:
        from imud.cli.common import EXIT_NO_DAEMON, _fail

        _fail(f"no samples arrived from {job.device_name}", EXIT_NO_DAEMON, job.as_json)
    if buf.summary():
        con.print(f"{job.device_name}: {buf.summary()}")
    return buf.recording()


def capture_for(
    job: Any,
    default_s: float,
    need_mag: bool = False,
    show_temperature: bool = False,
    more: Callable[[Recording], str | None] | None = None,
) -> Recording:
    """Capture for --duration (or `default_s`) seconds; for the magnetometer, stop as soon as
    the field has been seen from enough directions; for a temperature fit, show the span so far
    (each polynomial order needs 5 degC more of it). `more(recording)`: after `default_s`
    (when --duration was not given), go on while it says what the fit still needs, up to
    MAX_EXTEND_S (a gyro on a bench: until rotations about every axis were seen)."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    given = job.o["duration"]
    limit = given or default_s
    extendable = more is not None and not given
    buf = Buffer(f"live {job.device_name}")
    s, it = _stream(job)
    con = _console(job)
    start = time.monotonic()
    cols = (TextColumn("{task.description}"), BarColumn(), TimeRemainingColumn())
    with s, Progress(*cols, console=con, transient=True) as prog:
        task = prog.add_task(f"capturing {job.device_name}", total=limit)
        last = 0.0
        for b in it:
            buf.add(b)
            now = time.monotonic()
            prog.update(task, completed=min(now - start, limit))
            if now - start >= limit:
                if not extendable or now - start >= MAX_EXTEND_S:
                    break
                if now - last < MORE_EVERY_S:
                    continue
                last = now
                assert more is not None
                why = more(buf.recording())
                if why is None:
                    break
                limit = min(MAX_EXTEND_S, now - start + MORE_EVERY_S)
                prog.update(task, total=MAX_EXTEND_S, description=f"still needed: {why}")
                continue
            if need_mag and now - last >= UPDATE_S and buf.n > 100:
                last = now
                frac = _mag_coverage(buf.recording())
                prog.update(task, description=f"rotate it every way: {frac:.0%} of directions")
                if frac >= 0.95:
                    break
            elif show_temperature and now - last >= UPDATE_S and buf.n > 1:
                last = now
                temp = buf.recording().temp
                if temp is not None and np.isfinite(temp).any():
                    lo, hi = float(np.nanmin(temp)), float(np.nanmax(temp))
                    prog.update(
                        task,
                        description=f"keep it still: {lo:.1f} to {hi:.1f} degC "
                        f"(span {hi - lo:.1f}; order k needs {SPAN_PER_ORDER_C:g}k)",
                    )
        it.close()
    if buf.n < 2:
        from imud.cli.common import EXIT_NO_DAEMON, _fail

        _fail(f"no samples arrived from {job.device_name}", EXIT_NO_DAEMON, job.as_json)
    if buf.summary():
        con.print(f"{job.device_name}: {buf.summary()}")
    return buf.recording()


def _mag_coverage(rec: Recording) -> float:
    from imud.calib.mag import coverage

    if rec.mag is None:
        return 0.0
    m = rec.mag
    centred = m - 0.5 * (m.max(axis=0) + m.min(axis=0))
    u = centred / np.maximum(np.linalg.norm(centred, axis=1, keepdims=True), 1e-12)
    return float(coverage(u).fraction)
