"""The imud config file: one `[zenoh]` table and a list of `[[device]]` tables.

`load_config` is the one way in, used by the daemon, the CLI and the tests. Errors come back as a
`ConfigError` with one line per problem, naming the device, the field, the bad value and the fix.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal, Union, cast

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    create_model,
    field_validator,
    model_validator,
)

from imud import registry
from imud.channels import Channel
from imud.chips.api import DeviceBase
from imud.configerrors import explain
from imud.errors import ConfigError
from imud.rosnames import join, name_problem, node_problem
from imud.zerrors import DEFAULT_ENDPOINT, endpoint_problem

# where a ROS 2 machine's Zenoh router (rmw_zenohd) or zenoh-bridge-ros2dds listens by default
ROS_ROUTER = "tcp/127.0.0.1:7447"
ROS_DOMAIN_MAX = 232  # the largest domain id ROS 2 allows (DDS's port mapping)


class ZenohSettings(BaseModel):
    """Where the daemon's Zenoh session listens and connects. Multicast scouting is always off."""

    model_config = ConfigDict(extra="forbid")

    mode: Literal["peer", "client", "router"] = "peer"
    listen: list[str] = Field(default_factory=lambda: [DEFAULT_ENDPOINT])
    connect: list[str] = Field(default_factory=list)
    prefix: str = Field("imud", pattern=r"^[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*$")
    shared_memory: bool = False
    options: dict[str, Any] = Field(
        default_factory=dict,
        description='any other Zenoh setting, by its config path: {"transport/unicast/qos/enabled" '
        "= false}; applied after imud's own, so it can override them",
    )

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, v: list[str]) -> list[str]:
        """Checked here so a bad endpoint (or port 99999) is a config error naming the field,
        not a Zenoh failure at start-up."""
        problems = [p for p in map(endpoint_problem, v) if p]
        if problems:
            raise ValueError("; ".join(problems))
        return v


class DaemonSettings(BaseModel):
    """How the daemon itself runs."""

    model_config = ConfigDict(extra="forbid")

    realtime_priority: int | None = Field(
        None,
        ge=1,
        le=99,
        description="SCHED_FIFO priority for the bus worker threads (needs CAP_SYS_NICE or "
        "LimitRTPRIO). At 16-32 kHz a FIFO lasts 4-8 ms: without it an ordinary scheduler "
        "delay can overflow it",
    )
    bus_processes: bool = Field(
        True,
        description="run each bus in its own process, so no other bus or the publisher can "
        "hold its interpreter lock (measured: needed for zero loss at 32 kHz on 2 vCPUs); "
        "false runs every bus as a thread of one process",
    )
    hung_after_s: float = Field(
        10.0,
        ge=2.0,
        le=600.0,
        description="a bus process whose worker makes no progress this long (stuck inside a "
        "bus call) is killed and restarted; longer than any bus call may legitimately block "
        "(the longest driver wait is a chip's reset, well under 1 s)",
    )


Ros2Profile = Literal["rmw_zenoh", "bridge", "dds"]


class Ros2Settings(BaseModel):
    """`[ros2]`: every device as a ROS 2 publisher (docs/ros2.md). Off unless `enabled`."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = False
    profiles: list[Ros2Profile] = Field(
        default_factory=lambda: list[Ros2Profile](["rmw_zenoh"]),
        min_length=1,
        description="rmw_zenoh: straight to ROS 2 nodes on rmw_zenoh; bridge: for "
        "zenoh-bridge-ros2dds; dds: to DDS-based nodes (the dds extra: cyclonedds)",
    )
    domain_id: int | None = Field(
        None, ge=0, le=ROS_DOMAIN_MAX, description="default: $ROS_DOMAIN_ID, else 0"
    )
    namespace: str = Field("/", description="topics: <namespace>/<device>/imu/data_raw ...")
    node: str = Field("imud", description="the node name `ros2 node list` shows")
    frame_id: str = Field("imu_link", description="header.frame_id (per device: [device.ros2])")
    rate_hz: float = Field(
        200.0,
        gt=0.0,
        description="at most this many messages a second per device; a faster chip's samples "
        "are averaged over each interval",
    )
    batch_ms: float = Field(
        10.0,
        ge=0.0,
        le=1000.0,
        description="publish a device's messages once this much of its stream has arrived: "
        "fewer, larger steps cost the daemon less CPU; 0: every batch as it arrives",
    )
    temperature: bool = Field(False, description="also imu/temperature (sensor_msgs/Temperature)")
    diagnostics: bool = Field(
        True,
        description="each device's health and lost samples once a second on /diagnostics "
        "(diagnostic_msgs/DiagnosticArray)",
    )
    reliable: bool = Field(True, description="offer RELIABLE (a DDS reader of either kind matches)")
    depth: int = Field(5, ge=1, le=1000, description="KEEP_LAST depth the publishers offer")
    distro: Literal["humble", "jazzy", "kilted", "rolling"] = Field(
        "jazzy", description="of the ROS 2 nodes: Humble's rmw_zenoh has no type hashes"
    )
    attachment: Literal["current", "key-value"] = Field(
        "current",
        description="rmw_zenoh's attachment layout: key-value for Jazzy 0.2.0-0.2.3 and Humble "
        "0.1.0-0.1.1, current for every later one",
    )
    connect: list[str] = Field(
        default_factory=lambda: [ROS_ROUTER],
        description="the ROS machine's Zenoh router or bridge; joined to [zenoh] connect",
    )

    @field_validator("connect")
    @classmethod
    def _endpoints(cls, v: list[str]) -> list[str]:
        problems = [p for p in map(endpoint_problem, v) if p]
        if problems:
            raise ValueError("; ".join(problems))
        return v

    @field_validator("namespace")
    @classmethod
    def _namespace(cls, v: str) -> str:
        problem = name_problem(v, "namespace")
        if problem:
            raise ValueError(problem)
        return v

    @field_validator("node")
    @classmethod
    def _node(cls, v: str) -> str:
        problem = node_problem(v)
        if problem:
            raise ValueError(problem)
        return v

    @field_validator("frame_id")
    @classmethod
    def _frame_id(cls, v: str) -> str:
        if "\0" in v or not v.strip():
            raise ValueError("frame_id must be a non-empty name without NUL, e.g. 'imu_link'")
        return v

    @field_validator("profiles")
    @classmethod
    def _unique_profiles(cls, v: list[Ros2Profile]) -> list[Ros2Profile]:
        if len(set(v)) != len(v):
            raise ValueError(f"profiles {v} names one twice")
        return v


class ImudConfig(BaseModel):
    """The whole file. `device` is validated as the union of the registered chips' models,
    discriminated on `chip` (see `config_model`); to the type checker it is `DeviceBase`."""

    model_config = ConfigDict(extra="forbid")

    daemon: DaemonSettings = Field(default_factory=DaemonSettings)
    zenoh: ZenohSettings = Field(default_factory=ZenohSettings)
    ros2: Ros2Settings = Field(default_factory=Ros2Settings)
    device: list[DeviceBase] = Field(min_length=1)

    def session_settings(self) -> ZenohSettings:
        """`[zenoh]` as the daemon's session uses it: with `[ros2] connect` joined when a ROS 2
        profile that goes through Zenoh is on."""
        s, r = self.zenoh, self.ros2
        if not (r.enabled and {"rmw_zenoh", "bridge"} & set(r.profiles)):
            return s
        extra = [e for e in r.connect if e not in s.connect]
        return s.model_copy(update={"connect": [*s.connect, *extra]})

    @model_validator(mode="after")
    def _unique(self) -> ImudConfig:
        names: dict[str, int] = {}
        slots: dict[tuple[str, ...], str] = {}
        for i, d in enumerate(self.device):
            if d.name == "daemon":
                raise ValueError(
                    f"device[{i}]: name 'daemon' is reserved (<prefix>/daemon/status is the "
                    "daemon's own status); pick another name"
                )
            if d.name in names:
                raise ValueError(
                    f"device[{i}]: name {d.name!r} is already used by device[{names[d.name]}]; "
                    "names must be unique"
                )
            names[d.name] = i
            transports = registry.CHIPS[d.chip].transports
            for bus in d.die_buses():
                slot = bus.slot
                if slot in slots:
                    raise ValueError(
                        f"device[{i}] {d.name!r}: {' '.join(slot)} is already taken by "
                        f"{slots[slot]!r}"
                    )
                slots[slot] = d.name
                kind = bus.transport
                if kind not in transports:
                    raise ValueError(
                        f"device[{i}] {d.name!r}: a {d.chip} cannot be on a {kind} bus; "
                        f"it works over: {', '.join(transports)}"
                    )
            if d.sim is not None and not d.bus.simulated:
                raise ValueError(
                    f'device[{i}] {d.name!r}: a [device.sim] table needs bus.kind = "sim" '
                    f"(this device is on {d.bus.kind})"
                )
            if d.bus.simulated and d.sim is None:
                d.sim = _default_sim()
            channels = registry.CHIPS[d.chip].channels
            if d.orientation.enabled:
                if channels & Channel.ORIENTATION:
                    raise ValueError(
                        f"device[{i}] {d.name!r}: orientation.enabled: a {d.chip} computes its "
                        "own orientation (its fusion output); imud's filter would publish a "
                        "second one on the same channel: remove [device.orientation] or set "
                        "enabled = false"
                    )
                if not channels & Channel.GYRO or not channels & Channel.ACCEL:
                    raise ValueError(
                        f"device[{i}] {d.name!r}: orientation.enabled needs a gyro and an "
                        f"accelerometer; a {d.chip} does not publish both"
                    )
            rate = d.ros2.rate_hz
            if rate is not None and rate > d.odr_hz:
                raise ValueError(
                    f"device[{i}] {d.name!r}: ros2.rate_hz = {rate:g} is above its odr_hz "
                    f"({d.odr_hz:g}): ROS 2 gets at most one message a sample; set it to "
                    f"{d.odr_hz:g} or less"
                )
        topics: dict[str, str] = {}
        for d in self.device:
            if not d.ros2.enabled:
                continue
            where = join(self.ros2.namespace, d.ros2.namespace or d.name)
            problem = name_problem(where + "/imu/data_raw")
            if problem:
                raise ValueError(f"device {d.name!r}: its ROS 2 topics: {problem}")
            if where in topics:
                raise ValueError(
                    f"devices {topics[where]!r} and {d.name!r} would both publish under "
                    f"{where}: give one a [device.ros2] namespace of its own"
                )
            topics[where] = d.name
        return self


def _default_sim() -> Any:
    from imud.sim.settings import SimSettings

    return SimSettings()


_models: tuple[int, type[ImudConfig]] | None = None


def config_model() -> type[ImudConfig]:
    """`ImudConfig` with `device` as the union of every registered chip's model; rebuilt when
    a chip is registered (a test's toy chip, a plugin)."""
    global _models
    if _models is None or _models[0] != registry.generation:
        models = tuple(spec.config_model for spec in registry.CHIPS.values())
        device: Any = (
            models[0] if len(models) == 1 else Annotated[Union[models], Field(discriminator="chip")]  # noqa: UP007
        )
        model = create_model(
            "ImudConfig", __base__=ImudConfig, device=(list[device], Field(min_length=1))
        )
        _models = (registry.generation, cast(type[ImudConfig], model))
    return _models[1]


def parse_config(raw: dict[str, Any], base_dir: Path | None = None) -> ImudConfig:
    try:
        cfg = config_model().model_validate(raw, context={"base_dir": base_dir})
    except ValidationError as e:
        model = config_model()
        raise ConfigError([explain(err, raw, model) for err in e.errors()]) from None
    return cfg


def load_config(path: str | Path) -> ImudConfig:
    """Read, parse and validate a config file. Raises `ConfigError`."""
    p = Path(path)
    try:
        with open(p, "rb") as f:
            raw = tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError([f"{p}: no such file"]) from None
    except IsADirectoryError:
        raise ConfigError([f"{p}: is a directory, expected a TOML file"]) from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError([f"{p}: TOML syntax error: {e}"]) from None
    except UnicodeDecodeError as e:
        raise ConfigError([f"{p}: not UTF-8 text (byte {e.start}); TOML files are UTF-8"]) from None
    except OSError as e:
        raise ConfigError([f"{p}: cannot read: {e.strerror}"]) from None
    return parse_config(raw, p.parent.resolve())
