"""A datasheet fact about a chip's register map (tests/test_register_facts.py checks them)."""

from __future__ import annotations

from dataclasses import dataclass

ROWS = "rows"  # Fact.key: the set of a table's keys


@dataclass(frozen=True)
class Fact:
    name: str  # attribute path in the chip's registers module, e.g. "Register.PWR_MGMT_1"
    value: object  # the datasheet literal (a BitField is compared by its mask)
    cite: str  # document, revision, section; the drivers the sheet quotes
    key: object = None  # one row of a table (name[key]), or ROWS for the table's keys
    at_least: bool = False  # a minimum wait: the map may add margin

    @property
    def id(self) -> str:
        if self.key is None:
            return self.name
        return f"{self.name}.keys" if self.key == ROWS else f"{self.name}[{self.key!r}]"


F = Fact  # short, for the tables
