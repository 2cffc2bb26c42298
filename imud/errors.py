"""Exceptions shared by buses, drivers and the daemon."""

from __future__ import annotations


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


class RegisterMismatch(BusError):
    """A configured register no longer holds its value: the chip must be reinitialised."""


class DeviceIdentityError(RuntimeError):
    """The chip at the configured address is not the configured chip, or will not configure."""


class ConfigError(ValueError):
    """A config file is unreadable or invalid; `messages` has one line per problem."""

    def __init__(self, messages: list[str]) -> None:
        super().__init__("\n".join(messages))
        self.messages = messages
