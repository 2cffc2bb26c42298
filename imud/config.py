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
from imud.chips.api import DeviceBase
from imud.configerrors import explain
from imud.errors import ConfigError
from imud.zerrors import DEFAULT_ENDPOINT, endpoint_problem


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


class ImudConfig(BaseModel):
    """The whole file. `device` is validated as the union of the registered chips' models,
    discriminated on `chip` (see `config_model`); to the type checker it is `DeviceBase`."""

    model_config = ConfigDict(extra="forbid")

    daemon: DaemonSettings = Field(default_factory=DaemonSettings)
    zenoh: ZenohSettings = Field(default_factory=ZenohSettings)
    device: list[DeviceBase] = Field(min_length=1)

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
