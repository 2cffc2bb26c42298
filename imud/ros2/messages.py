"""Each device's batches as ROS 2 messages: sensor_msgs/Imu, MagneticField and Temperature on its
REP-145 topics, averaged to `[ros2] rate_hz`, stamped by the samples, never stepping back; and
/diagnostics from the daemon's status. What they are, not where they go: the daemon's ROS 2
output (imud/ros2/output.py) puts them on rmw_zenoh, the bridge and DDS, and the recorder writes
them to MCAP, so both carry the same messages for the same batches.

`batch` is fed one device's batches in order, from one thread per device; `reconfigure` swaps
whole `_Device` objects, so a batch sees either the old or the new one.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable, Iterator
from dataclasses import astuple, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from imud.channels import Channel
from imud.ros2 import diagnostics as diag
from imud.ros2.cdr import Layout, layout, messages, template
from imud.ros2.covariance import UNKNOWN, Covariances, covariances
from imud.ros2.decimate import Decimator, factor
from imud.rosnames import join
from imud.wire import KIND_SAMPLES, Picks, WireError, gather, peek

if TYPE_CHECKING:
    from imud.chips.api import DeviceBase, NoiseFigures
    from imud.config import ImudConfig

log = logging.getLogger("imud.ros2")

IMU = "sensor_msgs/msg/Imu"
MAG = "sensor_msgs/msg/MagneticField"
TEMPERATURE = "sensor_msgs/msg/Temperature"
NO_ORIENTATION = np.r_[-1.0, np.zeros(8)]  # REP-145: orientation_covariance[0] = -1


@dataclass(eq=False)
class Topic:
    """One ROS 2 topic: its name, message type and (for the devices' fixed-layout messages)
    layout. Compared by identity: a topic object is one publisher, kept across reloads."""

    name: str
    type_name: str
    layout: Layout | None  # None: not a fixed-layout message (diagnostics)
    frame_id: str = ""
    handles: dict[str, Any] = field(default_factory=dict)  # what an output keeps per topic
    lock: threading.Lock = field(default_factory=threading.Lock)  # the old and new device's
    # relay threads both emit during a reload


@dataclass(frozen=True)
class Payloads:
    """One step's messages on a topic: each message's header stamp and CDR bytes, a device's as
    one record array of its fixed layout (a recorder writes them whole), others as a list.
    Iterating gives each message's bytes."""

    stamps_ns: npt.NDArray[np.int64]
    records: npt.NDArray[np.void] | list[bytes]

    def __iter__(self) -> Iterator[bytes]:
        if isinstance(self.records, list):
            return iter(self.records)
        return (r.tobytes() for r in self.records)


Emit = Callable[[Topic, Payloads], None]


@dataclass
class _Feed:
    """A topic as one device fills it: its messages' constant fields (a cdr.template)."""

    topic: Topic
    base: Any


@dataclass
class _Device:
    cfg: DeviceBase
    cols: dict[Channel, slice]  # where each channel sits in the (N, W) matrix of a batch
    picks: Picks  # the wire's channel components, column by column
    decimator: Decimator
    cov: Covariances  # of its messages at its settings and rate (docs/ros2.md "Covariances")
    topics: dict[str, _Feed] = field(default_factory=dict)  # replaced whole, never edited
    calibration: Signature = None  # the calibration file its covariances were read from
    last_ns: int = -1  # stamps never step back (a bus restarted, a reload)
    dropped: int = 0
    pending: list[bytes] = field(default_factory=list)  # batches held until [ros2] batch_ms
    pending_from: int = 0  # the first held sample's stamp


class Ros2Messages:
    """The messages of `cfg`'s devices. `emit(topic, payloads)` receives each step's CDR
    payloads; `on_topic(topic, added)` hears of topics coming and going (an output declares
    publishers there). A device with `ros2.enabled = false` has none."""

    def __init__(
        self,
        cfg: ImudConfig,
        emit: Emit,
        on_topic: Callable[[Topic, bool], None] | None = None,
        diagnostics: bool | None = None,
        hold_ms: float | None = None,
    ) -> None:
        self.settings = cfg.ros2
        self._emit = emit
        self._on_topic = on_topic or (lambda t, added: None)
        # how much of a stream to hold before a step (the same messages whatever it is: the
        # decimator groups by seq; a recorder, which need not be prompt, holds longer)
        self._hold_ns = int((cfg.ros2.batch_ms if hold_ms is None else hold_ms) * 1e6)
        # topics by (name, type, frame_id): a device rebuilt by a reload keeps its topics, so
        # subscribers see one publisher that never restarted
        self._topics: dict[tuple[str, str, str], Topic] = {}
        self._devices: dict[str, _Device] = {}
        self._lock = threading.Lock()  # building and dropping topics only
        self.diagnostics: Topic | None = None
        self._lost: dict[str, int] = {}  # each device's lost samples at the last report
        if cfg.ros2.diagnostics if diagnostics is None else diagnostics:
            self.diagnostics = Topic(diag.TOPIC, diag.TYPE_NAME, None)
            self._topics[(diag.TOPIC, diag.TYPE_NAME, "")] = self.diagnostics
            self._on_topic(self.diagnostics, True)
        self.reconfigure(cfg)

    # --- the topics ---------------------------------------------------------------------------
    def reconfigure(self, cfg: ImudConfig) -> None:
        """Topics for `cfg`'s devices: a device whose ROS 2 side is unchanged keeps its topics
        and state; others get new ones (their sequence numbers go on)."""
        with self._lock:
            old = self._devices
            new: dict[str, _Device] = {}
            for d in cfg.device:
                if not d.ros2.enabled:
                    continue
                prev = old.get(d.name)
                if prev is not None and _same(prev.cfg, d):
                    new[d.name] = prev
                    continue
                dev = self._device(d)
                if prev is not None:
                    dev.last_ns = prev.last_ns
                new[d.name] = dev
            self._devices = new
            used = {id(f.topic) for dev in new.values() for f in dev.topics.values()}
            if self.diagnostics is not None:
                used.add(id(self.diagnostics))
            for key, t in list(self._topics.items()):
                if id(t) not in used:
                    self._on_topic(t, False)
                    del self._topics[key]

    def _device(self, d: DeviceBase) -> _Device:
        from imud import registry  # the chip's channels: what topics it has

        s = self.settings
        channels = registry.device_channels(d)
        cols: dict[Channel, slice] = {}
        picks: list[tuple[Channel, int]] = []
        width = 0
        for ch, w in _WIDTHS.items():
            if channels & ch:
                cols[ch] = slice(width, width + w)
                width += w
                # a quaternion is w, x, y, z on the wire and x, y, z, w in ROS
                picks += [(ch, i) for i in (_XYZW if ch is Channel.ORIENTATION else range(w))]
        k = factor(d.odr_hz, d.ros2.rate_hz or s.rate_hz)
        quat = cols.get(Channel.ORIENTATION)
        sig = _signature(d.calibration)
        cov = covariances(_noise(d), d.odr_hz, k, _measured(d))
        dev = _Device(d, cols, tuple(picks), Decimator(k, quat), cov, calibration=sig)
        dev.topics = self._feeds(d, channels, cov)
        return dev

    def _feeds(self, d: DeviceBase, channels: Channel, cov: Covariances) -> dict[str, _Feed]:
        """The device's topics (announced when new) with their messages' constant fields."""
        s = self.settings
        where = join(s.namespace, d.ros2.namespace or d.name)
        frame = d.ros2.frame_id or s.frame_id
        imu_cov = {
            "angular_velocity_covariance": cov.gyro,
            "linear_acceleration_covariance": cov.accel,
        }
        wanted: list[tuple[str, str, dict[str, Any]]] = []
        if channels & (Channel.ACCEL | Channel.GYRO):
            wanted.append(
                ("imu/data_raw", IMU, {"orientation_covariance": NO_ORIENTATION, **imu_cov})
            )
        if channels & Channel.ORIENTATION:
            # an orientation whose accuracy no datasheet figure imud has states: unknown
            # (REP-145, all zero), never -1, which would say there is none
            wanted.append(("imu/data", IMU, {"orientation_covariance": UNKNOWN, **imu_cov}))
        if channels & Channel.MAG:
            wanted.append(("imu/mag", MAG, {"magnetic_field_covariance": cov.mag}))
        if s.temperature and channels & Channel.TEMPERATURE:
            wanted.append(("imu/temperature", TEMPERATURE, {"variance": 0.0}))
        feeds: dict[str, _Feed] = {}
        for rel, type_name, fixed in wanted:
            key = (join(where, rel), type_name, frame)
            topic = self._topics.get(key)
            if topic is None:
                topic = Topic(key[0], type_name, layout(type_name, frame), frame)
                self._topics[key] = topic
                self._on_topic(topic, True)
            feeds[rel] = _Feed(topic, template(_lay(topic), fixed))
        return feeds

    def topics(self) -> list[str]:
        """Every device topic, for status."""
        return sorted(f.topic.name for d in self._devices.values() for f in d.topics.values())

    def all_topics(self) -> list[Topic]:
        """Every topic, /diagnostics included."""
        return list(self._topics.values())

    def dropped(self) -> dict[str, int]:
        """Per device, messages not sent because their stamp did not follow the last one sent
        (a bus restart or a reload re-sent an instant already published), for status."""
        return {name: dev.dropped for name, dev in self._devices.items() if dev.dropped}

    def close(self) -> None:
        with self._lock:
            for t in self._topics.values():
                self._on_topic(t, False)
            self._topics = {}
            self._devices = {}

    # --- once a second -------------------------------------------------------------------------
    def tick(self, devices: list[dict[str, Any]], now_ns: int, period_s: float = 1.0) -> None:
        """Every `period_s`, with the daemon's devices' status JSON: emits /diagnostics, and
        takes up the measured noise of a calibration file that changed."""
        for dev in list(self._devices.values()):
            sig = _signature(dev.cfg.calibration)
            if sig != dev.calibration:
                dev.calibration = sig
                self._refresh_covariances(dev)
        t = self.diagnostics
        if t is None:
            return
        statuses = []
        for d in devices:
            name = str(d.get("name"))
            statuses.append(diag.device_status(d, self._lost.get(name), period_s))
            self._lost[name] = int(d.get("lost_samples", 0))
        self._emit(t, Payloads(np.array([now_ns], dtype=np.int64), [diag.encode(now_ns, statuses)]))

    def _refresh_covariances(self, dev: _Device) -> None:
        from imud import registry

        d = dev.cfg
        cov = covariances(_noise(d), d.odr_hz, dev.decimator.k, _measured(d))
        if all(np.array_equal(a, b) for a, b in zip(astuple(cov), astuple(dev.cov), strict=True)):
            return
        with self._lock:
            dev.cov = cov
            dev.topics = self._feeds(d, registry.device_channels(d), cov)
        log.info("%s: ROS 2 covariances now from %s", d.name, d.calibration)

    # --- the batches --------------------------------------------------------------------------
    def batch(self, name: str, payload: bytes | memoryview) -> None:
        """One wire batch of device `name`: held until `[ros2] batch_ms` of the stream has
        arrived (by the samples' stamps, so how the scheduler ran does not change what is
        emitted), then averaged and emitted in one step."""
        dev = self._devices.get(name)
        if dev is None:
            return
        try:
            _, n, first_ns, last_ns, _ = peek(payload)
        except Exception:  # struct.error: shorter than a header
            log.error("%s: a batch too short for the ROS 2 messages", name)
            return
        if not n:
            return
        if not dev.pending:
            dev.pending_from = first_ns
        dev.pending.append(bytes(payload))
        if last_ns - dev.pending_from < self._hold_ns:
            return
        held, dev.pending = dev.pending, []
        self._step(name, dev, held)

    def flush(self) -> None:
        """Emit what every device holds (the end of a recording)."""
        for name, dev in list(self._devices.items()):
            held, dev.pending = dev.pending, []
            if held:
                self._step(name, dev, held)

    def _step(self, name: str, dev: _Device, payloads: list[bytes]) -> None:
        parts = []
        for p in payloads:
            try:
                kind, first, t_ns, values = gather(p, dev.picks)
            except WireError:
                log.exception("%s: a batch the ROS 2 messages cannot read", name)
                continue
            if kind == KIND_SAMPLES and t_ns.shape[0]:
                parts.append((first, t_ns, values))
        if not parts:
            return
        if len(parts) == 1:
            first, t_ns, m = parts[0][0], parts[0][1], parts[0][2].astype(np.float64)
            seq = first + np.arange(t_ns.shape[0], dtype=np.int64)
        else:
            t_ns = np.concatenate([p[1] for p in parts])
            m = np.concatenate([p[2] for p in parts], dtype=np.float64)
            # each batch's samples count on from its first seq: one arange, shifted per batch
            lens = np.array([p[1].shape[0] for p in parts], dtype=np.int64)
            firsts = np.array([p[0] for p in parts], dtype=np.int64)
            seq = np.arange(t_ns.shape[0], dtype=np.int64)
            seq += np.repeat(firsts - (np.cumsum(lens) - lens), lens)
        out = dev.decimator.feed(seq, t_ns, m)
        if not out.n:
            return
        t, v = out.t_ns, out.values
        if t[0] <= dev.last_ns:
            keep = t > dev.last_ns
            dev.dropped += int(np.count_nonzero(~keep))
            t, v = t[keep], v[keep]
            if not t.size:
                return
        dev.last_ns = int(t[-1])
        self._messages(dev, t, v)

    def _messages(self, dev: _Device, t: Any, v: Any) -> None:
        cols = dev.cols
        imu: dict[str, Any] = {}
        if Channel.GYRO in cols:
            imu["angular_velocity"] = v[:, cols[Channel.GYRO]]
        if Channel.ACCEL in cols:
            imu["linear_acceleration"] = v[:, cols[Channel.ACCEL]]
        raw = dev.topics.get("imu/data_raw")
        if raw is not None:
            self._emit(raw.topic, Payloads(t, messages(_lay(raw.topic), t, imu, raw.base)))
        for rel, ch, name in _OPTIONAL:
            feed = dev.topics.get(rel)
            if feed is None:
                continue
            x = v[:, cols[ch]]
            tt = t
            have = ~np.isnan(x).all(axis=1)
            if not have.all():  # batches without this channel (a held magnetometer reading)
                x, tt = x[have], t[have]
                if not tt.size:
                    continue
            fields = {name: x[:, 0] if ch is Channel.TEMPERATURE else x}
            if ch is Channel.ORIENTATION:
                fields.update({f: a[have] for f, a in imu.items()})
                cov = cols.get(Channel.ORIENTATION_COVARIANCE)
                if cov is not None:  # imud's own filter states its covariance per sample
                    fields["orientation_covariance"] = v[have][:, cov][:, _SYM]
            self._emit(feed.topic, Payloads(tt, messages(_lay(feed.topic), tt, fields, feed.base)))


# a device's matrix columns, in this order: what each channel is as a ROS field
_WIDTHS = {
    Channel.ACCEL: 3,  # linear_acceleration
    Channel.GYRO: 3,  # angular_velocity
    Channel.MAG: 3,  # magnetic_field
    Channel.ORIENTATION: 4,  # orientation, x, y, z, w
    Channel.TEMPERATURE: 1,  # temperature
    Channel.ORIENTATION_COVARIANCE: 6,  # orientation_covariance, its upper triangle
}
_XYZW = (1, 2, 3, 0)
# the wire's xx, xy, xz, yy, yz, zz as ROS's row-major 3 x 3
_SYM = [0, 1, 2, 1, 3, 4, 2, 4, 5]
# topics sent only for samples that carry their channel: (topic, channel, field)
_OPTIONAL = (
    ("imu/data", Channel.ORIENTATION, "orientation"),
    ("imu/mag", Channel.MAG, "magnetic_field"),
    ("imu/temperature", Channel.TEMPERATURE, "temperature"),
)


def _lay(t: Topic) -> Layout:
    assert t.layout is not None  # every device topic has one
    return t.layout


Signature = tuple[int, int, int] | None


def _signature(path: Path | None) -> Signature:
    if path is None:
        return None
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_mtime_ns, st.st_size, st.st_ino)


def _measured(d: DeviceBase) -> dict[str, Any]:
    """The per-axis noise densities the device's calibration file measured, by sensor; empty
    when it has none or cannot be read (the device's status says why it is not applied)."""
    from imud.calib.file import CalibrationError, read_calibration

    if d.calibration is None:
        return {}
    try:
        cf = read_calibration(d.calibration)
    except CalibrationError:
        return {}
    if cf.chip is not None and cf.chip != d.chip:
        return {}
    out = {}
    for name in ("accel", "gyro"):
        table = cf.sensor(name)
        if table is not None and table.noise is not None:
            out[name] = np.asarray(table.noise.density, dtype=np.float64)
    return out


def _noise(d: DeviceBase) -> NoiseFigures | None:
    """The device's white noise at its settings, as its chip's spec states it (None: unknown)."""
    from imud import registry

    noise = registry.CHIPS[d.chip].noise
    return None if noise is None else noise(d)


def _same(a: DeviceBase, b: DeviceBase) -> bool:
    """The same ROS 2 side: chip, rate, ROS settings and noise (a new filter setting changes
    the covariances)."""
    return (a.chip, a.odr_hz, a.ros2, _noise(a)) == (b.chip, b.odr_hz, b.ros2, _noise(b))
