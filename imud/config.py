"""The imud config file: one `[zenoh]` table and a list of `[[device]]` tables.

`load_config` is the one way in, used by the daemon, the CLI and the tests. Errors come back as a
`ConfigError` with one line per problem, naming the device, the field, the bad value and the fix.
"""

from __future__ import annotations

import difflib
import tomllib
import types
from pathlib import Path
from typing import Annotated, Any, Literal, Union, cast, get_args, get_origin

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
from imud.buses.models import SimBus
from imud.calibration import CalibrationError, load_calibration
from imud.chips.api import DeviceBase
from imud.errors import ConfigError
from imud.zerrors import endpoint_problem

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


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
                kind = bus.transport if isinstance(bus, SimBus) else bus.kind
                if kind not in transports:
                    raise ValueError(
                        f"device[{i}] {d.name!r}: a {d.chip} cannot be on a {kind} bus; "
                        f"it works over: {', '.join(transports)}"
                    )
            if d.sim is not None and not isinstance(d.bus, SimBus):
                raise ValueError(
                    f'device[{i}] {d.name!r}: a [device.sim] table needs bus.kind = "sim" '
                    f"(this device is on {d.bus.kind})"
                )
            if isinstance(d.bus, SimBus) and d.sim is None:
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


def _where(loc: tuple[int | str, ...], raw: dict[str, Any]) -> str:
    """('device', 1, 'mpu6050', 'bus', 'sim', 'adress') -> "device[1] 'imu1' (mpu6050): bus.adress".

    Union tags pydantic puts in the location (the chip, a bus kind, `int` of `int | str`) are
    left out: they are not keys the user wrote; the chip is shown next to the device."""
    tags = _walk(loc)[1]
    parts: list[str] = []
    start = 0
    if len(loc) >= 2 and loc[0] == "device" and isinstance(loc[1], int):
        i = loc[1]
        devs = raw.get("device")
        name = ""
        if isinstance(devs, list) and i < len(devs) and isinstance(devs[i], dict):
            name = f" {devs[i].get('name', '?')!r}"
            chip = devs[i].get("chip")
            if loc[2:3] == (chip,):
                name += f" ({chip})"
        parts.append(f"device[{i}]{name}")
        start = 2
    field = ".".join(
        str(p)
        for j, p in enumerate(loc[start:], start)
        if j not in tags and not str(p).startswith("function-")
    )
    return ": ".join([*parts, field] if field else parts)


def _members(tp: Any) -> list[Any]:
    """The alternatives of a (possibly Annotated, Optional) union type, flattened."""
    origin = get_origin(tp)
    if origin is Annotated:
        return _members(get_args(tp)[0])
    if origin in (Union, types.UnionType):
        return [m for a in get_args(tp) for m in _members(a)]
    return [tp]


def _is_model(tp: Any) -> bool:
    return isinstance(tp, type) and issubclass(tp, BaseModel)


def _tags(model: type[BaseModel]) -> set[str]:
    """The values pydantic may put in an error's location for this union member: its class name
    and its single-valued Literal fields (the discriminator: chip = "mpu6050", kind = "sim")."""
    tags = {model.__name__}
    for f in model.model_fields.values():
        args = get_args(f.annotation)
        if get_origin(f.annotation) is Literal and len(args) == 1:
            tags.add(str(args[0]))
    return tags


def _walk(loc: tuple[int | str, ...]) -> tuple[list[Any], set[int]]:
    """Walk the config model's types along an error location: the types found at its end, and
    which of its parts name a union member rather than a field (pydantic puts the member's tag
    in the location: ('device', 0, 'mpu6050', 'bus', 'sim', 'adress'))."""
    here: list[Any] = [config_model()]
    tags: set[int] = set()
    for i, part in enumerate(loc):
        if isinstance(part, str) and part.startswith("function-"):
            tags.add(i)
            continue
        models = [t for t in here if _is_model(t)]
        nxt: list[Any] = []
        if isinstance(part, int):
            for t in here:
                if get_origin(t) in (list, tuple) and get_args(t):
                    nxt += _members(get_args(t)[0])
        elif len(models) > 1 and (tagged := [m for m in models if part in _tags(m)]):
            nxt = tagged  # a discriminated union: the location names the member
            tags.add(i)
        elif len(here) > 1 and (
            plain := [t for t in here if isinstance(t, type) and t.__name__ == part]
        ):
            nxt = plain  # int | str: the location names the alternative that failed
            tags.add(i)
        else:
            for t in here:
                if _is_model(t) and part in t.model_fields:
                    nxt += _members(t.model_fields[part].annotation)
                elif get_origin(t) is dict and len(get_args(t)) == 2:
                    nxt += _members(get_args(t)[1])
        here = nxt
    return here, tags


def _fields_at(loc: tuple[int | str, ...]) -> list[str]:
    """The field names the config model allows inside `loc` (an unknown key's parent): what
    "did you mean" chooses from."""
    return sorted({f for t in _walk(loc)[0] if _is_model(t) for f in t.model_fields})


def _unknown_field(loc: tuple[int | str, ...], where: str, value: Any) -> str:
    """An unknown key, with the nearest allowed name at that place ("did you mean")."""
    key = str(loc[-1])
    known = _fields_at(loc[:-1])
    best = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
    if len(loc) == 1 and best and isinstance(value, dict | list):
        # a top-level table: say it the way the TOML file spells it
        table = f"[[{best[0]}]]" if isinstance(value, list) else f"[{best[0]}]"
        extra = " (one [[device]] table per IMU)" if best[0] == "device" else ""
        return f"{where}: unknown field; did you mean {table}?{extra}"
    if best:
        return f"{where}: unknown field; did you mean {best[0]!r}?"
    if known:
        return f"{where}: unknown field; allowed here: {', '.join(known)}"
    return f"{where}: unknown field; check the spelling (see `imud config-schema`)"


def _format(err: Any, raw: dict[str, Any]) -> str:
    where = _where(tuple(err["loc"]), raw)
    msg = str(err["msg"]).removeprefix("Value error, ")
    kind = err["type"]
    if kind == "missing":
        if tuple(err["loc"]) == ("device",):
            return "device: missing; add one [[device]] table per IMU"
        return f"{where}: missing; this field is required"
    if kind == "extra_forbidden":
        return _unknown_field(tuple(err["loc"]), where, err.get("input"))
    if kind in ("union_tag_invalid", "union_tag_not_found"):
        ctx = err.get("ctx") or {}
        field = str(ctx.get("discriminator", "'kind'")).strip("'")
        known = ctx.get("expected_tags") or ", ".join(repr(c) for c in registry.CHIPS)
        what = "chip" if field == "chip" else f"{where.rsplit(': ', 1)[-1]} {field}"
        if kind == "union_tag_not_found":
            return f"{where}: missing {field!r} (one of: {known})"
        tags = [t.strip(" '\"") for t in str(known).split(",")]
        best = difflib.get_close_matches(str(ctx.get("tag")), tags, n=1, cutoff=0.6)
        mean = f"did you mean {best[0]!r}? " if best else ""
        return f"{where}: unknown {what} {ctx.get('tag')!r}; {mean}known: {known}"
    inp = err.get("input")
    if not isinstance(inp, dict | list):  # a scalar: show the bad value
        return f"{where} = {inp!r}: {msg}" if where else msg
    return f"{where}: {msg}" if where else msg


def parse_config(raw: dict[str, Any], base_dir: Path | None = None) -> ImudConfig:
    try:
        cfg = config_model().model_validate(raw, context={"base_dir": base_dir})
    except ValidationError as e:
        raise ConfigError([_format(err, raw) for err in e.errors()]) from None
    problems = []
    for i, d in enumerate(cfg.device):
        if d.calibration is not None:
            try:
                load_calibration(d.calibration)
            except CalibrationError as e:
                problems.append(f"device[{i}] {d.name!r}: calibration: {e}")
    if problems:
        raise ConfigError(problems)
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
