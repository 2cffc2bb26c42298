"""Config errors in the user's terms: one line per problem, naming the device, the field (as the
TOML file spells it, without pydantic's union tags), the bad value, and the fix or the nearest
valid name ("did you mean")."""

from __future__ import annotations

import difflib
import types
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import BaseModel

from imud import registry


def _where(loc: tuple[int | str, ...], raw: dict[str, Any], model: type[BaseModel]) -> str:
    """('device', 1, 'mpu6050', 'bus', 'sim', 'adress') -> "device[1] 'imu1' (mpu6050): bus.adress".

    Union tags pydantic puts in the location (the chip, a bus kind, `int` of `int | str`) are
    left out: they are not keys the user wrote; the chip is shown next to the device."""
    tags = _walk(loc, model)[1]
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


def _walk(loc: tuple[int | str, ...], model: type[BaseModel]) -> tuple[list[Any], set[int]]:
    """Walk the config model's types along an error location: the types found at its end, and
    which of its parts name a union member rather than a field (pydantic puts the member's tag
    in the location: ('device', 0, 'mpu6050', 'bus', 'sim', 'adress'))."""
    here: list[Any] = [model]
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


def _fields_at(loc: tuple[int | str, ...], model: type[BaseModel]) -> list[str]:
    """The field names the config model allows inside `loc` (an unknown key's parent): what
    "did you mean" chooses from."""
    return sorted({f for t in _walk(loc, model)[0] if _is_model(t) for f in t.model_fields})


def _unknown_field(
    loc: tuple[int | str, ...], where: str, value: Any, model: type[BaseModel]
) -> str:
    """An unknown key, with the nearest allowed name at that place ("did you mean")."""
    key = str(loc[-1])
    known = _fields_at(loc[:-1], model)
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


def explain(err: Any, raw: dict[str, Any], model: type[BaseModel]) -> str:
    """One pydantic error as one line naming the device, the field, the bad value and the fix."""
    where = _where(tuple(err["loc"]), raw, model)
    msg = str(err["msg"]).removeprefix("Value error, ")
    kind = err["type"]
    if kind == "missing":
        if tuple(err["loc"]) == ("device",):
            return "device: missing; add one [[device]] table per IMU"
        return f"{where}: missing; this field is required"
    if kind == "extra_forbidden":
        return _unknown_field(tuple(err["loc"]), where, err.get("input"), model)
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
