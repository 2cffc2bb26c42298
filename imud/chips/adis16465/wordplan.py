"""Configured 16-bit registers, written read-modify-write and verified through the chip's own
framing.

The settings are `imud.chips.regplan.RegisterSetting`s of width 16 (PX4's `_register_cfg` scheme:
the bits a setting sets and clears, the others kept), and `regplan.RegisterChecker` re-checks one
of them every 100 ms; only the reads and writes differ from a byte-register chip, since the
ADIS16465 pipelines its 16-bit words (one read of every setting in one pass).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from imud.chips.regplan import RegisterSetting
from imud.errors import DeviceIdentityError


class WordPort(Protocol):
    def read_words(self, registers: Sequence[int]) -> list[int]: ...

    def write_word(self, register: int, value: int) -> None: ...


class WordPlan:
    die = ""  # one die: messages name no die

    def __init__(self, port: WordPort, settings: Sequence[RegisterSetting]) -> None:
        self.port = port
        self.settings = list(settings)

    def write_all(self) -> None:
        """Read-modify-write every setting (one pipelined read of them all first)."""
        current = self.port.read_words([s.register for s in self.settings])
        for s, value in zip(self.settings, current, strict=True):
            self.port.write_word(s.register, s.apply(value))

    def verify(self, s: RegisterSetting) -> int | None:
        """The register's value if it does not hold the setting (read twice), else None."""
        (got,) = self.port.read_words([s.register])
        if not s.holds(got):
            (got,) = self.port.read_words([s.register])
        return None if s.holds(got) else got

    def verify_all(self) -> None:
        for s in self.settings:
            got = self.verify(s)
            if got is not None:
                raise DeviceIdentityError(f"{s.describe(got)} after configuring")
