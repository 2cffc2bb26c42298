"""The daemon's ROS 2 output: each device's relayed batches as sensor_msgs messages, on the
profiles `[ros2]` names (docs/ros2.md).

Fed from the bus links' relay threads (`batch`), one device's batches always from the same
thread, in order; never on a bus worker. What the messages are is imud/ros2/messages.py's; this
puts them on rmw_zenoh, the bridge and DDS, each topic's publishers kept across reloads.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import zenoh

from imud.ros2 import bridge as zb
from imud.ros2 import rmw_zenoh as rz
from imud.ros2.dds import DdsError, DdsOutput
from imud.ros2.messages import Ros2Messages, Topic

if TYPE_CHECKING:
    from imud.config import ImudConfig, Ros2Settings

log = logging.getLogger("imud.ros2")


class DomainError(ValueError):
    pass


def domain_id(s: Ros2Settings, env: dict[str, str] | None = None) -> int:
    """`[ros2] domain_id`, else $ROS_DOMAIN_ID, else 0. Raises `DomainError` naming a bad
    environment value."""
    if s.domain_id is not None:
        return s.domain_id
    raw = (os.environ if env is None else env).get("ROS_DOMAIN_ID", "").strip()
    if not raw:
        return 0
    if not raw.isdigit() or int(raw) > 232:
        raise DomainError(
            f"ROS_DOMAIN_ID={raw!r} is not a ROS 2 domain id (0-232): fix the environment, or "
            "set [ros2] domain_id"
        )
    return int(raw)


@dataclass
class _Handles:
    """A topic's publishers on every profile it goes out on (Topic.handles["out"])."""

    rmw: Any = None  # zenoh.Publisher on rmw_zenoh's key
    bridge: Any = None  # zenoh.Publisher on the bridge's key
    dds: Any = None  # a dds writer
    token: Any = None  # zenoh.LivelinessToken: rmw_zenoh's publisher
    bridge_token: Any = None  # zenoh.LivelinessToken: the publisher announced to the bridge
    token_key: str = ""
    gid: bytes = b""
    sent: int = 0  # messages put (rmw_zenoh's attachment numbers them from 1)


class Ros2Output:
    """The messages of imud/ros2/messages.py on the profiles `[ros2]` names."""

    def __init__(self, cfg: ImudConfig, session: zenoh.Session) -> None:
        self.settings = cfg.ros2
        self.session = session
        self.domain = domain_id(cfg.ros2)
        self.zid = str(session.info.zid())
        self.error: str | None = None  # a profile that could not start (the others run)
        self._dds: DdsOutput | None = None
        if "dds" in cfg.ros2.profiles:
            try:
                self._dds = DdsOutput(
                    self.domain, cfg.ros2.reliable, cfg.ros2.depth, cfg.ros2.distro != "humble"
                )
            except DdsError as e:
                self.error = f"dds: {e}"
                log.error("ROS 2 %s; the other profiles run", self.error)
        self._ids = iter(range(1, 1 << 31))  # entity ids, unique within this session
        self._node = session.liveliness().declare_token(
            rz.node_token(self.domain, self.zid, 0, self.settings.namespace, self.settings.node)
        )
        self.msgs = Ros2Messages(cfg, self._put, self._topic)

    # --- what goes out ------------------------------------------------------------------------
    def reconfigure(self, cfg: ImudConfig) -> None:
        """Publishers for `cfg`'s devices: a device whose ROS 2 side is unchanged keeps its
        publishers and state; others get new ones (their sequence numbers go on)."""
        self.msgs.reconfigure(cfg)

    def _topic(self, t: Topic, added: bool) -> None:
        if added:
            t.handles["out"] = self._declare(t)
        else:
            self._undeclare(t.handles.pop("out", _Handles()))

    def _declare(self, t: Topic) -> _Handles:
        s = self.settings
        h = _Handles()
        type_hash = rz.NO_TYPE_HASH if s.distro == "humble" else rz.TYPE_HASHES[t.type_name]
        if "rmw_zenoh" in s.profiles:
            qos = rz.Qos(reliable=s.reliable, depth=s.depth)
            h.token_key = rz.publisher_token(
                self.domain, self.zid, 0, next(self._ids), s.namespace, s.node, t.name,
                t.type_name, type_hash, qos,
            )  # fmt: skip
            h.gid = rz.gid(h.token_key)
            h.rmw = self.session.declare_publisher(
                rz.data_key(self.domain, t.name, t.type_name, type_hash),
                congestion_control=zenoh.CongestionControl.DROP,  # as rmw_zenoh's KEEP_LAST
                reliability=zenoh.Reliability.RELIABLE
                if s.reliable
                else zenoh.Reliability.BEST_EFFORT,
            )
            h.token = self.session.liveliness().declare_token(h.token_key)
        if self._dds is not None:
            try:
                h.dds = self._dds.writer(t.name, t.type_name)
            except Exception as e:  # cyclonedds' own errors: the other profiles go on
                self.error = f"dds: {t.name}: {e}"
                log.error("ROS 2 %s; the other profiles run", self.error)
        if "bridge" in s.profiles:
            h.bridge = self.session.declare_publisher(
                zb.data_key(t.name),
                congestion_control=zenoh.CongestionControl.DROP,
                reliability=zenoh.Reliability.RELIABLE
                if s.reliable
                else zenoh.Reliability.BEST_EFFORT,
            )
            bridge_hash = None if s.distro == "humble" else type_hash
            h.bridge_token = self.session.liveliness().declare_token(
                zb.publisher_token(self.zid, t.name, t.type_name, s.reliable, s.depth, bridge_hash)
            )
        return h

    def _undeclare(self, h: _Handles) -> None:
        for ent in (h.rmw, h.bridge, h.token, h.bridge_token):
            if ent is not None:
                with contextlib.suppress(zenoh.ZError):  # the session is closing
                    ent.undeclare()
        h.dds = None  # Cyclone deletes a writer with its last reference

    def topics(self) -> list[str]:
        """Every topic published, for status."""
        return self.msgs.topics()

    def messages(self) -> dict[str, int]:
        """Messages put on each topic since it was declared, for status."""
        return {t.name: t.handles["out"].sent for t in self.msgs.all_topics()}

    def dropped(self) -> dict[str, int]:
        """Per device, messages not sent because their stamp did not follow the last one sent
        (a bus restart or a reload re-sent an instant already published), for status."""
        return self.msgs.dropped()

    def close(self) -> None:
        self.msgs.close()
        with contextlib.suppress(zenoh.ZError):
            self._node.undeclare()  # type: ignore[no-untyped-call]
        if self._dds is not None:
            self._dds.close()
            self._dds = None

    def tick(self, devices: list[dict[str, Any]], period_s: float = 1.0) -> None:
        """Called by the daemon every `period_s` with its devices' status JSON: publishes
        /diagnostics, and takes up the measured noise of a calibration file that changed."""
        self.msgs.tick(devices, time.time_ns(), period_s)

    def batch(self, name: str, payload: bytes | memoryview) -> None:
        """One relayed wire batch of device `name` (imud/ros2/messages.py)."""
        self.msgs.batch(name, payload)

    def _put(self, t: Topic, payloads: Iterable[bytes]) -> None:
        form = rz.Attachment(self.settings.attachment)
        now = time.time_ns()
        h: _Handles = t.handles["out"]
        with t.lock:
            for payload in payloads:
                h.sent += 1
                if h.rmw is not None:
                    h.rmw.put(payload, attachment=rz.attachment(h.sent, now, h.gid, form))
                if h.bridge is not None:
                    h.bridge.put(payload)
                if h.dds is not None:
                    h.dds.write_cdr(payload)
