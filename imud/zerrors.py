"""Zenoh endpoints checked before Zenoh sees them, and Zenoh's errors made readable.

Zenoh's own messages end in the Rust source location that raised them ("... at
/root/.cargo/git/checkouts/zenoh-.../src/net/runtime/orchestrator.rs:447."): noise to a user, and
it changes with every Zenoh build. Every message the CLI and the daemon's `run` print goes through
`clean`. A malformed endpoint is caught here, with the value and the expected form, instead of
surfacing as "cannot connect" after Zenoh fails to parse it.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterable

# Zenoh's link protocols that take an address; `_IP` ones take HOST:PORT.
PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream")
_IP = {"tcp", "udp", "tls", "quic", "ws"}
EXPECTED = "PROTOCOL/HOST:PORT like 'tcp/127.0.0.1:7450'"
# where the daemon listens, and clients connect, by default: not Zenoh's own 7447, where a ROS 2
# machine's router (rmw_zenohd) or zenoh-bridge-ros2dds listens
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7450"

_RUST_AT = re.compile(r"\s+at\s+\S*\.rs:\d+(?::\d+)?\.?")
_LISTENER = re.compile(r"bound to (\S+?):?\s*\[")


def endpoint_problem(endpoint: str) -> str | None:
    """What is wrong with a Zenoh endpoint string, or None when Zenoh can use it.

    Checked: the protocol, a non-empty address, and for IP protocols HOST:PORT with the port in
    1-65535 (Zenoh itself only says "cannot connect" for port 99999)."""
    proto, slash, rest = endpoint.partition("/")
    if not slash or proto not in PROTOCOLS:
        known = ", ".join(PROTOCOLS)
        return f"{endpoint!r} is not a Zenoh endpoint: expected {EXPECTED} (protocols: {known})"
    address = re.split(r"[?#]", rest, maxsplit=1)[0]
    if not address:
        return f"{endpoint!r} has no address: expected {EXPECTED}"
    if proto not in _IP:
        return None
    host, colon, port = address.rpartition(":")
    if not colon or not host or host in ("[", "[]"):
        return f"{endpoint!r} needs HOST:PORT: expected {EXPECTED}"
    if not port.isdigit():
        return f"{endpoint!r}: port {port!r} is not a number: expected {EXPECTED}"
    if not 1 <= int(port) <= 65535:
        return f"{endpoint!r}: port {int(port)} is out of range (1-65535)"
    return None


def clean(message: str) -> str:
    """`message` without Zenoh's Rust source locations and the blank runs they leave."""
    return re.sub(r"  +", " ", _RUST_AT.sub("", message)).strip()


def leaves(e: BaseException) -> list[BaseException]:
    """The exceptions inside (nested) exception groups, as anyio task groups raise them."""
    if isinstance(e, BaseExceptionGroup):
        return [leaf for sub in e.exceptions for leaf in leaves(sub)]
    return [e]


def _is_zenoh(e: BaseException) -> bool:
    return isinstance(e, ZenohSetupError) or type(e).__module__.split(".")[0] == "zenoh"


def describe(e: BaseException, listen: Iterable[str] = ()) -> str:
    """One line for an exception that stopped the daemon from starting (or a client call):
    Zenoh's message cleaned, a taken listen port named with what to do about it."""
    texts = []
    for leaf in leaves(e):
        text = clean(str(leaf)) or type(leaf).__name__
        if not _is_zenoh(leaf):
            text = f"{type(leaf).__name__}: {text}"
        texts.append(listen_problem(text, listen) or text)
    return "; ".join(dict.fromkeys(texts))


def listen_problem(text: str, listen: Iterable[str] = ()) -> str | None:
    """A Zenoh listener error (already cleaned) said in terms of the config, or None when
    `text` is not one. Names the endpoint: from Zenoh's message, else the configured ones."""
    low = text.lower()
    if "address already in use" in low or "os error 98" in low:
        what = "address already in use; is another imud (or other program) listening there?"
        hint = "stop it, or change [zenoh] listen in the config"
    elif "cannot assign requested address" in low or "os error 99" in low:
        what = "that address is not on this machine"
        hint = "change [zenoh] listen to one of its addresses, e.g. tcp/127.0.0.1:7450"
    elif "permission denied" in low and "listen" in low:
        what = "permission denied (ports below 1024 need privileges)"
        hint = "change [zenoh] listen to a port above 1023"
    else:
        return None
    m = _LISTENER.search(text)
    endpoints = (
        [m.group(1)] if m else [ep for ep in listen if _hostport(ep) in text] or list(listen)
    )
    where = ", ".join(endpoints) or "the [zenoh] listen endpoint"
    return f"cannot listen on {where}: {what} ({hint})"


def _hostport(endpoint: str) -> str:
    return re.split(r"[?#]", endpoint.partition("/")[2], maxsplit=1)[0]


class ZenohSetupError(ValueError):
    """The Zenoh config imud builds was refused (a bad `[zenoh] options` entry); the message
    names the setting."""


class CleanZenohMessages(logging.Filter):
    """A log handler filter: records that quote a Zenoh error lose its Rust source locations,
    in the message and in a logged traceback alike."""

    _fmt = logging.Formatter()

    def filter(self, record: logging.LogRecord) -> bool:
        msg = record.getMessage()
        if ".rs:" in msg:
            record.msg, record.args = clean(msg), None
        if record.exc_info and not record.exc_text:
            record.exc_text = _RUST_AT.sub("", self._fmt.formatException(record.exc_info))
        return True
