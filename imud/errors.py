"""Exceptions shared by buses, drivers and the daemon."""

from __future__ import annotations

import errno
from enum import StrEnum


class BusError(OSError):
    """A transfer failed (NAK, timeout, short read); the driver resyncs on the next read."""


def open_error(node: str, e: OSError, enable: str, group: str) -> BusError:
    """A device node that will not open, with the fix: enable the bus, or join its group."""
    hint = (
        enable
        if isinstance(e, FileNotFoundError)
        else f"add the daemon's user to the {group} group"
    )
    return BusError(e.errno, f"cannot open {node}: {e.strerror}; {hint}")


class ErrorKind(StrEnum):
    """What kind of transfer failure a bus error was, for status (`bus_errors_<kind>`): a NAK
    points at wiring, pull-ups or a chip that reset; EIO at the adapter or the kernel driver; a
    timeout at a clock-stretching or hung device."""

    NAK = "nak"
    EIO = "eio"
    TIMEOUT = "timeout"
    OTHER = "other"


_NAK = frozenset({errno.EREMOTEIO, errno.ENXIO, errno.EAGAIN})  # no ACK; arbitration lost
_TIMEOUT = frozenset({errno.ETIMEDOUT})


def error_kind(e: BaseException) -> ErrorKind:
    """The kind of a failed transfer, from its errno (Linux's i2c-dev and spidev report NAK as
    EREMOTEIO or ENXIO, some adapters lost arbitration as EAGAIN)."""
    if isinstance(e, TimeoutError):
        return ErrorKind.TIMEOUT
    if isinstance(e, OSError) and e.errno is not None:
        if e.errno in _NAK:
            return ErrorKind.NAK
        if e.errno == errno.EIO:
            return ErrorKind.EIO
        if e.errno in _TIMEOUT:
            return ErrorKind.TIMEOUT
    return ErrorKind.OTHER


BUS_ERROR_KEYS = {k: f"bus_errors_{k}" for k in ErrorKind}  # status keys, per kind


class RegisterMismatch(BusError):
    """A configured register no longer holds its value: the chip must be reinitialised."""


class DeviceIdentityError(RuntimeError):
    """The chip at the configured address is not the configured chip, or will not configure."""


class ConfigError(ValueError):
    """A config file is unreadable or invalid; `messages` has one line per problem."""

    def __init__(self, messages: list[str]) -> None:
        super().__init__("\n".join(messages))
        self.messages = messages
