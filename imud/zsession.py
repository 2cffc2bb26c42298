"""Zenoh configs imud builds: multicast scouting off, explicit endpoints, SHM off by default."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import zenoh

from imud.zerrors import DEFAULT_ENDPOINT, ZenohSetupError, clean

if TYPE_CHECKING:
    from imud.config import ZenohSettings


def daemon_config(s: ZenohSettings) -> zenoh.Config:
    """The daemon's session config. Raises `ZenohSetupError` naming an `options` entry Zenoh
    refuses (`imud check-config` builds it too, so a bad entry is a config error)."""
    d: dict[str, Any] = {
        "mode": s.mode,
        "listen": {"endpoints": s.listen},
        "connect": {"endpoints": s.connect},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"shared_memory": {"enabled": s.shared_memory}},
    }
    cfg = zenoh.Config.from_json5(json.dumps(d))
    for key, value in s.options.items():
        try:
            cfg.insert_json5(key, json.dumps(value))
        except zenoh.ZError as e:  # Zenoh says only 'Str("unknown key")'
            why = clean(str(e)).removeprefix('Str("').removesuffix('")')
            raise ZenohSetupError(
                f"zenoh.options: {key!r} = {value!r}: Zenoh refuses it ({why}); keys are Zenoh "
                "config paths like 'transport/unicast/qos/enabled'"
            ) from None
    # the pass-through table must not switch multicast back on behind the user's back silently
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return cfg


def client_config(endpoint: str = DEFAULT_ENDPOINT) -> zenoh.Config:
    """For the CLI and tools: a client that connects to one daemon and listens nowhere."""
    d = {
        "mode": "client",
        "connect": {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"shared_memory": {"enabled": False}},
    }
    return zenoh.Config.from_json5(json.dumps(d))
