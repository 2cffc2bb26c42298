"""A client's session to one daemon, and its status question: all `imud status` needs (no NumPy,
no chip). `imud.client` adds the data streams."""

from __future__ import annotations

import json
from typing import Any

import zenoh

from imud.zerrors import DEFAULT_ENDPOINT, clean, endpoint_problem
from imud.zsession import client_config


class NoDaemon(ConnectionError):
    """Nothing answers: no Zenoh peer at the endpoint, or no daemon behind it."""


class BadEndpoint(ValueError):
    """The endpoint string is malformed (a usage error, not an unreachable daemon)."""


def open_session(endpoint: str = DEFAULT_ENDPOINT) -> zenoh.Session:
    """A client session to one daemon, with multicast scouting disabled (`client_config`): it talks
    to the given endpoint only. Raises `BadEndpoint` for a malformed endpoint (checked first, so
    `foo` or port 99999 is not reported as an absent daemon) and `NoDaemon` if nothing listens
    there."""
    problem = endpoint_problem(endpoint)
    if problem:
        raise BadEndpoint(problem)
    try:
        return zenoh.open(client_config(endpoint))
    except zenoh.ZError as e:
        reason = clean(str(e))
        # "Unable to connect to any of [Single(tcp/...)]!" only repeats the endpoint
        detail = "" if reason.startswith("Unable to connect") else f" ({reason})"
        raise NoDaemon(f"no imud daemon reachable at {endpoint}{detail}") from None


def get_config(
    session: zenoh.Session, prefix: str = "imud", timeout: float = 2.0
) -> dict[str, Any]:
    """What the daemon runs (Daemon.config_view): its config as loaded and as written, and its
    devices' calibration files. Raises `NoDaemon` as get_status does."""
    return _ask(session, f"{prefix}/daemon/config", timeout)


def get_status(
    session: zenoh.Session, prefix: str = "imud", device: str | None = None, timeout: float = 2.0
) -> dict[str, Any]:
    """The daemon's status (or one device's) as JSON. Raises `NoDaemon` when nothing answers
    within `timeout` seconds (a Zenoh peer without an imud daemon, or another `prefix`)."""
    return _ask(session, f"{prefix}/{device or 'daemon'}/status", timeout)


def _ask(session: zenoh.Session, key: str, timeout: float) -> dict[str, Any]:
    try:
        for reply in session.get(key, timeout=timeout):
            if reply.ok is not None:
                parsed: dict[str, Any] = json.loads(reply.ok.payload.to_string())
                return parsed
    except zenoh.ZError as e:
        raise NoDaemon(f"asking {key} failed: {clean(str(e))}") from None
    raise NoDaemon(f"no answer on {key} within {timeout:g} s")
